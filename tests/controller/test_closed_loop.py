"""Closed loop on the hybrid plant: the MPC's acceptance.

The controller sees the plant through simulated sensors and the EKF, with seeded
wheel-speed noise (0.05 m/s) and GNSS position noise (0.02 m); seeds are fixed and printed.
The figures are printed (pytest -s).
"""

from __future__ import annotations

import copy

import numpy as np
import pytest
from hypothesis import HealthCheck, given, seed, settings
from hypothesis import strategies as st

from hmpc.controller.base import Status
from hmpc.controller.metrics import pedal_switches
from hmpc.controller.closed_loop import run_closed_loop as _run_closed_loop
from hmpc.controller.limits import ActuatorLimits
from hmpc.controller.mpc import MpcConfig, MpcController
from hmpc.controller.pid import PidController
from hmpc.models.params import load_params
from hmpc.models.logs.recording import Recording
from hmpc.models.reference import Reference
from hmpc.models.sim.scenarios import make_scenario

SEED = 7
NOISE = dict(speed_noise_mps=0.05, position_noise_m=0.02, seed=SEED)


@pytest.fixture(scope="module")
def params():
    return load_params("params/report_2008.yaml", require_model=True)


def run_closed_loop(*args, **kwargs):
    """The closed loop; every run in this file must be free of controller internal errors
    (a bug turned into a controlled stop would otherwise pass as a mere failure)."""
    res = _run_closed_loop(*args, **kwargs)
    assert res.metrics["internal_errors"] == 0, res.internal_errors[0][1]
    return res


def _fig(m):
    return (
        f"speed RMS {m['speed_error_rms_mps']:.3f} m/s, lateral RMS "
        f"{m['lateral_error_rms_m']:.3f} m, "
        f"pedal switches {m['pedal_switches_per_min']:.1f}/min, "
        f"zone transitions {m['zone_transitions_per_min']:.1f}/min, failures {m['failures']}, "
        f"solve p50/p99 {m['solve_time_ms']['p50']:.2f}/{m['solve_time_ms']['p99']:.2f} ms"
    )


def test_idle_hold_without_throttle_brake_chatter(params):
    ref = make_scenario("idle_hold", params)
    mpc = run_closed_loop(MpcController(params), ref, params, **NOISE)
    pid = run_closed_loop(PidController(params), ref, params, **NOISE)
    print(f"\nidle_hold seed {SEED}\n  MPC: {_fig(mpc.metrics)}\n  PID: {_fig(pid.metrics)}")
    m = mpc.metrics
    assert m["failures"] == 0
    assert m["speed_error_rms_mps"] <= 0.2
    assert m["pedal_switches_per_min"] <= 6.0
    # the PID baseline on the same run still changes pedal by the sign of its speed error
    # (3.1/min measured, filtered input and rate-limited pedals); the MPC's mode logic holds
    # one pedal (0/min measured)
    assert m["pedal_switches_per_min"] < pid.metrics["pedal_switches_per_min"]
    assert m["pedal_switches_per_min"] <= 1.0
    # and it really held 1.0 m/s below the idle speed (with the brake against idle creep)
    t, v = mpc.recording["time"], mpc.recording["speed"]
    hold = (t > 8) & (t < 24)
    assert abs(np.mean(v[hold]) - 1.0) < 0.05
    assert np.all(mpc.recording["brake_pedal_cmd"][hold] > 0)
    assert np.all(mpc.recording["accel_pedal_cmd"][hold] == 0)


@pytest.mark.parametrize("name", ["ramp_sequence", "arcs", "figure8"])
def test_tracking(params, name):
    ref = make_scenario(name, params)
    res = run_closed_loop(MpcController(params), ref, params, **NOISE)
    m = res.metrics
    print(f"\n{name} seed {SEED}: MPC {_fig(m)}")
    assert m["failures"] == 0
    assert m["speed_error_rms_mps"] <= 0.3
    assert m["lateral_error_rms_m"] <= 0.3
    assert m["both_pedals_samples"] == 0


def _boundary_reference(seconds=32.0, centre=5.0, amp=0.4, period=8.0):
    """Speed swinging across the low/high zone boundary: transitions are not worth it."""
    t = np.arange(0.0, seconds, 0.02)
    v = centre + amp * np.sin(2 * np.pi * t / period)
    x = np.concatenate([[0.0], np.cumsum(v[1:] * 0.02)])
    return Reference(t, x, 0 * t, 0 * t, v, name="boundary_swing")


def test_transition_penalty_reduces_zone_transitions(params):
    ref = _boundary_reference()
    with_p = run_closed_loop(MpcController(params), ref, params, **NOISE).metrics
    without = run_closed_loop(
        MpcController(params, MpcConfig(w_transition=0.0)), ref, params, **NOISE
    ).metrics
    print(
        f"\nboundary swing seed {SEED}: zone transitions with penalty "
        f"{with_p['zone_transitions']} ({with_p['zone_transitions_per_min']:.1f}/min), without "
        f"{without['zone_transitions']} ({without['zone_transitions_per_min']:.1f}/min); "
        f"speed RMS {with_p['speed_error_rms_mps']:.3f} vs "
        f"{without['speed_error_rms_mps']:.3f} m/s"
    )
    assert without["zone_transitions"] >= 6
    assert with_p["zone_transitions"] <= without["zone_transitions"] // 2
    # the ramps of ramp_sequence ask for transitions at steady acceleration: still allowed
    rs = make_scenario("ramp_sequence", params)
    m = run_closed_loop(MpcController(params), rs, params, **NOISE).metrics
    assert m["zone_transitions"] == 4  # 2, 5, 5, 2 m/s: once each
    assert m["speed_error_rms_mps"] <= 0.3


def test_model_mismatch_20_percent_weaker_zones_stays_stable(params):
    weak = copy.deepcopy(params)
    for z in weak.zones:
        z.scale_mps2 *= 0.8
        z.brake_scale_mps2 *= 0.8
    for name in ("ramp_sequence", "idle_hold"):
        ref = make_scenario(name, params)
        m = run_closed_loop(MpcController(params), ref, params, plant_params=weak, **NOISE).metrics
        print(
            f"\nmismatch (plant zones 20% weaker) {name} seed {SEED}: MPC {_fig(m)}, "
            f"max speed error {m['speed_error_max_mps']:.3f} m/s"
        )
        assert m["failures"] == 0
        assert m["speed_error_rms_mps"] <= 0.3
        assert m["speed_error_max_mps"] <= 1.0
        assert m["lateral_error_rms_m"] <= 0.3


def test_dead_times_are_compensated(params):
    delayed = copy.deepcopy(params)
    delayed.steering.dead_time_s = 0.2
    delayed.longitudinal_dead_time_s = 0.4
    ref = make_scenario("ramp_sequence", params)
    aware = run_closed_loop(MpcController(delayed), ref, delayed, **NOISE).metrics
    unaware = run_closed_loop(
        MpcController(params), ref, params, plant_params=delayed, **NOISE
    ).metrics
    print(
        f"\ndead times 0.2/0.4 s: speed RMS aware {aware['speed_error_rms_mps']:.3f}, "
        f"unaware {unaware['speed_error_rms_mps']:.3f} m/s"
    )
    assert aware["failures"] == 0
    assert aware["speed_error_rms_mps"] < 0.85 * unaware["speed_error_rms_mps"]


def test_recording_is_canonical_and_round_trips(params, tmp_path):
    ref = _boundary_reference(seconds=6.0)
    res = run_closed_loop(MpcController(params), ref, params, **NOISE)
    rec = res.recording
    for ch in (
        "time",
        "x",
        "y",
        "heading",
        "speed",
        "steering_wheel_angle",
        "accel_pedal",
        "brake_pedal",
        "steering_cmd",
        "accel_pedal_cmd",
        "brake_pedal_cmd",
    ):
        assert ch in rec
    assert np.allclose(np.diff(rec["time"]), 0.02)
    rec.save(tmp_path / "run.csv")
    back = Recording.load(tmp_path / "run.csv")
    assert np.allclose(back["speed"], rec["speed"])
    assert res.metrics["steps"] == len(res.statuses) == 60


class _Spy:
    """A controller that records the state it is given (and drives with the MPC)."""

    def __init__(self, inner):
        self.inner, self.name, self.seen = inner, "spy", []

    def reset(self):
        self.inner.reset()
        self.seen = []

    def step(self, state, reference, t_s, **kw):
        self.seen.append(np.array(state, dtype=float))
        return self.inner.step(state, reference, t_s, **kw)


def test_controller_sees_the_estimate_never_the_plant(params):
    """The truth reaches the controller only through the simulated sensors and the
    EKF. The states it is given are the estimates (equal to ``estimated_state``), differ from
    the plant's at every step but the first (the estimator starts on the start pose), and stay
    within centimetres of it. Measured on this 6 s run: position error RMS about 1 cm."""
    ref = _boundary_reference(seconds=6.0)
    spy = _Spy(MpcController(params))
    res = run_closed_loop(spy, ref, params, **NOISE)
    seen = np.array(spy.seen)
    assert np.array_equal(seen, res.estimated_state)
    err = res.estimated_state - res.true_state
    assert np.all(np.abs(err[1:, :2]).max(axis=1) > 0)
    pos = np.hypot(err[:, 0], err[:, 1])
    assert pos.max() < 0.1 and res.metrics["estimator"]["position_error_rms_m"] < 0.04
    assert res.metrics["estimator"]["gnss_accepted"] > 100
    assert np.all(res.estimator_time_s > 0)
    # no GNSS for 2 s: the estimate dead-reckons on wheel speeds, gyro and steering angle
    from hmpc.models.sim.live_sensors import SensorConfig

    out = run_closed_loop(
        MpcController(params),
        ref,
        params,
        seed=SEED,
        sensors=SensorConfig(gnss_outages=((2.0, 4.0),)),
    )
    assert out.metrics["failures"] == 0
    assert out.metrics["estimator"]["messages"]["gnss_outage"] == 40
    assert out.metrics["estimator"]["position_error_rms_m"] < 0.1


def test_pedal_switch_count():
    ap = np.array([0.2, 0.0, 0.0, 0.0, 0.3, 0.0, 0.0])
    bp = np.array([0.0, 0.0, 0.1, 0.0, 0.0, 0.0, 0.2])
    assert pedal_switches(ap, bp) == 3
    assert pedal_switches(ap, 0 * bp) == 0


# ------------------------------------------------------------------ property test
def _random_reference(draw_speeds, draw_curv, seconds=12.0):
    t = np.arange(0.0, seconds, 0.02)
    knots_t = np.linspace(0, seconds, len(draw_speeds))
    v = np.interp(t, knots_t, draw_speeds)
    kap = np.interp(t, knots_t, draw_curv)
    th = np.concatenate([[0.0], np.cumsum(v[1:] * kap[1:] * 0.02)])
    x = np.concatenate([[0.0], np.cumsum(v[1:] * np.cos(th[1:]) * 0.02)])
    y = np.concatenate([[0.0], np.cumsum(v[1:] * np.sin(th[1:]) * 0.02)])
    return Reference(t, x, y, th, v, name="random")


@seed(20240605)
@settings(
    max_examples=5,
    deadline=None,
    derandomize=False,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture],
)
@given(
    speeds=st.lists(st.floats(0.0, 9.0), min_size=3, max_size=5),
    curv=st.lists(st.floats(-0.15, 0.15), min_size=3, max_size=5),
    noise_seed=st.integers(0, 1000),
)
def test_property_limits_never_exceeded(params, speeds, curv, noise_seed):
    n = min(len(speeds), len(curv))
    ref = _random_reference(speeds[:n], curv[:n])
    ctl = MpcController(params)
    res = run_closed_loop(
        ctl, ref, params, speed_noise_mps=0.05, position_noise_m=0.02, seed=noise_seed
    )
    lim = ActuatorLimits.from_params(params)
    rec = res.recording
    sw, ap, bp = rec["steering_cmd"], rec["accel_pedal_cmd"], rec["brake_pedal_cmd"]
    assert np.all(np.abs(sw) <= lim.steering_wheel_angle_max_rad + 1e-9)
    # commands change every 0.1 s: the rate limit per control period
    step = sw[::5]
    assert np.all(np.abs(np.diff(step)) <= lim.steering_wheel_rate_max_radps * 0.1 + 1e-9)
    assert np.all((ap >= 0) & (ap <= 1) & (bp >= 0) & (bp <= 1))
    assert not np.any((ap > 0) & (bp > 0))
    assert rec["speed"].min() >= 0.0
    # statuses: every step returned a Status, every solve succeeded, no internal error
    assert len(res.statuses) == res.metrics["steps"]
    assert all(isinstance(s, Status) for s in res.statuses)
    assert res.metrics["failures"] == 0, res.metrics["statuses"]
    assert res.metrics["internal_errors"] == 0 and res.internal_errors == []


def test_concealed_effects_reach_the_plant_not_the_model(params):
    """``effects=``: the plant is the ground-truth simulator with physics the controller's
    model lacks. A 0.3 s steering dead time shows in the recorded yaw rate (it follows the
    commanded steering 0.3 s late: best lag 0.28-0.32 s) and a 0.05 rad uphill grade slows the
    car below what the effect-free run reaches; the loop stays stable, without failures."""
    from hmpc.models.sim.effects import parse_effect
    from hmpc.models.plant import heading_rate

    ref = make_scenario("figure8", params)
    ref = Reference(
        ref.time_s[:1000],
        ref.x_m[:1000],
        ref.y_m[:1000],
        ref.heading_rad[:1000],
        ref.speed_mps[:1000],
        name="figure8[:20s]",
    )
    run = {
        e: _run_closed_loop(
            MpcController(params), ref, params, seed=SEED, effects=[parse_effect(e)] if e else None
        )
        for e in ("", "steering_dead_time:delay_s=0.3", "road_grade:grade_rad=0.05")
    }
    for e, r in run.items():
        assert r.metrics["failures"] == 0, e
    rec = run["steering_dead_time:delay_s=0.3"].recording
    sw, v, yaw = rec["steering_wheel_angle"], rec["speed"], rec["yaw_rate"]
    b = params.vehicle.wheelbase_m
    pred = heading_rate(v, params.steering.offset_rad + params.steering.scale * sw, b)
    dt = float(rec["time"][1] - rec["time"][0])
    errs = [np.mean((yaw[k:] - pred[: len(pred) - k]) ** 2) for k in range(0, 30)]
    assert 0.28 <= int(np.argmin(errs)) * dt <= 0.32
    clean = run[""].recording["speed"].mean()
    assert run["road_grade:grade_rad=0.05"].recording["speed"].mean() < clean - 0.05


# ------------------------------------------------------------ the drive loop's candump
def _candump_times(path) -> np.ndarray:
    return np.array(
        [
            float(line[1 : line.index(")")])
            for line in path.read_text().splitlines()
            if line.startswith("(")
        ]
    )


def test_candump_writer_orders_a_frame_read_late(tmp_path):
    """The drive's candump writer (no bus, no clock): a frame stamped before the sent frames
    but read on the next tick is written before them; nothing is written before the frames
    it might precede are read, and every frame is written once."""
    import can
    from hmpc.controller.actuation.candump import OrderedCandump

    def frame(t, rx):
        return can.Message(
            timestamp=t, arbitration_id=0x100 + int(1000 * t), data=b"\x01", is_rx=rx, channel=0
        )

    path = tmp_path / "c.log"
    w = OrderedCandump(path)
    w.reading(10.000)  # tick 0: read
    w.on_message_received(frame(9.999, True))
    w.on_message_received(frame(10.004, False))  # sent
    w.on_message_received(frame(10.005, False))
    w.flush()
    w.reading(10.020)  # tick 1: read a frame of 10.003
    w.on_message_received(frame(10.003, True))
    w.on_message_received(frame(10.021, True))
    w.on_message_received(frame(10.024, False))
    w.flush()  # up to tick 0's read: 9.999 only
    assert len(_candump_times(path)) <= 1
    w.reading(10.040)
    w.on_message_received(frame(10.041, True))
    w.flush()
    w.stop()
    t = _candump_times(path)
    assert list(t) == sorted([9.999, 10.004, 10.005, 10.003, 10.021, 10.024, 10.041])
    dirs = [line.split()[-1] for line in path.read_text().splitlines()]
    assert dirs == ["R", "R", "T", "T", "R", "T", "R"]


@pytest.mark.realtime
def test_drive_candump_is_time_ordered_and_ingests_cleanly(tmp_path):
    """A drive run's own candump (Toyota figure8 on the simulator node, 6 s): frames in time
    order, every sent frame in it, and ``hmpc ingest`` reads it with no recoverable problem
    (it reported received frames up to 2 ms older than the sent frame logged before them;
    with the loop writing frames as it handled them, 6 steps back in 10 s were measured)."""
    import json

    from _data import PARAMS_DIR
    from _drive import drive
    from hmpc.tools.cli import main

    res, log = drive("toyota", "figure8", 6.0, tmp_path)
    t = _candump_times(log)
    assert len(t) > 100 and np.all(np.diff(t) >= 0), np.diff(t).min()
    lines = log.read_text().splitlines()
    assert sum(line.endswith(" T") for line in lines) == sum(res.summary["frames_sent"].values())
    assert sum(line.endswith(" R") for line in lines) > 0
    out = tmp_path / "ingest.json"
    rc = main(
        [
            "ingest",
            str(log),
            "--dbc",
            str(PARAMS_DIR.parent / "tools/data/dbc/toyota_rav4_2017.dbc.gz"),
            "--signals",
            str(PARAMS_DIR / "toyota_rav4_2017.signals.yaml"),
            "--out",
            str(tmp_path / "rec.csv"),
            "--json",
            str(out),
        ]
    )
    assert rc == 0
    problems = json.loads(out.read_text())["problems"]
    assert problems["total"] == 0, problems["items"]
