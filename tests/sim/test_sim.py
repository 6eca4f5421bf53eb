"""The ground-truth simulator: repeatable, true to its parameters, quantised like the RAV4's CAN,
covering what each of the report's experiments should, and effects doing what they say.

Seeds are fixed (printed in the parametrisation). Noise level "none" gives ideal sensors, on
which the report's eqs. 1, 7 and 8 must hold exactly; "typical" is what identification sees.
"""

import json
import math

import numpy as np
import pytest

from hmpc.models.sim import effects as fx
from hmpc.models.sim import sensors as sn
from hmpc.models.logs.channels import CHANNELS
from hmpc.models.logs.dbc import load_dbc
from hmpc.models.errors import InputError, ParamError
from hmpc.models.params import Params, dump_params, load_params
from hmpc.models.plant import HybridPlant
from hmpc.models.logs.recording import Recording
from hmpc.models.sim.plans import DEFAULT_SW_MAX_RAD, EXPERIMENTS
from hmpc.models.sim.simulator import random_params, run_experiment, simulate_experiment
from _data import PARAMS_DIR, bundled

ALL_CHANNELS = [
    "time",
    "steering_wheel_angle",
    "wheel_speed_fl",
    "wheel_speed_fr",
    "wheel_speed_rl",
    "wheel_speed_rr",
    "speed",
    "accel_pedal",
    "brake_pedal",
    "gear",
    "engine_rpm",
    "yaw_rate",
    "accel_x",
    "accel_y",
    "x",
    "y",
    "z",
    "heading",
    "pitch",
    "roll",
    "gps_speed",
]


@pytest.fixture(scope="module")
def report() -> Params:
    return load_params(PARAMS_DIR / "report_2008.yaml", require_model=True)


def _zone_accel(p: Params, v, th, br):
    """Eq. 8 with brake of the zone holding each speed (no hysteresis)."""
    plant = HybridPlant(p, hysteresis_mps=0.0)
    z = np.array([plant.zone_by_speed(x) for x in v])
    return plant.z_offset[z] + plant.z_scale[z] * th - plant.z_brake[z] * br


def _lag_s(ref, sig, rate_hz, max_lag_s=1.0):
    """Delay of ``sig`` behind ``ref`` [s] by cross-correlation of their derivatives."""
    a, b = np.diff(ref), np.diff(sig)
    a, b = a - a.mean(), b - b.mean()
    lags = np.arange(0, int(max_lag_s * rate_hz) + 1)
    c = [np.dot(a[: len(a) - k], b[k:]) for k in lags]
    return lags[int(np.argmax(c))] / rate_hz


# ------------------------------------------------------------------------ determinism
def test_same_seed_same_recording_and_different_seed_differs(report):
    a = simulate_experiment("figure8", report, seed=7)
    b = simulate_experiment("figure8", report, seed=7)
    c = simulate_experiment("figure8", report, seed=8)
    assert list(a.channels) == list(b.channels) == ALL_CHANNELS
    for k in a.channels:
        assert np.array_equal(a[k], b[k]), k
    assert a.meta == b.meta
    assert not np.array_equal(a["x"], c["x"])
    assert a.meta["seed"] == 7 and a.meta["experiment"] == "figure8"
    assert a.meta["params"] == report.to_dict() and a.meta["effects"] == []
    assert json.loads(json.dumps(a.meta)) == a.meta  # plain JSON: the CLI can write it as is


def test_effect_objects_are_reusable_between_runs(report):
    e = [fx.SteeringDeadTime(0.2), fx.PedalDeadTime(0.1), fx.SteeringLag(0.1)]
    a = simulate_experiment("arcs", report, seed=1, effects=e)
    b = simulate_experiment("arcs", report, seed=1, effects=e)
    assert np.array_equal(a["yaw_rate"], b["yaw_rate"])
    assert np.array_equal(a["accel_x"], b["accel_x"])


# ---------------------------------------------------------------- truth, noise = "none"
@pytest.mark.parametrize("name", ["arcs", "circles", "figure8"])
def test_ideal_yaw_rate_is_eq1_with_eq7(report, name):
    r = simulate_experiment(name, report, seed=3, noise="none")
    delta = 0.017 + 0.08 * r["steering_wheel_angle"]
    expect = r["gps_speed"] * np.sin(delta) / 2.65
    np.testing.assert_allclose(r["yaw_rate"], expect, atol=1e-12)
    assert np.abs(r["yaw_rate"]).max() > 0.3  # the experiment really turns


@pytest.mark.parametrize("seed", [11, 12])
def test_ideal_wheel_speeds_follow_eqs_2_to_6(seed):
    p = random_params(seed)
    r = simulate_experiment("circles", p, seed=seed, noise="none")
    b, tf = p.vehicle.wheelbase_m, p.vehicle.track_front_m
    yaw, v = r["yaw_rate"], r["gps_speed"]
    delta = p.steering.offset_rad + p.steering.scale * r["steering_wheel_angle"]
    fl, fr, rl, rr = (r[f"wheel_speed_{w}"] for w in ("fl", "fr", "rl", "rr"))
    # rear axle: eq. 5 exact, and the exact inverse recovers the road-wheel angle
    np.testing.assert_allclose(rr - rl, yaw * tf, atol=1e-12)
    moving = v > 0.5
    np.testing.assert_allclose(
        sn.road_wheel_angle_from_rear(rl, rr, b, tf)[moving], delta[moving], atol=1e-9
    )
    # front axle: fr^2 - fl^2 = 2 r T v cos(delta) exactly; eq. 5 within 1 % at small angles
    np.testing.assert_allclose(fr**2 - fl**2, 2 * yaw * tf * v * np.cos(delta), atol=1e-10)
    small = moving & (np.abs(delta) < 0.14) & (np.abs(yaw) > 0.05)
    assert small.sum() > 100
    ratio = ((fr - fl) / tf)[small] / yaw[small]
    assert np.all(np.abs(ratio - 1) < 0.01)
    assert np.abs(delta).max() > 0.4  # full lock reached


@pytest.mark.parametrize("name,seed", [("ramps", 0), ("ramp_sequence", 5), ("open_loop", 6)])
def test_ideal_accel_x_is_the_zone_model_of_the_pedals(name, seed):
    p = random_params(seed)
    r = simulate_experiment(name, p, seed=seed, noise="none")
    v, th, br = r["gps_speed"], r["accel_pedal"], r["brake_pedal"]
    delta = p.steering.offset_rad + p.steering.scale * r["steering_wheel_angle"]
    edges = np.array([z.v_max_mps for z in p.zones[:-1]])
    away = np.min(np.abs(v[:, None] - edges[None, :]), axis=1) > 0.02
    sel = (v > 0.05) & away & (np.abs(delta) < 0.03)
    assert sel.sum() > 0.5 * len(v)
    err = r["accel_x"][sel] - _zone_accel(p, v[sel], th[sel], br[sel])
    assert np.abs(err).max() < 0.01
    # and the speed really integrates it: v(t) - v(0) = integral of accel along the path
    run = run_experiment(name, p, seed=seed, noise="none")
    tr = run.truth
    np.testing.assert_allclose(
        np.cumsum(tr["accel_mps2"])[:-1] * tr.dt_s, tr["v_mps"][1:], atol=1e-9
    )


def test_pedals_never_both_and_speed_never_negative(report):
    for name in EXPERIMENTS:
        run = run_experiment(name, report, seed=4)
        tr = run.truth
        assert not np.any((tr["accel_pedal"] > 0) & (tr["brake_pedal"] > 0)), name
        assert tr["v_mps"].min() >= 0.0, name
        r = run.recording  # the foot needs 0.25 s between pedals: longer than any message period
        assert not np.any((r["accel_pedal"] > 0) & (r["brake_pedal"] > 0)), name
        k = np.flatnonzero(tr["accel_pedal"] > 0)
        j = np.flatnonzero(tr["brake_pedal"] > 0)
        gaps = np.abs(k[:, None] - j[None, ::7]).min() if len(k) and len(j) else 10**9
        assert gaps * tr.dt_s >= 0.25 - 1e-9, name
        assert np.all(np.isfinite(np.column_stack([r[c] for c in ALL_CHANNELS if c != "gear"])))
        h = r["heading"]
        assert np.all((h > -np.pi) & (h <= np.pi)), name
        # pedal rates within the driver's limits (1 /s throttle, 1.5 /s brake)
        assert np.abs(np.diff(tr["accel_pedal"])).max() <= 1.0 * tr.dt_s + 1e-12
        assert np.abs(np.diff(tr["brake_pedal"])).max() <= 1.5 * tr.dt_s + 1e-12


# ----------------------------------------------------------------- CAN quantisation
def _on_grid(x, step, offset=0.0):
    k = (np.asarray(x) - offset) / step
    return np.abs(k - np.round(k)).max()


def test_typical_channels_carry_the_rav4_quantisation(report):
    r = simulate_experiment("arcs", report, seed=9)
    assert _on_grid(np.rad2deg(r["steering_wheel_angle"]), 0.1) < 1e-6
    for w in ("fl", "fr", "rl", "rr"):
        assert _on_grid(r[f"wheel_speed_{w}"] * 3.6, 0.01, -67.67) < 1e-6
    assert _on_grid(r["speed"] * 3.6 * 4, 0.01) < 1e-6  # mean of four 0.01 km/h values
    assert _on_grid(r["accel_pedal"] * 100, 0.5) < 1e-9
    assert _on_grid(r["brake_pedal"] * 100, 0.5) < 1e-9
    assert _on_grid(r["engine_rpm"], 0.78125) < 1e-9
    assert len(np.unique(r["accel_pedal"])) > 20  # pedal really varies
    assert set(np.unique(r["gear"])) == {"D"}
    # the recording's steps are the DBC's (independent source: the RAV4 DBC via cantools)
    db = load_dbc(bundled("dbc/toyota_rav4_2017.dbc.gz"))
    for sig in sn.CAN_SIGNALS:
        if sig.channel in ("steering_wheel_angle", "brake_pedal"):
            continue
        s = db.get_message_by_name(sig.message).get_signal_by_name(sig.signal)
        assert (s.scale, s.offset, s.unit) == (sig.step_dbc, sig.offset_dbc, sig.unit_dbc), sig
    sa = db.get_message_by_name("STEER_ANGLE_SENSOR")
    assert sa.get_signal_by_name("STEER_ANGLE").scale == 1.5
    assert sa.get_signal_by_name("STEER_FRACTION").scale == 0.1


def test_quantisation_equals_cantools_encode_decode():
    db = load_dbc(bundled("dbc/toyota_rav4_2017.dbc.gz"))
    rng = np.random.default_rng(1)
    msg = db.get_message_by_name("WHEEL_SPEEDS")
    wheels = {
        "WHEEL_SPEED_FL": "wheel_speed_fl",
        "WHEEL_SPEED_FR": "wheel_speed_fr",
        "WHEEL_SPEED_RL": "wheel_speed_rl",
        "WHEEL_SPEED_RR": "wheel_speed_rr",
    }
    sigs = {s.channel: s for s in sn.CAN_SIGNALS}
    for v in rng.uniform(0.0, 20.0, (50, 4)):
        v = v + 0.0003  # keep away from exact half counts, where rounding conventions differ
        frame = msg.encode({k: x * 3.6 for k, x in zip(wheels, v)}, scaling=True)
        dec = msg.decode(frame)
        for (k, ch), x in zip(wheels.items(), v):
            assert dec[k] / 3.6 == pytest.approx(float(sn.quantise_dbc(x, sigs[ch])), abs=1e-12)
    angles = rng.uniform(-480, 480, 300)
    q = sn.steer_angle_sensor_deg(angles)
    assert np.abs(q - angles).max() <= 0.05 + 1e-9
    assert _on_grid(q, 0.1) < 1e-9


def test_can_messages_have_the_real_rates_and_are_held(report):
    r = simulate_experiment("ramps", report, seed=2)
    for ch, period in (
        ("wheel_speed_fl", 1 / 83.3),
        ("accel_pedal", 1 / 31.5),
        ("brake_pedal", 1 / 41.5),
        ("engine_rpm", 1 / 42.5),
    ):
        t, _ = r.raw[ch]
        assert np.median(np.diff(t)) == pytest.approx(period, rel=0.02), ch
    t, v = r.raw["accel_pedal"]  # zero-order hold: each grid value is the last message
    i = np.searchsorted(t, r["time"], side="right") - 1
    np.testing.assert_array_equal(r["accel_pedal"], v[i])
    assert r.raw["x"][0][1] - r.raw["x"][0][0] == pytest.approx(0.01)  # INS at 100 Hz


def test_typical_ins_noise_has_the_documented_size(report):
    clean = run_experiment("arcs", report, seed=5, noise="quantised").recording
    noisy = run_experiment("arcs", report, seed=5).recording
    bias = noisy.meta["sensor_truth"]
    e_yaw = noisy["yaw_rate"] - clean["yaw_rate"]
    assert abs(e_yaw.mean() - bias["yaw_rate_bias_radps"]) < 0.0005
    assert np.std(e_yaw) == pytest.approx(0.005, rel=0.1)
    assert abs(bias["yaw_rate_bias_radps"]) <= 0.002
    assert np.std(noisy["accel_x"] - clean["accel_x"]) == pytest.approx(0.05, rel=0.1)
    assert 0.005 < np.std(noisy["x"] - clean["x"]) < 0.04
    dh = np.angle(np.exp(1j * (noisy["heading"] - clean["heading"])))
    assert 0.0003 < np.std(dh) < 0.004  # ~0.1 deg
    assert noisy.meta["sensor_truth"] != clean.meta["sensor_truth"]


# ------------------------------------------------------------------------- coverage
@pytest.mark.parametrize("name", ["ramps", "ramp_sequence", "open_loop"])
def test_longitudinal_experiments_exercise_every_zone_with_both_pedals(report, name):
    for p in (report, random_params(21)):
        cov = run_experiment(name, p, seed=21).recording.meta["coverage"]
        for zname, z in cov["zones"].items():
            assert z["throttle_s"] >= 3.0 and z["brake_s"] >= 2.0, (name, zname, z)
            assert z["throttle_max"] >= 0.12, (name, zname, z)
        assert 60.0 <= cov["duration_s"] <= 130.0


def test_arcs_run_at_the_reports_speeds_with_steps_both_ways(report):
    run = run_experiment("arcs", report, seed=1)
    r = run.recording
    t, v = r["time"], r["gps_speed"]
    found = set()
    for seg in r.meta["segments"]:
        if not seg["label"].startswith("arc "):
            continue
        sel = (t >= seg["t_start_s"]) & (t < seg["t_end_s"])
        speed = float(seg["label"].split()[2])
        assert abs(np.mean(v[sel]) - speed) < 0.2, seg
        found.add((seg["label"].split()[1], speed))
    assert found == {("cw", 2.8), ("ccw", 2.4), ("cw", 5.2), ("ccw", 5.2)}
    bands = r.meta["coverage"]["steering_by_speed"]
    assert bands["2-5 m/s"]["sw_min_rad"] <= -4.9 and bands["2-5 m/s"]["sw_max_rad"] >= 4.9
    assert bands["5-20 m/s"]["sw_min_rad"] <= -2.9 and bands["5-20 m/s"]["sw_max_rad"] >= 2.9
    assert 90.0 <= r.meta["duration_s"] <= 130.0


def test_circles_reach_full_lock_both_ways_at_two_speeds(report):
    r = simulate_experiment("circles", report, seed=1)
    bands = r.meta["coverage"]["steering_by_speed"]
    for band in ("0.5-2 m/s", "2-5 m/s"):
        assert bands[band]["sw_min_rad"] == pytest.approx(-DEFAULT_SW_MAX_RAD, abs=0.01)
        assert bands[band]["sw_max_rad"] == pytest.approx(DEFAULT_SW_MAX_RAD, abs=0.01)
    # each full-lock hold turns the car through a full circle (heading change 2 pi)
    run = run_experiment("circles", report, seed=1, noise="none")
    psi, t = run.truth["psi_rad"], run.truth["t_s"]
    for seg in run.recording.meta["segments"]:
        if "full lock" in seg["label"]:
            k0, k1 = np.searchsorted(t, [seg["t_start_s"], seg["t_end_s"] - 1e-9])
            assert abs(abs(psi[k1] - psi[k0]) - 2 * np.pi) < 0.25, seg


def test_figure8_turns_both_ways_at_a_steady_speed_in_low_gear(report):
    r = simulate_experiment("figure8", report, seed=2)
    v, yaw = r["gps_speed"], r["yaw_rate"]
    cruise = v > 2.5
    assert 3.2 < np.mean(v[cruise]) < 3.8 and np.std(v[cruise]) < 0.4
    assert yaw[cruise].max() > 0.3 and yaw[cruise].min() < -0.3
    assert set(np.unique(r["gear"])) == {"L"}
    dsw = np.diff(r["steering_wheel_angle"])[cruise[1:] & cruise[:-1]]
    assert np.abs(dsw).max() < 0.2  # smooth: no jumps (6 rad/s over two 83 Hz messages + jitter)
    tr = run_experiment("figure8", report, seed=2).truth
    assert np.abs(np.diff(tr["sw_rad"])).max() <= 6.0 * tr.dt_s + 1e-12  # the rate limit


def test_steering_angle_range_scales_with_the_vehicle_file():
    p = random_params(3)
    p.vehicle.steering_wheel_angle_max_rad = 7.0
    r = simulate_experiment("circles", p, seed=3, noise="none")
    assert np.abs(r["steering_wheel_angle"]).max() == pytest.approx(7.0)


# -------------------------------------------------------------------------- effects
def test_steering_dead_time_delays_the_yaw_response(report):
    base = simulate_experiment("arcs", report, seed=1, noise="none", rate_hz=100.0)
    late = simulate_experiment(
        "arcs", report, seed=1, noise="none", rate_hz=100.0, effects=[fx.SteeringDeadTime(0.25)]
    )
    for r, expect in ((base, 0.0), (late, 0.25)):
        pred = r["gps_speed"] * np.sin(0.017 + 0.08 * r["steering_wheel_angle"]) / 2.65
        assert _lag_s(pred, r["yaw_rate"], 100.0) == pytest.approx(expect, abs=0.011)
    assert late.meta["effects"] == [{"type": "steering_dead_time", "delay_s": 0.25}]


def test_steering_lag_is_first_order_with_its_time_constant(report):
    tau = 0.3
    run = run_experiment("arcs", report, seed=1, noise="none", effects=[fx.SteeringLag(tau)])
    tr = run.truth
    sw, eff = tr["sw_rad"], tr["sw_eff_rad"]
    # eff[k+1] - eff[k] = a (sw[k] - eff[k]) with a = 1 - exp(-dt/tau): fit a from the data
    x, y = sw[:-1] - eff[:-1], np.diff(eff)
    a = float(np.dot(x, y) / np.dot(x, x))
    assert -tr.dt_s / math.log(1 - a) == pytest.approx(tau, rel=0.01)
    r = run.recording  # visible in the recording as a lag of the yaw rate behind the wheel
    pred = r["gps_speed"] * np.sin(0.017 + 0.08 * r["steering_wheel_angle"]) / 2.65
    assert 0.1 < _lag_s(pred, r["yaw_rate"], 50.0) < 0.5


def test_pedal_dead_time_delays_the_acceleration(report):
    d = 0.3
    r = simulate_experiment("ramps", report, seed=0, noise="none", effects=[fx.PedalDeadTime(d)])
    n = int(round(d * 50))
    v, th, br = r["gps_speed"], r["accel_pedal"], r["brake_pedal"]
    model_late = _zone_accel(report, v[n:], th[:-n], br[:-n])
    sel = (v[n:] > 0.3) & (np.abs(v[n:] - 2.0) > 0.05) & (np.abs(v[n:] - 5.0) > 0.05)
    assert np.abs(r["accel_x"][n:][sel] - model_late[sel]).max() < 0.02
    model_now = _zone_accel(report, v, th, br)
    assert np.abs(r["accel_x"] - model_now)[v > 0.3].max() > 0.2  # without the delay it fails


@pytest.mark.parametrize(
    "effect,check",
    [
        (
            fx.AeroDrag(3.2e-4),
            lambda v, res: np.testing.assert_allclose(res, -3.2e-4 * v**2, atol=0.01),
        ),
        (
            fx.RoadGrade(0.05),
            lambda v, res: np.testing.assert_allclose(res, -9.80665 * math.sin(0.05), atol=0.01),
        ),
    ],
)
def test_acceleration_effects_add_their_term(report, effect, check):
    r = simulate_experiment("ramp_sequence", report, seed=0, noise="none", effects=[effect])
    v = r["gps_speed"]
    sel = (v > 0.3) & (np.abs(v - 2.0) > 0.05) & (np.abs(v - 5.0) > 0.05)
    res = r["accel_x"] - _zone_accel(report, v, r["accel_pedal"], r["brake_pedal"])
    check(v[sel], res[sel])


def test_road_grade_shows_in_pitch_and_height(report):
    run = run_experiment("ramps", report, seed=0, noise="none", effects=[fx.RoadGrade(0.04)])
    r = run.recording
    dist = np.sum(run.truth["v_mps"]) * run.truth.dt_s
    assert r["z"][-1] == pytest.approx(dist * math.sin(0.04), rel=0.01)
    assert np.median(r["pitch"]) == pytest.approx(0.04, abs=0.002)


def test_wheel_radius_error_scales_the_wheel_speeds(report):
    base = simulate_experiment("ramps", report, seed=0, noise="none")
    off = simulate_experiment(
        "ramps", report, seed=0, noise="none", effects=[fx.WheelRadiusError(1.03)]
    )
    for ch in ("wheel_speed_fl", "wheel_speed_rr", "speed"):
        np.testing.assert_allclose(off[ch], 1.03 * base[ch], rtol=1e-12)
    np.testing.assert_array_equal(off["gps_speed"], base["gps_speed"])


def test_clock_offset_shifts_can_against_ins(report):
    c = 0.3
    base = simulate_experiment("ramps", report, seed=0, noise="none")
    off = simulate_experiment("ramps", report, seed=0, noise="none", effects=[fx.ClockOffset(c)])
    n = int(round(c * 50))
    np.testing.assert_allclose(off["speed"][n:], base["speed"][:-n], atol=1e-9)
    np.testing.assert_array_equal(off["gps_speed"], base["gps_speed"])
    assert _lag_s(off["gps_speed"], off["speed"], 50.0) == pytest.approx(c, abs=0.021)
    typ = simulate_experiment("ramps", report, seed=0, effects=[fx.ClockOffset(c)])
    assert _lag_s(typ["gps_speed"], typ["speed"], 50.0) == pytest.approx(c, abs=0.041)
    assert typ.meta["sensor_truth"]["can_clock_offset_s"] == c


def test_steering_nonlinearity_and_understeer_bend_the_steering_map(report):
    k = 0.002
    r = simulate_experiment("circles", report, seed=1, noise="none", effects=[fx.SteeringCubic(k)])
    sw, v = r["steering_wheel_angle"], r["gps_speed"]
    d = sn.road_wheel_angle_from_rear(r["wheel_speed_rl"], r["wheel_speed_rr"], 2.65, 1.6)
    m = v > 0.5
    np.testing.assert_allclose(d[m], (0.017 + 0.08 * (sw + k * sw**3))[m], atol=1e-9)
    assert np.abs(d[m] - (0.017 + 0.08 * sw)[m]).max() > 0.09  # 14 % more angle at full lock
    K = 0.003
    r = simulate_experiment("arcs", report, seed=1, noise="none", effects=[fx.Understeer(K)])
    sw, v = r["steering_wheel_angle"], r["gps_speed"]
    d = sn.road_wheel_angle_from_rear(r["wheel_speed_rl"], r["wheel_speed_rr"], 2.65, 1.6)
    m = v > 0.5
    expect = (0.017 + 0.08 * sw) * 2.65 / (2.65 + K * v**2)
    np.testing.assert_allclose(d[m], expect[m], atol=1e-9)


def test_truth_plant_applies_effects_step_by_step(report):
    from hmpc.models.sim.truth_plant import TruthPlant

    tp = TruthPlant(report, [fx.SteeringDeadTime(0.1), fx.AeroDrag(1e-3)], dt_s=0.01)
    s = np.array([0.0, 0.0, 0.0, 10.0])
    sw_eff = []
    for k in range(20):
        st = tp.step(s, (0.0 if k == 0 else 2.0, 0.1, 0.0))
        assert st.accel_extra_mps2 == pytest.approx(-1e-3 * s[3] ** 2)
        assert st.result.accel_mps2 == pytest.approx(st.accel_model_mps2 + st.accel_extra_mps2)
        sw_eff.append(st.u_eff[0])
        s = st.result.state
    assert sw_eff == [0.0] * 11 + [2.0] * 9  # the step at k = 1 arrives 10 steps (0.1 s) late
    assert tp.zone == 2


def test_effects_parse_from_text_and_reject_bad_specs():
    e = fx.parse_effect("steering_dead_time:delay_s=0.2")
    assert isinstance(e, fx.SteeringDeadTime) and e.delay_s == 0.2
    for eff in (
        fx.AeroDrag(3e-4),
        fx.RoadGrade(-0.02),
        fx.WheelRadiusError(0.99),
        fx.ClockOffset(-0.1),
        fx.SteeringLag(0.2),
        fx.PedalDeadTime(0.1),
        fx.SteeringCubic(0.001),
        fx.Understeer(0.003),
    ):
        again = fx.effect_from_dict(eff.describe())
        assert type(again) is type(eff) and again.describe() == eff.describe()
    for bad, match in (
        ("warp_drive:x=1", "unknown effect"),
        ("steering_dead_time:delay=0.2", "delay_s"),
        ("steering_dead_time:delay_s=-1", "delay_s"),
        ("aero_drag:coeff_per_m=abc", "not a number"),
        ("road_grade:0.1", "key=value"),
    ):
        with pytest.raises(InputError, match=match) as ei:
            fx.parse_effect(bad)
        assert "\n" not in str(ei.value)


# ------------------------------------------------------------------ params, API, I/O
def test_random_params_are_plausible_seeded_and_loadable(tmp_path):
    for seed in range(8):
        p = random_params(seed)
        assert p.is_model and p == random_params(seed)
        assert -0.03 <= p.steering.offset_rad <= 0.03 and 0.05 <= p.steering.scale <= 0.10
        idle, low, high = p.zones
        assert idle.offset_mps2 > 0 > low.offset_mps2 - 1e-12 and high.offset_mps2 < 0
        assert all(1.5 <= z.scale_mps2 <= 3.5 and 3.0 <= z.brake_scale_mps2 <= 8.0 for z in p.zones)
        dump_params(p, tmp_path / "p.yaml")
        q = load_params(tmp_path / "p.yaml", require_model=True)
        assert q.steering == p.steering and q.zones == p.zones
    assert random_params(0) != random_params(1)


def test_bad_arguments_are_named(report):
    with pytest.raises(InputError, match="unknown experiment 'spiral'"):
        simulate_experiment("spiral", report)
    with pytest.raises(InputError, match="noise"):
        simulate_experiment("arcs", report, noise="loud")
    with pytest.raises(ParamError, match="steering"):
        simulate_experiment("arcs", Params(vehicle=report.vehicle))
    with pytest.raises(ValueError):
        simulate_experiment("arcs", report, rate_hz=0.0)


def test_recording_round_trips_through_csv(report, tmp_path):
    r = simulate_experiment("open_loop", report, seed=3)
    assert set(CHANNELS) >= set(r.channels)
    r.to_csv(tmp_path / "rec.csv")
    back = Recording.load(tmp_path / "rec.csv")
    assert list(back.channels) == ALL_CHANNELS
    for k in ALL_CHANNELS:
        if k == "gear":
            assert list(back[k]) == list(r[k])
        else:
            np.testing.assert_allclose(back[k], r[k], rtol=1e-12, atol=1e-9)
    assert r.rate_hz == pytest.approx(50.0)
