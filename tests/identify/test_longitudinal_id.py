"""Zone models (eq. 8 + brake): zone assignment, standstill and boundaries, the matched
smoothing, dead time, FOS term choice, unexercised inputs and speeds above the last zone."""

import numpy as np
import pytest

from hmpc.models.sim.effects import parse_effect
from hmpc.models.identify.pipeline import concat_recordings
from hmpc.models.identify.longitudinal import (
    LongitudinalIdConfig,
    assign_zones,
    identify_longitudinal,
    speed_rmse,
)
from hmpc.models.params import load_params
from hmpc.models.sim.simulator import simulate_experiment
from hmpc.models.identify.stats import apply_kernel, matched_kernels
from _data import PARAMS_DIR

SEED = 9
ZONES = (("idle", 0.0, 2.0), ("low", 2.0, 5.0), ("high", 5.0, 20.0))
LONG_EXPS = ("ramps", "ramp_sequence", "open_loop")


@pytest.fixture(scope="module")
def truth():
    return load_params(PARAMS_DIR / "report_2008.yaml")


def test_zone_assignment_follows_the_report_boundaries():
    v = np.array([0.0, 1.0, 2.0, 2.0001, 5.0, 5.01, 20.0, 20.5, np.nan])
    assert assign_zones(v, ZONES).tolist() == [0, 0, 0, 1, 1, 2, 2, -1, -1]
    # with hysteresis a speed hovering on a boundary keeps its zone
    v = np.array([1.9, 2.05, 1.98, 2.1, 2.3, 2.05, 1.9, 1.7])
    assert assign_zones(v, ZONES, 0.25).tolist() == [0, 0, 0, 0, 1, 1, 1, 0]


def test_matched_kernel_makes_filtered_eq8_exact():
    """d/dt of a speed driven by eq. 8 equals eq. 8 on the matched-smoothed pedal, even at
    steps; the plain Savitzky-Golay smoother of the pedal does not."""
    from scipy.signal import savgol_filter

    dt = 0.02
    u = np.zeros(1000)
    u[200:400] = 0.4
    u[600:650] = np.linspace(0, 0.3, 50)
    u[650:800] = 0.3
    a = 0.2 + 2.5 * u
    v = 3.0 + np.concatenate([[0.0], np.cumsum(0.5 * dt * (a[1:] + a[:-1]))])
    d, g = matched_kernels(dt, 0.5)
    lhs, rhs = apply_kernel(v, d), 0.2 + 2.5 * apply_kernel(u, g)
    ok = np.isfinite(lhs)
    assert np.max(np.abs(lhs[ok] - rhs[ok])) < 1e-9
    naive = 0.2 + 2.5 * savgol_filter(u, len(d), 2)
    assert np.max(np.abs(lhs[ok] - naive[ok])) > 0.05


def test_speed_rmse_is_zero_for_the_true_model_and_restarts_runs():
    dt = 0.02
    a = np.where(np.arange(600) < 300, 1.0, -0.5)
    v = 2.0 + np.concatenate([[0.0], np.cumsum(0.5 * dt * (a[1:] + a[:-1]))])
    m = np.ones(600, bool)
    assert speed_rmse(v, a, m, dt, 10.0) < 1e-12
    assert speed_rmse(v, a + 0.1, m, dt, 2.0) < speed_rmse(v, a + 0.1, m, dt, 10.0)


def test_noise_free_recordings_give_the_truth_exactly(truth):
    rec = concat_recordings(
        [simulate_experiment(n, truth, seed=SEED, noise="none") for n in LONG_EXPS]
    )
    res = identify_longitudinal(rec, truth.vehicle)
    for z, t in zip(res.zones, truth.zones):
        assert z.offset_mps2 == pytest.approx(t.offset_mps2, abs=0.005), z.name
        assert z.scale_mps2 == pytest.approx(t.scale_mps2, rel=0.005), z.name
        assert z.brake_scale_mps2 == pytest.approx(t.brake_scale_mps2, rel=0.005), z.name
    st = res.report["standstill"]
    assert st["samples"] > 0 and "excluded" in st["note"]
    assert res.report["boundary_samples_excluded"] > 0


def test_speeds_above_the_last_zone_are_counted_not_dropped(truth):
    rec = simulate_experiment("ramps", truth, seed=SEED)  # ramps reach 8 m/s
    cfg = LongitudinalIdConfig(zones=(("idle", 0.0, 2.0), ("low", 2.0, 5.0)))
    res = identify_longitudinal(rec, truth.vehicle, cfg)
    above = res.report["above_last_zone"]
    v = res.series["v_mps"]
    assert above["samples"] == int(np.sum(v > 5.0)) > 0
    assert above["seconds"] == pytest.approx(above["samples"] / rec.rate_hz)
    assert [z.name for z in res.zones] == ["idle", "low"]


def test_pedal_dead_time_and_drag_are_found(truth):
    fx = [parse_effect("pedal_dead_time:delay_s=0.3"), parse_effect("aero_drag:coeff_per_m=0.0005")]
    rec = concat_recordings(
        [simulate_experiment(n, truth, seed=SEED, effects=fx) for n in LONG_EXPS]
    )
    res = identify_longitudinal(rec, truth.vehicle)
    print(
        "dead time", res.dead_time_s, [(z["name"], z["fos"]["terms"]) for z in res.report["zones"]]
    )
    assert res.dead_time_s == pytest.approx(0.3, abs=0.03)
    # its held-out 95% interval holds the truth and not zero
    lo, hi = res.report["dead_time_ci95_s"]
    assert lo <= 0.3 <= hi and lo > 0.0 and hi - lo < 0.2, (lo, hi)
    assert res.report["dead_time_note"] is None
    high = next(z for z in res.report["zones"] if z["name"] == "high")
    # drag ~ v^2: FOS picks a speed term in the high zone where drag matters
    assert {"v^2", "v"} & set(high["fos"]["terms"])
    assert high["fos"]["nmse_pct"] < high["nmse_pct"]


def test_accel_x_source_is_used_and_named(truth):
    rec = concat_recordings([simulate_experiment(n, truth, seed=SEED) for n in LONG_EXPS])
    res = identify_longitudinal(rec, truth.vehicle, LongitudinalIdConfig(accel_source="accel_x"))
    assert res.accel_source.startswith("accel_x")
    for z, t in zip(res.zones, truth.zones):
        # INS accel_x carries a bias of up to 0.02 m/s^2 and white noise: measured offset
        # errors -0.004/-0.005/-0.011 m/s^2 and scale errors 0.36/0.52/0.50%; bounds 0.02 m/s^2
        # (the bias) and 1% (margin 2x; the acceptance's 0.05 m/s^2 and 5% stay the outer bound)
        assert z.offset_mps2 == pytest.approx(t.offset_mps2, abs=0.02), z.name
        assert z.scale_mps2 == pytest.approx(t.scale_mps2, rel=0.01), z.name


def test_unexercised_brake_is_flagged_not_invented(truth):
    rec = simulate_experiment("ramps", truth, seed=SEED)
    rec.channels["brake_pedal"] = np.zeros(len(rec))
    res = identify_longitudinal(rec, truth.vehicle)
    for z in res.zones:
        assert z.identifiable is False
        assert "brake" in z.note and "prior" in z.note
        assert z.brake_scale_mps2 == LongitudinalIdConfig().brake_scale_prior_mps2


def test_bad_zones_and_missing_pedal_are_input_errors(truth):
    from hmpc.models.errors import InputError

    rec = simulate_experiment("ramps", truth, seed=SEED)
    with pytest.raises(InputError, match="contiguous"):
        identify_longitudinal(
            rec, truth.vehicle, LongitudinalIdConfig(zones=(("a", 0.0, 2.0), ("b", 3.0, 5.0)))
        )
    del rec.channels["accel_pedal"]
    with pytest.raises(InputError, match="accel_pedal"):
        identify_longitudinal(rec, truth.vehicle)


def test_no_pedal_dead_time_is_reported_where_there_is_none(truth):
    """No delay simulated: the held-out evidence must not report one (below 2 samples, or
    "not determined" with 0 used); measured: best lag 0, interval [-0.01, 0.01] s."""
    rec = concat_recordings([simulate_experiment(n, truth, seed=SEED) for n in LONG_EXPS])
    res = identify_longitudinal(rec, truth.vehicle)
    lon = res.report
    print(lon["dead_time_estimate_s"], lon["dead_time_ci95_s"], lon["dead_time_note"])
    assert res.dead_time_s < 2 / rec.rate_hz
    assert lon["dead_time_note"] is None or "not determined" in lon["dead_time_note"]
    if lon["dead_time_ci95_s"] is not None:
        assert lon["dead_time_ci95_s"][0] <= 0.0


def test_braking_without_a_brake_channel_is_named_not_absorbed_silently(truth):
    """The car brakes but the recording has no brake channel: each zone says the braking is
    unobserved and that its offset and scale absorb it, lists those keys as not identified
    with the reason, and is not called identifiable."""
    rec = concat_recordings([simulate_experiment(n, truth, seed=SEED) for n in LONG_EXPS])
    del rec.channels["brake_pedal"]
    res = identify_longitudinal(rec, truth.vehicle)
    ni = res.report["not_identified"]
    for z, zr in zip(res.zones, res.report["zones"]):
        assert z.identifiable is False
        assert "no brake_pedal channel" in z.note and "no channel observes" in z.note, z.note
        assert zr["braking"]["decel_beyond_coasting_s"] >= 2.0
        for key in ("brake_scale_mps2", "offset_mps2", "scale_mps2"):
            assert "brake_pedal" in ni[f"zones.{z.name}.{key}"]


def test_coasting_without_a_brake_channel_does_not_claim_unobserved_braking(truth):
    """The open-loop programme's brake phases removed from the data (brake never pressed and
    no brake channel): no deceleration beyond coasting, so nothing is said to absorb it."""
    rec = simulate_experiment("ramps", truth, seed=SEED)
    braking = np.asarray(rec["brake_pedal"]) > 0.0
    keep = ~dilate_mask(braking, int(3 * rec.rate_hz))
    for k in list(rec.channels):
        if k not in ("time",) and rec.channels[k].dtype.kind == "f":
            rec.channels[k] = np.where(keep, rec.channels[k], np.nan)
    del rec.channels["brake_pedal"]
    res = identify_longitudinal(rec, truth.vehicle)
    for z in res.zones:
        if z.note:
            assert "no channel observes" not in z.note, z.note
    # nothing listed as absorbing braking (a zone without data still lists its copied values)
    ni = res.report["not_identified"]
    assert not [k for k, why in ni.items() if "no channel observes" in why], ni
    assert not [k for k, why in ni.items() if k.endswith(".offset_mps2") and "copied" not in why]


def dilate_mask(mask, n):
    from hmpc.models.identify.stats import dilate

    return dilate(mask, n, n)


def test_heldout_sse_equals_refitting_without_each_fold():
    """stats.heldout_sse from per-fold sums = an explicit refit per fold (seeded data)."""
    from hmpc.models.identify.stats import contiguous_fold_ids, heldout_sse, not_worse_than_best

    rng = np.random.default_rng(5)
    n, k = 600, 5
    X = np.column_stack([np.ones(n), rng.normal(size=n), rng.normal(size=n)])
    Y = np.column_stack(
        [
            X @ [0.3, 1.2, -0.7] + 0.1 * rng.normal(size=n),
            X @ [0.3, 1.3, -0.7] + 0.1 * rng.normal(size=n),
        ]
    )
    fold = contiguous_fold_ids(n, k)
    sse, cnt = heldout_sse(X, Y, fold, k, fit_col=0)
    for g in range(k):
        tr, te = fold != g, fold == g
        c = np.linalg.lstsq(X[tr], Y[tr, 0], rcond=None)[0]
        assert sse[g] == pytest.approx(np.sum((Y[te] - (X[te] @ c)[:, None]) ** 2, axis=0))
        assert cnt[g] == te.sum()
    # the fit to column 0 predicts column 1 (other scale) worse in every fold: beyond noise
    jb, within, _ = not_worse_than_best(np.array([sse[:, 0], sse[:, 1]]))
    assert jb == 0 and within.tolist() == [True, False]


def test_half_sample_kernels_bracket_the_matched_smoother():
    from hmpc.models.identify.stats import half_sample_kernels

    d, g = matched_kernels(0.02, 0.5)
    early, late = half_sample_kernels(d, 0.02)
    assert early.sum() == pytest.approx(1.0) and late.sum() == pytest.approx(1.0)
    assert np.allclose(0.5 * (early + late), g)


def test_a_zone_without_data_names_every_copied_value_and_its_source_zone(truth):
    """Samples of the low zone (2, 5] m/s removed from a simulated recording: the low zone is
    not fitted, and each of its written values is listed under not_identified with the zone
    it was copied from (the nearest fitted one: idle, the lower of two equally near); the
    fitted idle and high zones list nothing copied."""
    rec = concat_recordings([simulate_experiment(n, truth, seed=SEED) for n in LONG_EXPS])
    v = np.mean([np.asarray(rec[f"wheel_speed_{w}"]) for w in ("fl", "fr")], axis=0)
    gone = (v > 1.5) & (v <= 5.5)  # the low zone and a margin: no smoothing window reaches it
    for k in list(rec.channels):
        if k != "time" and rec.channels[k].dtype.kind == "f":
            rec.channels[k] = np.where(gone, np.nan, rec.channels[k])
    res = identify_longitudinal(rec, truth.vehicle)
    reps = {zr["name"]: zr for zr in res.report["zones"]}
    assert reps["low"]["samples"] == 0 and reps["idle"]["samples"] > 0 < reps["high"]["samples"]
    ni = res.report["not_identified"]
    for key in ("offset_mps2", "scale_mps2", "brake_scale_mps2"):
        why = ni[f"zones.low.{key}"]
        assert "no usable data" in why and "copied from zone 'idle'" in why, why
        assert reps["low"]["not_identified"][key] == why
    assert not [k for k, why in ni.items() if "copied" in why and not k.startswith("zones.low.")]
    assert {z.name: z.identifiable for z in res.zones}["low"] is False
