"""Steering identification pieces: the eq. 2-6 inversion, the dead time, intervals that survive
correlated residuals, and the identifiability verdict."""

import numpy as np
import pytest
from scipy.signal import lfilter

from hmpc.models.sim.effects import parse_effect
from hmpc.models.identify.pipeline import concat_recordings
from hmpc.models.params import load_params
from hmpc.models.sim.sensors import wheel_speeds
from hmpc.models.sim.simulator import simulate_experiment
from hmpc.models.identify.stats import ols_hac, quantisation_step
from hmpc.models.identify.steering import (
    identify_steering,
    road_wheel_angle_from_front,
    road_wheel_angle_from_yaw,
    xcorr_dead_time,
)
from _data import PARAMS_DIR

SEED = 5


@pytest.fixture(scope="module")
def truth():
    return load_params(PARAMS_DIR / "report_2008.yaml")


def test_front_wheel_inversion_is_exact_to_full_lock():
    # wheel speeds from the simulator's independent rigid-body model (models.sensors)
    b, T = 2.65, 1.6
    delta = np.linspace(-0.66, 0.66, 41)
    for v in (1.5, 5.0, 20.0):
        fl, fr, rl, rr = wheel_speeds(np.full_like(delta, v), delta, b, T, T)
        d_est, v_est = road_wheel_angle_from_front(fl, fr, b, T)
        np.testing.assert_allclose(d_est, delta, atol=1e-9)
        np.testing.assert_allclose(v_est, v, rtol=1e-9)
        # (b): yaw rate of eq. 1 with the rear-axle speed gives the same angle
        r = v * np.sin(delta) / b
        np.testing.assert_allclose(
            road_wheel_angle_from_yaw(r, 0.5 * (rl + rr), b), delta, atol=1e-12
        )
    # eq. 5 alone (omega = (fr - fl) / T, delta = b omega / v) is several percent off at lock:
    fl, fr, _, _ = wheel_speeds(np.array([3.0]), np.array([0.6]), b, T, T)
    naive = b * (fr - fl) / T / 3.0
    assert abs(naive[0] / 0.6 - 1.0) > 0.03
    d, v = road_wheel_angle_from_front(np.array([0.0, np.nan]), np.array([0.0, 1.0]), b, T)
    assert np.isnan(d).all() and v[0] == 0.0 and np.isnan(v[1])


def test_xcorr_dead_time_finds_a_known_delay():
    rng = np.random.default_rng(SEED)
    dt, n, lag = 0.02, 5000, 7  # 0.14 s
    u = lfilter([1.0], [1.0, -0.95], rng.normal(size=n))
    y = np.concatenate([np.zeros(lag), u[:-lag]]) + 0.1 * rng.normal(size=n)
    est, peak = xcorr_dead_time(u, y, np.ones(n, bool), dt, min_lag_s=-0.2, max_lag_s=1.0)
    assert est == pytest.approx(lag * dt, abs=0.01)
    assert peak > 0.9


def test_blockwise_hac_interval_covers_where_the_naive_one_does_not():
    """On AR(1) regressor and residuals (rho = 0.98, 50 Hz-like), seeded: the time-block HAC
    interval covers the true slope in most runs, the textbook OLS interval in few."""
    cover_hac = cover_naive = 0
    runs = 60
    for s in range(runs):
        rng = np.random.default_rng(1000 + s)
        n = 3000
        x = 0.2 * lfilter([1.0], [1.0, -0.98], rng.normal(size=n))
        e = 0.1 * lfilter([1.0], [1.0, -0.98], rng.normal(size=n))
        X = np.column_stack([np.ones(n), x])
        y = 0.3 + 2.0 * x + e
        r = ols_hac(X, y)
        cover_hac += r.ci95[1, 0] <= 2.0 <= r.ci95[1, 1]
        res = y - X @ r.coef
        se = np.sqrt(res @ res / (n - 2) * np.linalg.inv(X.T @ X)[1, 1])
        cover_naive += abs(r.coef[1] - 2.0) <= 1.96 * se
    print(
        f"coverage over {runs} seeded runs: HAC {cover_hac / runs:.2f}, naive "
        f"{cover_naive / runs:.2f}"
    )
    assert cover_hac / runs >= 0.8
    assert cover_naive / runs <= 0.3


def test_steering_dead_time_is_recovered(truth):
    fx = [parse_effect("steering_dead_time:delay_s=0.2")]
    rec = concat_recordings(
        [simulate_experiment(n, truth, seed=SEED, effects=fx) for n in ("arcs", "figure8")]
    )
    res = identify_steering(rec, truth.vehicle)
    print(
        f"dead time {res.dead_time_s:.3f} s (truth 0.2 s), offset {res.offset_rad:+.5f}, "
        f"scale {res.scale:.5f}"
    )
    # measured: dead time 0.195 s, offset error -0.00008 rad, scale error -0.095%; bounds
    # 0.01 s (half a 50 Hz sample), 0.0003 rad and 0.3% (margin 2-4x; acceptance 0.002 rad, 2%)
    assert res.dead_time_s == pytest.approx(0.2, abs=0.01)
    assert res.report["dead_time"]["used"]
    assert abs(res.offset_rad - truth.steering.offset_rad) <= 0.0003
    assert abs(res.scale / truth.steering.scale - 1) <= 0.003


def test_little_steering_is_reported_not_identifiable(truth):
    """The ramps (near-straight steering) cannot separate offset from scale: say so."""
    rec = simulate_experiment("ramps", truth, seed=SEED)
    res = identify_steering(rec, truth.vehicle)
    print(res.note)
    assert res.identifiable is False
    assert "steering-wheel range" in res.note
    checks = {c["name"]: c for c in res.report["identifiability"]["checks"]}
    assert checks["steering_range_rad"]["passed"] is False
    # the estimate still comes with a finite interval, and it covers the truth (measured
    # scale [0.0786, 0.0812] around 0.08, offset [0.01654, 0.01727] around 0.017 rad)
    assert np.isfinite(res.scale_ci95).all() and np.isfinite(res.offset_ci95_rad).all()
    assert res.scale_ci95[0] <= truth.steering.scale <= res.scale_ci95[1]
    assert res.offset_ci95_rad[0] <= truth.steering.offset_rad <= res.offset_ci95_rad[1]


def test_wide_steering_is_identifiable_and_replay_refines(truth):
    rec = concat_recordings([simulate_experiment(n, truth, seed=SEED) for n in ("arcs", "circles")])
    res = identify_steering(rec, truth.vehicle)
    assert res.identifiable, res.note
    assert res.method == "position_replay"
    fit = res.fits["position_replay"]
    assert fit.extra["windows"] >= 10
    # [m]: the replayed bicycle stays on the measured track (measured 0.030 m; bound 0.06 m)
    assert fit.rms_error < 0.06
    ag = res.report["agreement_a_b"]
    # measured correlation 0.9992, scale ratio 1.0030; bounds 0.998 and 0.6%
    assert ag["correlation"] > 0.998 and abs(ag["scale_ratio"] - 1) < 0.006


WHEELS = ("wheel_speed_fl", "wheel_speed_fr", "wheel_speed_rl", "wheel_speed_rr")


@pytest.fixture(scope="module")
def wide(truth):
    """Wide steering at several speeds (hmpc's simulator, seeded)."""
    return concat_recordings(
        [simulate_experiment(n, truth, seed=SEED) for n in ("arcs", "circles")]
    )


def _without(rec, *names):
    from hmpc.models.logs.recording import Recording

    return Recording({k: v for k, v in rec.channels.items() if k not in names}, {}, dict(rec.meta))


def test_without_wheel_speeds_steering_comes_from_yaw_rate_and_speed(truth, wide):
    """No wheel speeds -> the yaw-rate fit (with 'speed' at a point it estimates) and
    the replay; the skipped method is named with its channel."""
    res = identify_steering(_without(wide, *WHEELS), truth.vehicle)
    sel = res.report["selection"]
    assert "wheel_speed_difference" not in res.fits and "yaw_rate" in res.fits
    assert "wheel_speed_fl" in sel["skipped"]["wheel_speed_difference"]
    assert set(sel["scores"]) == set(res.fits) and sel["chosen"] == res.method
    assert res.report["speed_source"] == "speed"
    for f in (res.fits["yaw_rate"], res):
        assert abs(f.offset_rad - truth.steering.offset_rad) <= 0.002
        assert abs(f.scale / truth.steering.scale - 1) <= 0.02
    assert "speed_point_k_ci95" in res.fits["yaw_rate"].extra


def test_with_the_wheel_speeds_removed_the_yaw_fit_matches_the_full_recording(truth, wide):
    """The yaw-rate method does not depend on the wheel speeds being there: its map without
    them lies within the full recording's yaw-rate interval widened by 1%."""
    full = identify_steering(wide, truth.vehicle).fits["yaw_rate"]
    alone = identify_steering(_without(wide, *WHEELS), truth.vehicle).fits["yaw_rate"]
    lo, hi = full.scale_ci95
    assert lo * 0.99 <= alone.scale <= hi * 1.01, (alone.scale, full.scale_ci95)


def test_no_method_with_its_channels_is_an_input_error_naming_them(truth):
    from hmpc.models.errors import InputError

    rec = simulate_experiment("arcs", truth, seed=SEED)
    with pytest.raises(InputError, match="wheel_speed_fl") as e:
        identify_steering(_without(rec, *WHEELS, "yaw_rate", "x"), truth.vehicle)
    assert "no channel 'yaw_rate'" in str(e.value) and "no channel 'x'" in str(e.value)
    # yaw rate and positions, but no speed at all: named as such
    with pytest.raises(InputError, match="no channel 'speed' and no channel 'gps_speed'"):
        identify_steering(_without(rec, *WHEELS, "speed", "gps_speed"), truth.vehicle)


def test_replay_alone_needs_only_positions_heading_and_a_speed(truth, wide):
    res = identify_steering(_without(wide, *WHEELS, "yaw_rate"), truth.vehicle)
    assert list(res.fits) == ["position_replay"]
    assert set(res.report["selection"]["skipped"]) == {"wheel_speed_difference", "yaw_rate"}
    assert res.report["dead_time"]["used"] is False


def test_yaw_rate_only_reasons_are_computed_from_its_data(truth):
    """The ramps without wheel speeds: the yaw-rate path's verdict names the measured
    steering-wheel range, and its gyro-bias check carries the fit's own correlation."""
    rec = _without(simulate_experiment("ramps", truth, seed=SEED), *WHEELS)
    res = identify_steering(rec, truth.vehicle)
    assert "yaw_rate" in res.fits
    by_fit = res.report["identifiability_by_fit"]["yaw_rate"]
    assert by_fit["identifiable"] is False and "steering-wheel range" in by_fit["note"]
    lo, hi = res.report["steering_wheel_range_rad"]
    checks = {c["name"]: c for c in res.report["identifiability"]["checks"]}
    assert res.method == "yaw_rate", res.report["selection"]  # the replay is untrusted here
    bias = checks["offset_gyro_bias_correlation"]
    assert bias["value"] == pytest.approx(
        abs(res.fits["yaw_rate"].extra["offset_bias_correlation"])
    )
    assert checks["steering_range_rad"]["passed"] is False
    assert checks["steering_range_rad"]["value"] <= hi - lo + 1e-12


def test_gyro_bias_reason_only_for_a_fit_that_estimates_a_bias():
    yaw = _fit(method="yaw_rate", extra={"offset_bias_correlation": 0.99})
    n = 5000
    sw, v = np.linspace(-3.0, 3.0, n), np.full(n, 3.0)
    bad = _verdict(sw, v, yaw)
    checks = {c["name"]: c for c in bad["checks"]}
    assert checks["offset_gyro_bias_correlation"]["value"] == pytest.approx(0.99)
    assert not bad["offset_identifiable"] and bad["scale_identifiable"]
    assert "yaw-rate sensor's bias" in bad["note"]
    good = _verdict(sw, v, _fit(method="yaw_rate", extra={"offset_bias_correlation": 0.5}))
    assert good["identifiable"], good["note"]
    assert "offset_gyro_bias_correlation" not in {c["name"] for c in _verdict(sw, v)["checks"]}


# ---- the dead time is decided by held-out prediction
def _delay_data(lag, seed):
    rng = np.random.default_rng(seed)
    n = 6000
    sw = np.convolve(rng.normal(size=n + 400), np.ones(100) / 10, mode="same")[200:-200]
    meas = (
        0.01
        + 0.08 * np.concatenate([np.full(lag, sw[0]), sw[: n - lag]])
        + 0.002 * rng.normal(size=n)
    )
    return sw, meas


@pytest.mark.parametrize("lag", [0, 5])
def test_dead_time_cv_uses_a_delay_only_when_it_predicts_better(lag):
    from hmpc.models.identify.steering import SteeringIdConfig, dead_time_cv

    dt = 0.02
    for seed in range(5):
        sw, meas = _delay_data(lag, seed)
        cv = dead_time_cv(sw, meas, np.ones(len(sw), bool), dt, SteeringIdConfig())
        lo, hi = cv["interval_s"]
        assert lo <= lag * dt <= hi, (seed, cv)
        assert cv["used"] is (lag > 0), (seed, cv)
        if lag:
            assert cv["best_s"] == pytest.approx(lag * dt, abs=0.5 * dt)
        assert hi - lo <= 3 * dt


# ---- each identifiability reason is computed from the data it describes
def _fit(**kw):
    from hmpc.models.identify.steering import MapFit

    base = dict(
        method="wheel_speed_difference",
        offset_rad=0.01,
        scale=0.08,
        offset_ci95_rad=(0.0099, 0.0101),
        scale_ci95=(0.0799, 0.0801),
        corr=0.1,
        samples=5000,
        rms_error=1e-4,
        rms_unit="rad",
        ci_method="test",
    )
    base.update(kw)
    return MapFit(**base)


def _verdict(sw, v, fit=None):
    from hmpc.models.identify.steering import SteeringIdConfig, identifiability

    return identifiability(fit or _fit(), np.asarray(sw), np.asarray(v), 0.02, SteeringIdConfig())


def test_slow_steering_that_is_too_short_is_not_called_fast():
    """Every sample at 2.2-2.5 m/s but only 4 s of them (a real Civic log had 1.8 s): the note
    must say 'only 4.0 s', never 'above 10 m/s', which it used to print."""
    rng = np.random.default_rng(3)
    n = 200  # 4 s at 50 Hz: fewer than the samples and the kinematic seconds needed
    res = _verdict(np.linspace(-3.0, 3.0, n), rng.uniform(2.2, 2.5, n))
    checks = {c["name"]: c for c in res["checks"]}
    assert not checks["kinematic_speed_s"]["passed"] and not checks["samples"]["passed"]
    assert "above" not in res["note"]
    assert "only 4.0 s" in res["note"] and "2.2-2.5 m/s" in res["note"]


def test_fast_steering_is_called_fast_with_its_speeds():
    from hmpc.models.identify.steering import SteeringIdConfig

    cfg = SteeringIdConfig()
    n = 4 * int(cfg.min_trustworthy_s / 0.02)
    res = _verdict(np.linspace(-3.0, 3.0, n), np.full(n, cfg.kinematic_speed_mps + 5.0))
    assert not res["scale_identifiable"]
    assert f"above {cfg.kinematic_speed_mps:g} m/s" in res["note"]


def test_small_steering_range_is_named_with_its_measured_range():
    n = 5000
    sw = np.radians(np.linspace(-0.5, 0.5, n))
    res = _verdict(sw, np.full(n, 3.0))
    measured = np.degrees(np.subtract(*np.percentile(sw, [97.5, 2.5])))  # 0.95 deg
    assert not res["identifiable"]
    assert f"range ({measured:.1f} deg)" in res["note"] and "offset" in res["note"]


# ---- a rounded yaw rate on steady arcs (a CAN channel with no dither)
def _rounded_arcs(seed, q):
    """Four steady arcs at 2.3-3.0 m/s joined by 2 s ramps, 50 Hz, the yaw rate of eq. 1 with
    a random map and a small gyro bias, rounded to ``q`` with no noise (the vehicle node's
    KINEMATICS yaw rate: one reading per arc)."""
    rng = np.random.default_rng(seed)
    b = 2.65
    off, scale, bias = rng.uniform(0.01, 0.03), rng.uniform(0.06, 0.09), rng.uniform(-1e-3, 1e-3)
    sw_lv = rng.permutation([-4.0, -2.5, 2.5, 4.0]) + rng.uniform(-0.2, 0.2, 4)
    v_lv = rng.uniform(2.3, 3.0, 4)
    sw, v = [np.full(100, 0.0)], [np.full(100, v_lv[0])]
    for k in range(4):
        sw.append(np.linspace(sw[-1][-1], sw_lv[k], 100))
        v.append(np.linspace(v[-1][-1], v_lv[k], 100))
        sw.append(np.full(500, sw_lv[k]))
        v.append(np.full(500, v_lv[k]))
    sw, v = np.concatenate(sw), np.concatenate(v)
    yaw = bias + v * np.tan(off + scale * sw) / b
    return np.round(yaw / q) * q, v, sw, b, off


def test_quantisation_step_is_read_from_the_levels_and_only_from_a_rounded_channel():
    q = np.deg2rad(0.244)
    yaw, *_ = _rounded_arcs(0, q)
    # the grid interpolates between readings: in-between values are not levels
    t = np.arange(len(yaw)) * 0.02
    grid = np.interp(t + 0.007, t, yaw)
    assert quantisation_step(grid) == pytest.approx(q, rel=1e-9)
    rng = np.random.default_rng(1)
    assert quantisation_step(np.repeat(rng.normal(0.0, 0.05, 500), 2)) is None  # held float
    assert quantisation_step(np.cumsum(rng.normal(0.0, 1e-3, 1000))) is None


def test_rounded_yaw_rate_interval_covers_the_offset_the_blocks_alone_miss():
    """The rounding of one reading per arc goes into bias and offset and leaves no residual:
    the time-block interval alone covers the true offset on 19 of 60 seeded arcs, with the
    rounding term on 55 (95 % nominal; at least 54 asserted), and not by being absurd. (At
    2.3-3.0 m/s the offset and the gyro bias are nearly one parameter: the intervals are wide,
    as wide as the errors.)"""
    from hmpc.models.identify.steering import fits as st

    q = np.deg2rad(0.244)
    hit, hit_blocks, width, err = 0, 0, [], []
    real = st.quantisation_step
    for seed in range(60):
        yaw, v, sw, b, off = _rounded_arcs(seed, q)
        steady = np.ones(len(yaw), dtype=bool)
        fit = st._fit_yaw(yaw, v, sw, steady, b, (off, 0.08))
        hit += fit.offset_ci95_rad[0] <= off <= fit.offset_ci95_rad[1]
        width.append(0.5 * (fit.offset_ci95_rad[1] - fit.offset_ci95_rad[0]))
        err.append(abs(fit.offset_rad - off))
        try:
            st.quantisation_step = lambda x: None
            blk = st._fit_yaw(yaw, v, sw, steady, b, (off, 0.08))
        finally:
            st.quantisation_step = real
        hit_blocks += blk.offset_ci95_rad[0] <= off <= blk.offset_ci95_rad[1]
    spread = np.percentile(err, 95)
    print(
        "coverage with rounding",
        hit,
        "blocks only",
        hit_blocks,
        "median half-width",
        np.median(width),
        "95th percentile of the error",
        spread,
    )
    assert hit >= 54
    assert hit_blocks < hit
    # honest, not absurd: the typical half-width is of the size of the errors it covers
    assert 0.5 * spread < np.median(width) < 2.0 * spread
