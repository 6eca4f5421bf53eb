"""Run a controller against the hybrid plant and measure how it did.

The loop owns the "bus": it takes the command each controller step returns, applies the
limits again (independently of the controller), delays it by the PLANT's actuator dead
times, and steps the plant. The plant may be built from different parameters than the
controller's model (``plant_params``: model mismatch, ``hmpc simulate --plant-params``).

The output is a canonical recording (``models.logs.recording.Recording``) at the plant rate
with the applied inputs, the commands (``steering_cmd``, ``accel_pedal_cmd``,
``brake_pedal_cmd``) and the plant state, plus the run metrics and the controller's
statuses: ``failures`` counts the steps whose own computation failed (any status but
solved/ok/hold), ``internal_errors`` those that were bugs (their tracebacks are in
``ClosedLoopResult.internal_errors``). The library prints nothing: progress goes to an
optional callback (the CLI prints it).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field, replace
from collections.abc import Callable
from typing import Any

import numpy as np

from hmpc.models.params import Params
from hmpc.models.plant import DelayLine, HybridPlant, heading_rate
from hmpc.models.logs.recording import Recording
from hmpc.models.sim.live_sensors import LiveSensors, SensorConfig
from hmpc.models.sim.truth_plant import TruthPlant
from hmpc.models.reference import Reference

from hmpc.controller.base import Controller, Status
from hmpc.controller.estimator import Estimator, EstimatorConfig
from hmpc.controller.limits import ActuatorLimits, Command, apply_limits
from hmpc.controller.metrics import (
    follow_verdict,
    limit_times,
    pedal_switches,
    smoothness_of,
    stall_figures,
)


class SensorFeedback:
    """What a simulated closed loop gives its controller: the car's sensors
    (``models.sim.live_sensors``) feeding an :class:`Estimator`, never the plant state.

    Per plant step call :meth:`observe` with the truth; per control step :meth:`estimate`
    (the state at ``t_s`` with its covariance, propagated with the input held so far), then
    :meth:`command` with the input applied from ``t_s`` on.

    Args:
        params: the controller's model (the estimator's; the sensors use it for eq. 7).
        sensors: rates, latency, noise (default ``SensorConfig()``: the default noise).
        config: the estimator's noise model (default matched to ``sensors``).
        seed: the sensors' seed. t0_s: time of the first truth sample [s].
        initial_state: start the estimator from this plant state at ``t0_s`` with the
            config's initial uncertainty (default: from the first GNSS fix, as a car does;
            until then :meth:`estimate` returns None).
    """

    def __init__(
        self,
        params: Params,
        sensors=None,
        config: EstimatorConfig | None = None,
        *,
        seed: int = 0,
        t0_s: float = 0.0,
        initial_state=None,
    ):
        self.sensors = LiveSensors(params, sensors, seed, t0_s)
        self.estimator = Estimator(params, config or EstimatorConfig.matching(self.sensors.cfg))
        if initial_state is not None:
            self.estimator.reset(t0_s, initial_state)

    def observe(
        self,
        t_s: float,
        state,
        steering_wheel_angle_rad: float,
        accel_mps2: float = 0.0,
        delta_rad: float | None = None,
    ) -> int:
        """Feed the truth at ``t_s`` to the sensors and what arrives to the estimator; returns
        the number of messages that arrived."""
        msgs = self.sensors.observe(t_s, state, steering_wheel_angle_rad, accel_mps2, delta_rad)
        for m in msgs:
            self.estimator.feed(m, t_s)
        return len(msgs)

    def estimate(self, t_s: float):
        """``(state, covariance)`` (4, 4x4) at ``t_s``, or None before the first fix."""
        self.estimator.predict(t_s)
        if not self.estimator.initialized:
            return None
        return self.estimator.state(), self.estimator.covariance()

    def command(self, t_s: float, u) -> None:
        """The plant input applied from ``t_s`` on (steering-wheel angle, pedals)."""
        self.estimator.predict(t_s, u)


@dataclass
class ClosedLoopResult:
    """A closed-loop run: the recording, the metrics, and per-sample extras for plots.

    Attributes:
        recording: canonical channels at the plant rate.
        metrics: the run's figures (see :func:`metrics_of`).
        zone: plant zone per sample.
        speed_ref_mps: reference speed per sample [m/s].
        lateral_error_m: signed distance to the path per sample [m].
        statuses: controller status per control step (:class:`Status`).
        reasons: the status reason per control step ("" when solved).
        solve_time_s: solver time per control step [s].
        step_time_s: wall time of each controller step [s].
        control_time_s: time of each control step [s].
        internal_errors: (time [s], traceback) of every step that was an internal error.
        estimator_time_s: wall time of the estimator per control step [s]: the messages
            that arrived since the previous step, the prediction to now and the input
            changes (the sensors' own simulation excluded).
        estimate_latency_s: of that, the estimate at the control instant itself [s] (the
            prediction to now: what delays the command; the messages are processed as they
            arrive, between steps).
        estimated_state, true_state: (steps, 4) what the controller was given and the
            plant's state at each control step (x_m, y_m, psi_rad, v_mps).
        adapter: the online model estimator of the run (``controller.adapt.ModelAdapter``),
            None without one.
        adapt_time_s: its CPU time per control step [s] (learning and handing the model
            over to the controller and the estimator; the messages it sums are included;
            CPU time, so that a loaded host's preemptions do not count).
        step_cpu_s, estimator_cpu_s: ``step_time_s`` and ``estimator_time_s`` in CPU time
            of the loop's thread [s] (the work itself, without a loaded host's preemptions).
    """

    recording: Recording
    metrics: dict
    zone: np.ndarray
    speed_ref_mps: np.ndarray
    lateral_error_m: np.ndarray
    statuses: list = field(default_factory=list)
    solve_time_s: np.ndarray = field(default_factory=lambda: np.zeros(0))
    step_time_s: np.ndarray = field(default_factory=lambda: np.zeros(0))
    control_time_s: np.ndarray = field(default_factory=lambda: np.zeros(0))
    reasons: list = field(default_factory=list)
    internal_errors: list = field(default_factory=list)
    estimator_time_s: np.ndarray = field(default_factory=lambda: np.zeros(0))
    estimated_state: np.ndarray = field(default_factory=lambda: np.zeros((0, 4)))
    true_state: np.ndarray = field(default_factory=lambda: np.zeros((0, 4)))
    estimate_latency_s: np.ndarray = field(default_factory=lambda: np.zeros(0))
    adapter: object = None
    adapt_time_s: np.ndarray = field(default_factory=lambda: np.zeros(0))
    step_cpu_s: np.ndarray = field(default_factory=lambda: np.zeros(0))
    estimator_cpu_s: np.ndarray = field(default_factory=lambda: np.zeros(0))


def run_closed_loop(
    controller: Controller,
    reference: Reference,
    params: Params,
    *,
    plant_params: Params | None = None,
    control_period_s: float = 0.1,
    plant_dt_s: float = 0.02,
    seed: int = 0,
    speed_noise_mps: float | None = None,
    position_noise_m: float | None = None,
    extra_time_s: float = 0.0,
    limits: ActuatorLimits | None = None,
    progress: Callable[[float, float], None] | None = None,
    initial_state: np.ndarray | None = None,
    sensors: SensorConfig | None = None,
    estimator_config: EstimatorConfig | None = None,
    effects: list | None = None,
    adapter=None,
    sensor_faults: list | None = None,
) -> ClosedLoopResult:
    """Closed loop: ``controller.step(estimated_state, reference, t)`` every control period.

    The controller never sees the plant state: the truth goes, every plant step, to the
    simulated car sensors (``models.sim.live_sensors``: CAN wheel speeds and steering angle,
    IMU, GNSS with its rate and latency), whose messages feed the EKF
    (:class:`SensorFeedback`); each control step the controller gets the
    estimator's state at that instant. The estimator starts from the plant's start pose (a
    car parked where its last fix put it) with its initial uncertainty, and is told every
    change of the plant input (the applied, delayed command).

    Args:
        controller: a :class:`controller.base.Controller`.
        reference: the trajectory to follow.
        params: the controller's model (also the plant's, unless ``plant_params``).
        plant_params: a different plant (model mismatch).
        control_period_s: controller period [s] (commands held in between).
        plant_dt_s: plant integration step and recording period [s].
        seed: seed of the sensors' noise (printed in the metrics).
        speed_noise_mps: when given, replaces ``sensors``' speed noise (wheel speeds and GNSS
            speed) [m/s]; None keeps the sensor configuration's (default 0.05 m/s).
        position_noise_m: when given, replaces ``sensors``' GNSS position noise [m]; None
            keeps the sensor configuration's (default 0.02 m).
        extra_time_s: run this long past the reference's end [s].
        limits: limits applied at the actuation boundary (default from ``params``).
        progress: called as ``progress(fraction_done, t_s)`` (t_s since the start [s])
            at every further tenth of the run; None: no reports.
        initial_state: plant start state (default: on the reference).
        sensors: rates, latencies, noise, GNSS outages (default ``SensorConfig()``).
        estimator_config: the EKF's noise model (default matched to ``sensors``).
        effects: concealed physics in the plant (``models.sim.effects``: delays, lag, rack
            nonlinearity, understeer, drag, grade, idle creep, ...): the plant is then the
            ground-truth simulator's (``TruthPlant``), which the controller's model lacks.
        adapter: an online model estimator (``controller.adapt.ModelAdapter``, built for
            ``params`` and ``control_period_s``): it is fed every sensor message, learns each
            control step before the controller's step and hands a changed model to the
            controller's and the estimator's ``use_model``; told every command sent.
        sensor_faults: :class:`SensorFault` s applied to the messages before the estimator
            (and the adapter) see them.
    """
    every = _check_rates(control_period_s, plant_dt_s, progress)
    pp = plant_params if plant_params is not None else params
    plant = HybridPlant(pp)
    truth = TruthPlant(pp, list(effects), dt_s=plant_dt_s) if effects else None
    lim = limits or ActuatorLimits.from_params(params)
    sensor_cfg = sensor_config(sensors, speed_noise_mps, position_noise_m)
    assert pp.steering is not None  # HybridPlant(pp) took it as a model
    d_steer = DelayLine(float(pp.steering.dead_time_s or 0.0), plant_dt_s)
    d_acc = DelayLine(float(pp.longitudinal_dead_time_s or 0.0), plant_dt_s)
    d_brk = DelayLine(float(pp.longitudinal_dead_time_s or 0.0), plant_dt_s)
    controller.reset()

    t0 = float(reference.time_s[0])
    n = int(math.floor((reference.duration_s + extra_time_s) / plant_dt_s + 1e-9)) + 1
    s = (
        np.array(initial_state, dtype=float)
        if initial_state is not None
        else reference.initial_state(params)
    )
    fb = SensorFeedback(params, sensor_cfg, estimator_config, seed=seed, t0_s=t0, initial_state=s)
    zone = plant.select_zone(float(s[3]), None)
    cols = {k: np.zeros(n) for k in _COLUMNS}
    zones = np.zeros(n, dtype=np.int64)
    log = _StepLog()
    cmd = Command(0.0, 0.0, 0.0)
    prev_applied: Command | None = None
    u = np.zeros(3)  # plant input over the previous step (what the sensors saw)
    u_fed = None  # the plant input the estimator holds
    accel = 0.0  # true acceleration over the previous step [m/s^2]
    sw_eff = 0.0  # steering-wheel angle the road wheels followed (after effects)
    last_report = -1
    faults = list(sensor_faults or ())
    for i in range(n):
        t = t0 + i * plant_dt_s
        log.pending_est_s += _observe(
            fb, t, s, u[0], accel, plant.road_wheel_angle(sw_eff), adapter, faults, log
        )
        if i % every == 0:
            t_w, c_w = time.perf_counter(), time.thread_time()
            est = fb.estimate(t)
            meas = est[0] if est is not None else s.copy()  # reset above: never None
            t_est = time.perf_counter() - t_w
            log.est_cpu_t.append(time.thread_time() - c_w + log.pending_est_cpu_s)
            log.pending_est_cpu_s = 0.0
            if adapter is not None:  # its cost in CPU time: the host's load is not its own
                t_w = time.thread_time()
                _adapt(adapter, fb.estimator, controller, t)
                log.pending_adapt_s += time.thread_time() - t_w
            if adapter is None:  # offset-free steering (a learner takes the offset itself)
                correct = getattr(controller, "use_steering_correction", None)
                if correct is not None:
                    correct(fb.estimator.steering_correction_rad(), t)
            c_w = time.thread_time()
            res = controller.step(meas, reference, t)
            log.step_cpu_t.append(time.thread_time() - c_w)
            # the actuation boundary applies the limits again, whatever the controller did
            cmd = apply_limits(res.command, prev_applied, lim, control_period_s)
            prev_applied = cmd
            if adapter is not None:
                t_w = time.thread_time()
                adapter.commanded(t, cmd.steering_wheel_angle_rad, cmd.accel_pedal, cmd.brake_pedal)
                log.adapt_t.append(log.pending_adapt_s + time.thread_time() - t_w)
                log.pending_adapt_s = 0.0
            log.add(t, res, t_est, meas, s)
            if progress is not None:
                tenth = int(100 * i / max(n - 1, 1)) // 10
                if tenth != last_report:
                    last_report = tenth
                    progress(tenth / 10, t - t0)
        u = np.array(
            [
                d_steer.push(cmd.steering_wheel_angle_rad),
                d_acc.push(cmd.accel_pedal),
                d_brk.push(cmd.brake_pedal),
            ]
        )
        if u_fed is None or not np.array_equal(u, u_fed):
            t_w, c_w = time.perf_counter(), time.thread_time()
            fb.command(t, u)
            log.pending_est_s += time.perf_counter() - t_w
            log.pending_est_cpu_s += time.thread_time() - c_w
            u_fed = u
        r, sw_eff = _plant_step(plant, truth, s, u, plant_dt_s, zone)
        _record(cols, i, t, s, u, cmd, plant, sw_eff)
        cols["accel_x"][i] = accel = r.accel_mps2
        zones[i] = r.zone
        s, zone = r.state, r.zone
    if progress is not None and last_report != 10:  # the last control step came before the end
        progress(1.0, float(cols["time"][-1]) - t0)
    cols["heading"] = (cols["heading"] + np.pi) % (2 * np.pi) - np.pi
    rec = Recording(
        cols,
        {},
        {
            "source": "hmpc closed loop",
            "controller": getattr(controller, "name", "?"),
            "reference": reference.name,
            "seed": seed,
            "rate_hz": 1.0 / plant_dt_s,
        },
    )
    v_ref = reference.speed_at(cols["time"])
    lat = reference.lateral_errors(cols["x"], cols["y"], cols["time"])
    result = ClosedLoopResult(
        rec,
        {},
        zones,
        v_ref,
        lat,
        log.statuses,
        np.array(log.solve_t),
        np.array(log.step_t),
        np.array(log.ctl_t),
        log.reasons,
        log.errors,
        np.array(log.est_t),
        np.array(log.est_state).reshape(-1, 4),
        np.array(log.true_state).reshape(-1, 4),
        np.array(log.est_now_t),
        adapter,
        np.array(log.adapt_t),
        np.array(log.step_cpu_t),
        np.array(log.est_cpu_t),
    )
    result.metrics = metrics_of(result, lim)
    result.metrics["seed"] = seed
    result.metrics["estimator"] = _estimator_figures(result, fb)
    if adapter is not None:
        result.metrics["adaptation"] = adapter.report(t0)
        result.metrics["adaptation_details"] = {
            **adapter.summary(),
            "cost_us": _percentiles(log.adapt_t, 1e6),
            "sensor_faults": log.faults_applied,
        }
    return result


def _adapt(adapter, estimator, controller, t: float) -> None:
    """One learning step of ``adapter`` at ``t`` [s] from the estimator's speed and gyro bias;
    a changed model goes to the controller and the estimator."""
    v, bias = estimator.model_inputs()
    model = adapter.learn(t, v, bias if bias == bias else 0.0)
    if model is not None:
        use = getattr(controller, "use_model", None)
        if use is not None:
            use(model)
        estimator.use_model(model)


def _percentiles(values, scale: float) -> dict:
    a = np.asarray(values, dtype=float) * scale
    if not len(a):
        return {"p50": 0.0, "p99": 0.0, "max": 0.0}
    return {
        "p50": float(np.percentile(a, 50)),
        "p99": float(np.percentile(a, 99)),
        "max": float(a.max()),
    }


@dataclass(frozen=True)
class SensorFault:
    """A simulated sensor fault on the messages of a closed-loop run.

    ``kind``: ``frozen_wheel_speed`` (the front-left wheel speed keeps the value it had at
    ``t0_s`` until ``t1_s``), ``yaw_rate_spike`` (the IMU yaw rate reads ``value`` [rad/s]
    more from ``t0_s`` to ``t1_s``), ``frozen_yaw_rate`` (the IMU yaw rate keeps its value
    from ``t0_s`` to ``t1_s``).
    """

    kind: str
    t0_s: float
    t1_s: float
    value: float = 0.0

    def __post_init__(self):
        if self.kind not in SENSOR_FAULTS:
            raise ValueError(
                f"unknown sensor fault {self.kind!r} (one of {', '.join(SENSOR_FAULTS)})"
            )
        if not self.t0_s < self.t1_s:
            raise ValueError("a sensor fault needs t0_s < t1_s")


#: the kinds of :class:`SensorFault`
SENSOR_FAULTS = ("frozen_wheel_speed", "yaw_rate_spike", "frozen_yaw_rate")


def _apply_faults(m, faults: list, held: dict) -> int:
    """Change message ``m`` in place by the faults active at its measurement time; returns
    how many acted. ``held``: the values a frozen channel keeps."""
    n = 0
    for f in faults:
        if not f.t0_s <= m.t_meas_s < f.t1_s:
            continue
        v = m.values
        if f.kind == "frozen_wheel_speed" and m.kind == "can" and "wheel_speeds_mps" in v:
            ws = list(v["wheel_speeds_mps"])
            ws[0] = held.setdefault(("ws", id(f)), ws[0])
            v["wheel_speeds_mps"] = tuple(ws)
            n += 1
        elif f.kind == "yaw_rate_spike" and m.kind == "imu":
            v["yaw_rate_radps"] = v["yaw_rate_radps"] + f.value
            n += 1
        elif f.kind == "frozen_yaw_rate" and m.kind == "imu":
            v["yaw_rate_radps"] = held.setdefault(("yaw", id(f)), v["yaw_rate_radps"])
            n += 1
    return n


#: the recording's channels: plant state, applied input, commands, yaw rate, acceleration
_COLUMNS = (
    "time",
    "x",
    "y",
    "heading",
    "speed",
    "steering_wheel_angle",
    "accel_pedal",
    "brake_pedal",
    "yaw_rate",
    "accel_x",
    "steering_cmd",
    "accel_pedal_cmd",
    "brake_pedal_cmd",
)


def _plant_step(plant: HybridPlant, truth, s: np.ndarray, u: np.ndarray, dt_s: float, zone: int):
    """One plant step: the hybrid plant, or the ground-truth plant with its concealed effects
    (``truth``). Returns the step result and the steering-wheel angle the road wheels
    followed [rad] (after the effects)."""
    if truth is None:
        return plant.step(s, u, dt_s, zone), float(u[0])
    ts = truth.step(s, u)
    return ts.result, float(ts.u_eff[0])


def _check_rates(control_period_s: float, plant_dt_s: float, progress) -> int:
    """Plant steps per control period (ValueError on bad periods or progress)."""
    if not (plant_dt_s > 0 and control_period_s >= plant_dt_s - 1e-12):
        raise ValueError("need 0 < plant_dt_s <= control_period_s")
    ratio = control_period_s / plant_dt_s
    if abs(ratio - round(ratio)) > 1e-6:
        raise ValueError("control_period_s must be a whole number of plant_dt_s")
    if progress is not None and not callable(progress):
        raise ValueError("progress must be a callable progress(fraction, t_s) or None")
    return int(round(ratio))


def _record(
    cols: dict,
    i: int,
    t: float,
    s: np.ndarray,
    u: np.ndarray,
    cmd: Command,
    plant: HybridPlant,
    sw_eff: float,
) -> None:
    """Row ``i`` of the recording: time, plant state, applied input, command, yaw rate (from
    the steering-wheel angle the road wheels followed, ``sw_eff``, after concealed effects)."""
    cols["time"][i] = t
    cols["x"][i], cols["y"][i], cols["heading"][i], cols["speed"][i] = s
    cols["steering_wheel_angle"][i], cols["accel_pedal"][i], cols["brake_pedal"][i] = u
    cols["steering_cmd"][i] = cmd.steering_wheel_angle_rad
    cols["accel_pedal_cmd"][i] = cmd.accel_pedal
    cols["brake_pedal_cmd"][i] = cmd.brake_pedal
    delta = plant.road_wheel_angle(sw_eff)
    cols["yaw_rate"][i] = heading_rate(s[3], float(delta), plant.wheelbase_m, ops=math)


def sensor_config(
    sensors: SensorConfig | None = None,
    speed_noise_mps: float | None = None,
    position_noise_m: float | None = None,
) -> SensorConfig:
    """``sensors`` (default ``SensorConfig()``) with the legacy noise arguments applied:
    ``speed_noise_mps`` sets the wheel-speed and GNSS speed noise [m/s], ``position_noise_m``
    the GNSS position noise [m]."""
    cfg = sensors or SensorConfig()
    kw: dict[str, Any] = {}
    if speed_noise_mps is not None:
        kw.update(
            speed_noise_mps=float(speed_noise_mps), gnss_speed_noise_mps=float(speed_noise_mps)
        )
    if position_noise_m is not None:
        kw["position_noise_m"] = float(position_noise_m)
    return replace(cfg, **kw) if kw else cfg


def _observe(
    fb: SensorFeedback,
    t: float,
    s: np.ndarray,
    sw_rad: float,
    accel_mps2: float,
    delta_rad: float,
    adapter=None,
    faults=(),
    log=None,
) -> float:
    """Truth at ``t`` to the sensors, arrived messages (after the sensor ``faults``) to the
    estimator and the ``adapter``; returns the wall time the estimator spent on them [s] (the
    sensors' simulation is not the controller's time; the adapter's goes to ``log``)."""
    msgs = fb.sensors.observe(t, s, sw_rad, accel_mps2, float(delta_rad))
    if not msgs:
        return 0.0
    if faults:
        for m in msgs:
            log.faults_applied += _apply_faults(m, faults, log.fault_held)
    t_w, c_w = time.perf_counter(), time.thread_time()
    for m in msgs:
        fb.estimator.feed(m, t)
    t_a = time.perf_counter()
    if log is not None:
        log.pending_est_cpu_s += time.thread_time() - c_w
    if adapter is not None:
        c_a = time.thread_time()
        for m in msgs:
            adapter.feed(m)
        log.pending_adapt_s += time.thread_time() - c_a
    return t_a - t_w


class _StepLog:
    """Per-control-step records of a run (statuses, timings, estimate and truth)."""

    def __init__(self):
        self.statuses, self.reasons, self.errors = [], [], []
        self.solve_t, self.step_t, self.ctl_t, self.est_t, self.est_now_t = [], [], [], [], []
        self.est_state, self.true_state = [], []
        self.pending_est_s = 0.0  # estimator time spent after the last control step [s]
        self.step_cpu_t, self.est_cpu_t = [], []  # the same two in CPU time [s]
        self.pending_est_cpu_s = 0.0
        self.adapt_t = []  # the adapter's time per control step [s]
        self.pending_adapt_s = 0.0
        self.faults_applied = 0  # messages a sensor fault changed
        self.fault_held = {}  # the values frozen channels keep

    def add(self, t: float, res, t_est_s: float, est: np.ndarray, truth: np.ndarray) -> None:
        status = Status(res.status)
        self.statuses.append(status)
        self.reasons.append(res.reason)
        if status is Status.INTERNAL_ERROR:
            self.errors.append((t, res.traceback or res.reason))
        self.solve_t.append(float(res.solve_time_s))
        self.step_t.append(float(res.step_time_s))
        self.est_t.append(t_est_s + self.pending_est_s)
        self.est_now_t.append(t_est_s)
        self.pending_est_s = 0.0
        self.ctl_t.append(t)
        self.est_state.extend(float(q) for q in est[:4])
        self.true_state.extend(float(q) for q in truth[:4])


def _estimator_figures(res: ClosedLoopResult, fb: SensorFeedback) -> dict:
    """How well the controller's view matched the truth, and the sensors' message counts."""
    e = res.estimated_state - res.true_state
    st = fb.estimator.stats
    if len(e):
        pos = float(np.sqrt(np.mean(e[:, 0] ** 2 + e[:, 1] ** 2)))
        hd = float(np.sqrt(np.mean((np.remainder(e[:, 2] + np.pi, 2 * np.pi) - np.pi) ** 2)))
        sp = float(np.sqrt(np.mean(e[:, 3] ** 2)))
    else:
        pos = hd = sp = 0.0
    return {
        "position_error_rms_m": pos,
        "heading_error_rms_rad": hd,
        "speed_error_rms_mps": sp,
        "gnss_accepted": int(st["gnss"]["accepted"]),
        "gnss_rejected": int(st["gnss"]["rejected"]),
        "messages": dict(fb.sensors.counts),
    }


def control_updates(res: ClosedLoopResult) -> np.ndarray:
    """Indices of the recording's samples at the control updates (the commands are held
    between them); every sample when the run has no control times."""
    t = res.recording.channels["time"]
    if len(res.control_time_s) == 0 or len(t) < 2:
        return np.arange(len(t))
    tol = 1e-6 * float(t[1] - t[0])
    idx = np.searchsorted(t, np.asarray(res.control_time_s, dtype=float) - tol)
    return idx[idx < len(t)]


def metrics_of(res: ClosedLoopResult, limits: ActuatorLimits) -> dict:
    """The tracking figures (stable keys, SI units), the internal errors, the
    smoothness figures (:func:`smoothness_of`), the whole step with the estimator, and
    whether the car did what was asked: time at each actuator limit (``limits``), stalls
    (``stalls``) and the verdict (``followed``, ``not_followed``)."""
    rec = res.recording
    t = rec.channels["time"]
    minutes = max((t[-1] - t[0]) / 60.0, 1e-9)
    v = rec.channels["speed"]
    ev = v - res.speed_ref_mps
    solve_ms = res.solve_time_s[res.solve_time_s > 0] * 1e3
    step_ms = res.step_time_s * 1e3
    whole_ms = step_ms + (
        res.estimator_time_s * 1e3 if len(res.estimator_time_s) == len(step_ms) else 0.0
    )

    def pct(a, q):
        return float(np.percentile(a, q)) if len(a) else 0.0

    ap, bp = rec.channels["accel_pedal_cmd"], rec.channels["brake_pedal_cmd"]
    nz = int(np.count_nonzero(np.diff(res.zone)))
    upd = control_updates(res)
    sw_max = limits.steering_wheel_angle_max_rad
    lim = limit_times(
        t,
        rec.channels["steering_cmd"],
        ap,
        bp,
        steering_wheel_angle_max_rad=sw_max,
        pedal_max=limits.pedal_max,
    )
    stalls = stall_figures(t, v, res.speed_ref_mps)
    followed, why = follow_verdict(
        lim, stalls, float(t[-1] - t[0]), steering_wheel_angle_max_rad=sw_max
    )
    return {
        "speed_error_rms_mps": float(np.sqrt(np.mean(ev**2))),
        "lateral_error_rms_m": float(np.sqrt(np.mean(res.lateral_error_m**2))),
        "pedal_switches_per_min": pedal_switches(ap, bp, limits.pedal_deadband) / minutes,
        "zone_transitions_per_min": nz / minutes,
        "solve_time_ms": {
            "p50": pct(solve_ms, 50),
            "p99": pct(solve_ms, 99),
            "max": float(solve_ms.max()) if len(solve_ms) else 0.0,
        },
        "steps": int(len(res.statuses)),
        "failures": int(sum(1 for s in res.statuses if not Status(s).ok)),
        "internal_errors": int(sum(1 for s in res.statuses if s == Status.INTERNAL_ERROR)),
        # the commands at the control updates (held in between): rates per update
        **smoothness_of(
            t[upd],
            rec.channels["steering_cmd"][upd],
            ap[upd],
            bp[upd],
            duration_s=float(t[-1] - t[0]),
        ),
        # extras (not acceptance figures, kept stable too)
        "step_time_ms": {
            "p50": pct(step_ms, 50),
            "p99": pct(step_ms, 99),
            "max": float(step_ms.max()) if len(step_ms) else 0.0,
        },
        "step_with_estimator_ms": {
            "p50": pct(whole_ms, 50),
            "p99": pct(whole_ms, 99),
            "max": float(whole_ms.max()) if len(whole_ms) else 0.0,
        },
        "speed_error_max_mps": float(np.max(np.abs(ev))),
        "lateral_error_max_m": float(np.max(np.abs(res.lateral_error_m))),
        "pedal_switches": pedal_switches(ap, bp, limits.pedal_deadband),
        "zone_transitions": nz,
        "duration_s": float(t[-1] - t[0]),
        "both_pedals_samples": int(
            np.count_nonzero((ap > limits.pedal_deadband) & (bp > limits.pedal_deadband))
        ),
        "statuses": _count(res.statuses),
        # whether the car did what was asked (controller.metrics.follow_verdict)
        "followed": followed,
        "not_followed": why,
        "limits": lim,
        "stalls": stalls,
    }


def _count(statuses) -> dict:
    """Steps per status, keyed by the status value."""
    out: dict[str, int] = {}
    for s in statuses:
        key = Status(s).value
        out[key] = out.get(key, 0) + 1
    return out
