"""Known truth: identification recovers the simulator's parameters from every experiment.

Each parameter set (the report's values and three seeded random sets) drives all of the
report's experiments (models.sim, noise="typical": CAN quantisation, message rates and timing,
INS noise and biases); the recordings are joined and identified in one run.

Tolerances: near what the code achieves (measured over the four sets, sim seed 11), with the
margin stated beside each; the acceptance tolerances (steering offset +-0.002 rad, scale
+-2%; zone scales +-5%, offsets +-0.05 m/s^2) remain the outer bound and are far looser.
The figures docs/results.md states under "Known truth" are the tolerances below.
"""

import pytest

from hmpc.models.identify.pipeline import concat_recordings, identify
from hmpc.models.params import load_params
from hmpc.models.sim.plans import EXPERIMENTS
from hmpc.models.sim.simulator import random_params, simulate_experiment
from _data import PARAMS_DIR

SIM_SEED = 11
SETS = ["report_2008", 1, 2, 3]

# Measured worst case over SETS -> tolerance (docs/results.md "Known truth" states these).
# measured 0.00032 rad (params=2; the held-out choice takes the yaw-rate fit, whose interval
# covers the truth in all four sets; the replay's 0.00017 came with intervals that missed it
# in three)
STEER_OFFSET_TOL_RAD = 0.0004
STEER_SCALE_TOL = 0.0005  # measured 0.035%, margin 1.4x
DIRECT_OFFSET_TOL_RAD = 0.0005  # (a)/(b) fits: measured 0.00032 rad, margin 1.5x
DIRECT_SCALE_TOL = 0.0015  # (a)/(b) fits: measured 0.073%, margin 2x
STEER_DEAD_TIME_TOL_S = 0.01  # measured -0.0052 s (none simulated), margin 2x
ZONE_COEF_TOL = 0.003  # scale, brake scale: measured 0.28%, margin 1.1x
ZONE_OFFSET_TOL_MPS2 = 0.002  # measured 0.00056 m/s^2, margin 3.5x
ZONE_NMSE_MAX_PCT = 0.1  # measured 0.020%, margin 5x (the model is the truth)
ZONE_SPEED_RMSE_MAX_MPS = 0.02  # measured 0.0084 m/s, margin 2.4x
LON_DEAD_TIME_TOL_S = 0.02  # measured 0.000 s (none simulated), one 50 Hz sample

# Every 95% interval covers the truth: the zone intervals add the half-sample pedal timing
# bound (models.identify.longitudinal.ols_timed) to the HAC interval; measured: the largest
# error 0.77 half-widths (without that bound, 4 of the 36 zone intervals miss, by up to 1.13).
# A set listed here must miss, so a regression that is accepted shows up by name.
KNOWN_INTERVAL_MISSES: dict = {}


def _truth(which):
    if which == "report_2008":
        return load_params(PARAMS_DIR / "report_2008.yaml")
    return random_params(which)


@pytest.fixture(scope="module", params=SETS, ids=lambda s: f"params={s}")
def identified(request):
    truth = _truth(request.param)
    recs = [
        simulate_experiment(name, truth, seed=SIM_SEED, noise="typical") for name in EXPERIMENTS
    ]
    rec = concat_recordings(recs)
    res = identify(rec, truth.vehicle)
    print(f"\nparams={request.param} sim seed={SIM_SEED}: {len(rec)} samples")
    return truth, res


def _interval_misses(truth, params) -> dict[str, str]:
    """Every 95% interval of ``params`` that does not cover ``truth``: name -> what it says."""
    st, ts = params.steering, truth.steering
    items = [
        ("steering offset", st.offset_ci95_rad, ts.offset_rad),
        ("steering scale", st.scale_ci95, ts.scale),
    ]
    for z, t in zip(params.zones, truth.zones):
        items += [
            (f"zone {z.name} offset", z.offset_ci95_mps2, t.offset_mps2),
            (f"zone {z.name} scale", z.scale_ci95_mps2, t.scale_mps2),
            (f"zone {z.name} brake scale", z.brake_scale_ci95_mps2, t.brake_scale_mps2),
        ]
    misses = {}
    for name, ci, true in items:
        assert ci is not None and ci[0] < ci[1], f"{name}: no interval {ci}"
        if not ci[0] <= true <= ci[1]:
            misses[name] = f"[{ci[0]:.6g}, {ci[1]:.6g}] misses the truth {true:.6g}"
    return misses


def test_steering_map_recovered(identified):
    truth, res = identified
    st = res.params.steering
    err_off = st.offset_rad - truth.steering.offset_rad
    err_scale = st.scale / truth.steering.scale - 1.0
    print(
        f"steering [{st.method}]: offset {st.offset_rad:+.5f} (truth "
        f"{truth.steering.offset_rad:+.5f}, error {err_off:+.5f} rad), scale {st.scale:.5f} "
        f"(truth {truth.steering.scale:.5f}, error {100 * err_scale:+.3f}%)"
    )
    assert abs(err_off) <= STEER_OFFSET_TOL_RAD
    assert abs(err_scale) <= STEER_SCALE_TOL
    assert st.identifiable, st.note
    # both direct measurements agree with the truth as well
    for name in ("wheel_speed_difference", "yaw_rate"):
        f = res.steering.fits[name]
        assert abs(f.offset_rad - truth.steering.offset_rad) <= DIRECT_OFFSET_TOL_RAD, name
        assert abs(f.scale / truth.steering.scale - 1.0) <= DIRECT_SCALE_TOL, name
    # no dead time was simulated: the estimate must be near zero (message timing only)
    assert abs(st.dead_time_s) <= STEER_DEAD_TIME_TOL_S


def test_every_zone_recovered(identified):
    truth, res = identified
    assert [z.name for z in res.params.zones] == [z.name for z in truth.zones]
    for z, t in zip(res.params.zones, truth.zones):
        e_off = z.offset_mps2 - t.offset_mps2
        e_sc = z.scale_mps2 / t.scale_mps2 - 1.0
        e_br = z.brake_scale_mps2 / t.brake_scale_mps2 - 1.0
        print(
            f"zone {z.name}: offset error {e_off:+.4f} m/s^2, scale error {100 * e_sc:+.2f}%, "
            f"brake error {100 * e_br:+.2f}%, NMSE {z.nmse_pct:.2f}%, speed RMSE "
            f"{z.speed_rmse_mps:.3f} m/s"
        )
        assert abs(e_off) <= ZONE_OFFSET_TOL_MPS2, z.name
        assert abs(e_sc) <= ZONE_COEF_TOL, z.name
        assert abs(e_br) <= ZONE_COEF_TOL, z.name
        assert z.identifiable, z.note
        assert 0.0 <= z.nmse_pct < ZONE_NMSE_MAX_PCT  # the model is the truth: tiny residual
        assert z.speed_rmse_mps < ZONE_SPEED_RMSE_MAX_MPS
    assert res.params.longitudinal_dead_time_s == pytest.approx(0.0, abs=LON_DEAD_TIME_TOL_S)


def test_every_interval_covers_the_truth(identified, request):
    """A 95% interval must hold the value that generated the data, not only its own estimate."""
    truth, res = identified
    which = request.node.callspec.params["identified"]
    misses = _interval_misses(truth, res.params)
    for name, what in misses.items():
        print(f"params={which}: {name} 95% interval {what}")
    known = KNOWN_INTERVAL_MISSES.get(which, set())
    assert set(misses) <= known, f"new interval misses: {sorted(set(misses) - known)}"
    if known:
        assert set(misses) == known, (
            f"fixed, remove from KNOWN_INTERVAL_MISSES: {known - set(misses)}"
        )
        pytest.xfail(f"95% intervals too narrow: {'; '.join(sorted(misses))}")


def test_fos_selects_exactly_the_true_terms(identified):
    _, res = identified
    for zr in res.report["longitudinal"]["zones"]:
        assert set(zr["fos"]["terms"]) == {"1", "accel_pedal", "brake_pedal"}, zr["name"]
