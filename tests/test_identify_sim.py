"""Known truth: identification recovers the simulator's parameters from every experiment.

Each parameter set (the report's values and three seeded random sets) drives all of the
report's experiments (models.sim, noise="typical": CAN quantisation, message rates and timing,
INS noise and biases); the recordings are joined and identified in one run.

Tolerances (issue 3): steering offset +-0.002 rad, scale +-2%; every zone's throttle scale
+-5% and offset +-0.05 m/s^2; brake scale +-5% (the same relative tolerance as the throttle).
"""
import pytest

from hmpc.models.identify.pipeline import concat_recordings, identify
from hmpc.models.params import load_params
from hmpc.models.sim.simulator import EXPERIMENTS, random_params, simulate_experiment
from hmpc.tools.datafiles import PARAMS_DIR

SIM_SEED = 11
SETS = ["report_2008", 1, 2, 3]


def _truth(which):
    if which == "report_2008":
        return load_params(PARAMS_DIR / "report_2008.yaml")
    return random_params(which)


@pytest.fixture(scope="module", params=SETS, ids=lambda s: f"params={s}")
def identified(request):
    truth = _truth(request.param)
    recs = [simulate_experiment(name, truth, seed=SIM_SEED, noise="typical")
            for name in EXPERIMENTS]
    rec = concat_recordings(recs)
    res = identify(rec, truth.vehicle)
    print(f"\nparams={request.param} sim seed={SIM_SEED}: {len(rec)} samples")
    return truth, res


def test_steering_map_recovered(identified):
    truth, res = identified
    st = res.params.steering
    err_off = st.offset_rad - truth.steering.offset_rad
    err_scale = st.scale / truth.steering.scale - 1.0
    print(f"steering [{st.method}]: offset {st.offset_rad:+.5f} (truth "
          f"{truth.steering.offset_rad:+.5f}, error {err_off:+.5f} rad), scale {st.scale:.5f} "
          f"(truth {truth.steering.scale:.5f}, error {100 * err_scale:+.3f}%)")
    assert abs(err_off) <= 0.002
    assert abs(err_scale) <= 0.02
    assert st.identifiable, st.note
    # the interval is finite and holds the estimate
    assert st.offset_ci95_rad[0] <= st.offset_rad <= st.offset_ci95_rad[1]
    assert st.scale_ci95[0] <= st.scale <= st.scale_ci95[1]
    # both direct measurements agree with the truth as well
    for name in ("wheel_speed_difference", "yaw_rate"):
        f = res.steering.fits[name]
        assert abs(f.offset_rad - truth.steering.offset_rad) <= 0.002, name
        assert abs(f.scale / truth.steering.scale - 1.0) <= 0.02, name
    # no dead time was simulated: the estimate must be near zero (message timing only)
    assert abs(st.dead_time_s) <= 0.03


def test_every_zone_recovered(identified):
    truth, res = identified
    assert [z.name for z in res.params.zones] == [z.name for z in truth.zones]
    for z, t in zip(res.params.zones, truth.zones):
        e_off = z.offset_mps2 - t.offset_mps2
        e_sc = z.scale_mps2 / t.scale_mps2 - 1.0
        e_br = z.brake_scale_mps2 / t.brake_scale_mps2 - 1.0
        print(f"zone {z.name}: offset error {e_off:+.4f} m/s^2, scale error {100 * e_sc:+.2f}%, "
              f"brake error {100 * e_br:+.2f}%, NMSE {z.nmse_pct:.2f}%, speed RMSE "
              f"{z.speed_rmse_mps:.3f} m/s")
        assert abs(e_off) <= 0.05, z.name
        assert abs(e_sc) <= 0.05, z.name
        assert abs(e_br) <= 0.05, z.name
        assert z.identifiable, z.note
        assert 0.0 <= z.nmse_pct < 5.0          # the model is the truth: tiny residual
        assert z.speed_rmse_mps < 0.1
    assert res.params.longitudinal_dead_time_s == pytest.approx(0.0, abs=0.05)


def test_fos_selects_exactly_the_true_terms(identified):
    _, res = identified
    for zr in res.report["longitudinal"]["zones"]:
        assert set(zr["fos"]["terms"]) == {"1", "accel_pedal", "brake_pedal"}, zr["name"]
