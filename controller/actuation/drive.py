"""The real-time drive loop: the only owner of a ``can.Bus`` in hmpc.

Every tick (100 Hz, the fastest command's rate) the loop:

1. reads its clock and checks it against the monotonic clock (watchdog: frozen / jumping);
2. drains the bus, logs every received frame (candump ``-L``, ``candump.py``) and decodes the
   feedback with ingest's own signal map and decoder (``feedback.py``);
3. every control period (50 Hz by default) estimates the state and runs the controller (MPC,
   NMPC, PID, or an operator's commands passed through); the step RETURNS a command;
4. turns the command into the profile's quantities (Toyota: an inner angle loop gives the EPS
   torque, the zone model eq. 8 forward gives the acceleration request; by-wire: angle and
   pedals as they are), applies the limits, checks them again independently at the encoder and
   encodes (``command_path.py``), and sends each message at its own rate, logging every frame
   sent;
5. runs the watchdog: stale feedback (no wheel speeds for 3 periods), missed deadlines, a
   frozen or jumping clock, a failed solve, bus send errors, the car's status refusing the
   commands, and driver override (steering torque over the profile's threshold, brake or gas
   pressed) each start a controlled stop (steering held, braking at ``stop_decel_mps2`` with a
   jerk-limited ramp, to standstill, then held); the reason and times are reported.
   Faults can be injected to exercise these (``faults.py``).

Commands are sent only after an explicit engage (``engage_at_s``) and while the car's status
says it accepts them; before that the frames carry no request (torque 0 without the request
bit, acceleration 0, enable bits cleared).

State estimate (default): minimal dead reckoning: speed = the mean of the front wheel speeds
(eq. 1's point is the front-axle centre; the signal map's ``speed``, the four-wheel mean, is the
fallback), heading and position integrated every tick with eq. 1 (midpoint heading) from the
measured steering-wheel angle through the controller's own steering map (eq. 7).
``DriveConfig(estimator="ekf")`` feeds the shared estimator (``controller/estimator/``)
the decoded wheel speeds, steering angle and yaw rate instead; not the default yet
(see :class:`DriveConfig`: the Toyota's quantised yaw rate biases its heading when
straight). No GNSS reaches the bus, so position is dead reckoning either way; it drifts
with any steering-map mismatch, and the run JSON's tracking figures are measured on the
simulator node's true state when a node is present.
The run starts with the car on the reference's start, so the reference's clock is the loop's
clock (the controller takes over at engagement).

Online model estimation (``adapter``, a ``controller.adapt.ModelAdapter`` built for the
control period): every tick's decoded wheel speeds, steering angle, yaw rate and acceleration
feed it; each control step it learns before the controller's step and a changed model goes to
the controller, the estimator and the dead reckoning's steering map; the commands it is told
are the pedal plan (a Toyota's acceleration request is formed from it with the file's eq. 8,
so its adapter learns the command's response, ``inputs="accel_cmd"``). The run JSON then has
``adaptation``.

After the run, ``candump.audit_candump`` re-checks every command frame of the written log.
"""

from __future__ import annotations

import gc
import math
import time
from contextlib import contextmanager
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING

import can
import numpy as np
from threadpoolctl import threadpool_limits

from hmpc.models.errors import InputError
from hmpc.models.params import Params
from hmpc.models.plant import HybridPlant, heading_rate
from hmpc.models.reference import Reference

from hmpc.controller.base import Status
from hmpc.controller.limits import ActuatorLimits
from hmpc.controller.actuation import builders
from hmpc.controller.actuation.candump import OrderedCandump
from hmpc.controller.actuation.command_path import CommandPath
from hmpc.controller.actuation.drive_summary import (
    TRACE_KEYS,
    cpu_percentiles,
    record_row,
    summarize,
)
from hmpc.controller.actuation.faults import (
    Fault,
    check_node_faults,
    fault_active,
    schedule_node_faults,
)
from hmpc.controller.actuation.feedback import Feedback
from hmpc.controller.actuation.profiles import ActuationProfile
from hmpc.controller.actuation.watchdog import Watchdog, WatchdogConfig

if TYPE_CHECKING:
    from hmpc.controller.estimator import Estimator


@dataclass(frozen=True)
class DriveConfig:
    """Timing and stop behaviour (each number with its reason)."""

    # The controller at 50 Hz (the default); commands go out at their own rates.
    control_period_s: float = 0.02
    # Base tick: 100 Hz, the rate of the fastest command (STEERING_LKA, BW_STEER_CMD).
    tick_s: float = 0.01
    # The operator engages this long after start, once the feedback is fresh.
    engage_at_s: float = 0.3
    # Controlled stop: 2.0 m/s^2, within ISO 15622's automated braking bound (3.5) and the
    # controller's comfort; reached with a 2.5 m/s^3 ramp (ISO 15622's jerk bound).
    stop_decel_mps2: float = 2.0
    stop_jerk_mps3: float = 2.5
    # Below this measured speed the car is at a standstill (wheel-speed resolution 0.01 km/h
    # and the plant's clamp at zero).
    standstill_mps: float = 0.05
    # Acceleration request that holds the car at a standstill.
    hold_accel_mps2: float = -1.0
    # After standstill the loop holds this long, then ends the run.
    hold_s: float = 0.5
    # A run that cannot reach standstill after its stop started ends after this long.
    stop_timeout_s: float = 15.0
    watchdog: WatchdogConfig = WatchdogConfig()
    # "dead_reckoning" (default): eq. 1 integrated from the measured speed and steering
    # angle; "ekf": the shared estimator (controller/estimator/, the one simulate and replay
    # use) fed the decoded CAN feedback. On the node (MPC, 6 s, speed / lateral error RMS,
    # EKF against dead reckoning) they track alike on Toyota figure8 0.010 / 0.118 against
    # 0.010 / 0.116 m and ramp_sequence 0.209 / 0.009 against 0.205 / 0.008, by-wire figure8
    # 0.012 / 0.149 against 0.012 / 0.140; but on 20 s of idle_hold (1 m/s, straight) the
    # EKF's heading follows the Toyota's quantised yaw rate (0.244 deg/s steps: a straight car
    # reads -0.072 deg/s) and the car ends 0.177 m lateral RMS off against 0.002 m, so the
    # EKF is not the default until its CAN yaw-rate model knows the quantisation.
    estimator: str = "dead_reckoning"


@contextmanager
def _frozen_heap():
    """The garbage collector's full (generation 2) passes skip what exists before the run.

    With the controller, scipy, CasADi and matplotlib loaded a process holds ~130,000
    tracked objects, and one full collection took 72 ms here: longer than the stale-feedback
    rule's 3 wheel-speed periods (36 ms on the Toyota) and three 20 ms control periods, at a
    moment the interpreter chooses (a 10-minute bench run stopped on ``feedback_loss`` after
    7.4 min). ``gc.freeze()`` moves them to the permanent generation (a full pass then takes
    microseconds); the young generations are collected as before. Undone after the run."""
    gc.collect()
    gc.freeze()
    try:
        yield
    finally:
        gc.unfreeze()


@dataclass
class DriveResult:
    summary: dict
    trace: dict = field(default_factory=dict)


@dataclass
class _Run:
    """The drive loop's state carried from tick to tick (and the figures it collects)."""

    fb: Feedback
    wd: Watchdog
    act: CommandPath
    bus: can.BusABC
    writer: OrderedCandump
    counters: dict
    sent: dict
    trace: dict
    est: np.ndarray
    ekf: Estimator | None
    mono0: float
    epoch0: float
    periods: list = field(default_factory=list)
    late_steps: int = 0
    solve_ms: list = field(default_factory=list)
    statuses: list = field(default_factory=list)
    failures: int = 0
    state: str = "disengaged"
    engaged_at: float | None = None
    stop: dict = field(
        default_factory=lambda: {
            "reason": None,
            "t_s": None,
            "detected_t_s": None,
            "standstill_t_s": None,
        }
    )
    sw_cmd: float = 0.0
    ap_cmd: float = 0.0
    bp_cmd: float = 0.0
    res: object = None
    stop_accel: float = 0.0
    stop_bp: float = 0.0
    hold_from: float | None = None
    last_ctl_start: float | None = None
    t_freeze: float | None = None
    use_mono: bool = False
    rejected_seen: float | None = None
    t_est: float | None = None
    stop_reason_pending: str = ""
    k: int = 0
    # messages decoded by the last look before encoding (step 6), counted as seen next tick
    late_seen: list = field(default_factory=list)


class SystemClock:
    """The drive loop's default clock: the real ones (``time.monotonic`` [s], ``time.time``
    [s since the epoch], ``time.sleep``). A replay injects a simulated clock with the same three
    methods, so that a recorded log runs through the loop deterministically."""

    monotonic = staticmethod(time.monotonic)
    sleep = staticmethod(time.sleep)
    time = staticmethod(time.time)  # last: it shadows the module name in this class body


@dataclass
class _Tick:
    """One tick's clock and measurements."""

    t: float
    t_mono: float
    seen: list[str] | tuple[()] = ()
    v_meas: float = math.nan
    sw_meas: float = math.nan
    period_ws: float | None = None
    last_ws: float | None = None
    fresh: bool = False


class DriveLoop:
    """The drive loop (see the module docstring).

    Args:
        profile: the actuation profile.
        params: the controller's model (eq. 1, 7, 8).
        controller: ``step(state, reference, t_s) -> result`` with ``.command`` (steering-wheel
            angle, pedals), ``.ok``, ``.status``, ``.solve_time_s``, ``.zone``; and ``reset()``.
        reference: the trajectory.
        bus_kwargs: ``can.Bus`` arguments.
        candump: path of the candump ``-L`` log of every frame sent and received.
        duration_s: run time before the run's own controlled stop [s].
        faults: injected faults.
        node: the vehicle simulator node (for truth-based tracking figures and node-side faults).
        config: timing and stop behaviour.
        clock: ``monotonic()``, ``time()`` and ``sleep(s)`` of the loop (default
            :class:`SystemClock`, the real clocks; ``controller/replay.py`` injects a simulated
            one).
        adapter: an online model estimator (module docstring), or None.
    """

    def __init__(
        self,
        profile: ActuationProfile,
        params: Params,
        controller,
        reference: Reference,
        bus_kwargs: dict,
        candump: str | Path,
        *,
        duration_s: float,
        faults: list[Fault] | tuple[()] = (),
        node=None,
        config: DriveConfig = DriveConfig(),
        clock=None,
        adapter=None,
    ):
        self.adapter = adapter
        self.adapt_cpu_s: list = []  # the adapter's CPU time per control step [s]
        self._adapt_pending_s = 0.0
        self.profile = profile
        self.params = params
        self.controller = controller
        self.reference = reference
        self.bus_kwargs = dict(bus_kwargs)
        self.candump = Path(candump)
        self.duration_s = float(duration_s)
        self.faults = list(faults)
        self.node = node
        self.config = config
        self.clock = clock if clock is not None else SystemClock()
        self.plant = HybridPlant(params)
        self.toyota = profile.steering == "torque"
        check_node_faults(self.faults, node)
        ticks = {}
        for role, spec in profile.commands.items():
            k = spec.period_s / config.tick_s
            if abs(k - round(k)) > 0.02 * k or round(k) < 1:
                raise InputError(
                    f"command {role} at {spec.rate_hz:g} Hz is not a whole number of "
                    f"{config.tick_s * 1e3:g} ms ticks",
                    profile.path,
                )
            ticks[role] = int(round(k))
        self.ticks = ticks
        self.ctl_every = int(round(config.control_period_s / config.tick_s))
        self._stop_request = ""

    def request_stop(self, reason: str = "interrupted") -> None:
        """Ask for a controlled stop (e.g. from a SIGINT handler): safe from another thread."""
        self._stop_request = self._stop_request or str(reason)

    # --------------------------------------------------------------------- run
    def run(self) -> DriveResult:
        # BLAS on one thread for the whole run: every matrix of the loop is small (EKF 7x7,
        # the terminal cost's 3x3 DARE; the QP is OSQP's own C), where OpenBLAS's threads
        # only add wake-up latency: a 3x3 DARE took 33 ms median with two threads on a loaded
        # 2-core machine against 1.1 ms on one (the loop's period is 20 ms)
        with threadpool_limits(limits=1, user_api="blas"), _frozen_heap():
            return self._run()

    def _run(self) -> DriveResult:
        r = self._start_run()
        try:
            while True:
                tk = self._tick_clock(r)
                self._receive(r, tk)
                self._estimate(r, tk)
                self._poll_source(r, tk)
                if self._engagement(r, tk):
                    break
                r.stop_reason_pending = ""
                if r.state == "engaged" and r.k % self.ctl_every == 0:
                    self._control_step(r, tk)
                if r.state in ("stopping", "holding"):
                    self._stop_profile(r, tk)
                self._send_frames(r, tk)
                if self._run_over(r, tk):
                    break
                r.writer.flush()  # the candump, once this tick's frames are out
                r.k += 1
        finally:
            r.writer.stop()
            r.bus.shutdown()
            if self.node is not None:
                self.node.stop()
        fb = r.fb
        car_rejected = (
            int(fb.item("rejected_frames")) if "rejected_frames" in self.profile.feedback else None
        )
        summary = summarize(
            r.trace,
            r.periods,
            r.late_steps,
            r.solve_ms,
            r.statuses,
            r.failures,
            r.sent,
            r.act.blocked,
            r.act.clips,
            r.engaged_at,
            r.stop,
            r.k,
            profile_name=self.profile.name,
            controller_name=getattr(self.controller, "name", type(self.controller).__name__),
            reference=self.reference,
            node=self.node,
            car_rejected=car_rejected,
            control_period_s=self.config.control_period_s,
            candump=str(self.candump),
            estimator=self.config.estimator,
            steering_wheel_angle_max_rad=ActuatorLimits.from_params(
                self.params
            ).steering_wheel_angle_max_rad,
        )
        if self.adapter is not None:
            summary["adaptation"] = self.adapter.report()
            summary["adaptation_details"] = {
                **self.adapter.summary(),
                "cost_us": cpu_percentiles(self.adapt_cpu_s),
            }
        return DriveResult(summary, {kk: np.asarray(vv) for kk, vv in r.trace.items()})

    def _start_run(self) -> _Run:
        """Limiters and checks, the warmed controller, the bus, the log, the estimator and the
        simulator node's scheduled faults: everything the loop's first tick needs."""
        cfg = self.config
        prof = self.profile
        act = CommandPath(prof, self.params, cfg.tick_s)
        ref = self.reference
        # warm the controller (first solve builds the solver), then start clean
        x0 = ref.initial_state(self.params)
        self.controller.step(x0, ref, float(ref.time_s[0]))
        self.controller.reset()
        try:
            bus = can.Bus(**self.bus_kwargs)
        except (OSError, can.CanError, ValueError) as exc:  # no such interface, no driver
            where = ":".join(str(self.bus_kwargs.get(k)) for k in ("interface", "channel"))
            raise InputError(f"bus {where}: cannot open it ({exc})") from None
        self.candump.parent.mkdir(parents=True, exist_ok=True)
        writer = OrderedCandump(self.candump)  # time-ordered, written after the sends
        ekf = None
        if cfg.estimator == "ekf":
            from hmpc.controller.estimator import Estimator, EstimatorConfig

            # CAN resolution, not a phone-grade sensor: the wheel speeds are quantised to
            # 0.01 km/h (Toyota) / 1 mm/s (kit) and carry no other noise on the node
            ekf = Estimator(
                self.params, EstimatorConfig(can_speed_mps=0.005, init_wheel_scale=0.002)
            )
            ekf.reset(0.0, x0)
        r = _Run(
            fb=Feedback(prof),
            wd=Watchdog(cfg.watchdog),
            act=act,
            bus=bus,
            writer=writer,
            counters={role: 0 for role in prof.commands},
            sent={spec.message.name: 0 for spec in prof.commands.values()},
            trace={k: [] for k in TRACE_KEYS},
            est=x0.copy(),
            ekf=ekf,
            mono0=self.clock.monotonic(),
            epoch0=self.clock.time(),
        )
        if self.node is not None:
            self.node.start(r.mono0)
            schedule_node_faults(self.node, self.faults)
        return r

    def _send(self, r: _Run, msg: can.Message, t: float) -> bool:
        """Send one frame and log it; a bus error asks for a controlled stop."""
        try:
            if fault_active(self.faults, "bus_error", t):
                raise can.CanOperationError("injected bus_error: send failed")
            r.bus.send(msg)
        except can.CanError:
            r.stop_reason_pending = r.stop_reason_pending or "bus_error"
            return False
        msg.timestamp = r.epoch0 + (self.clock.monotonic() - r.mono0)
        msg.channel = 0
        msg.is_rx = False
        r.writer.on_message_received(msg)
        name = self.profile.db.get_message_by_frame_id(msg.arbitration_id).name
        r.sent[name] = r.sent.get(name, 0) + 1
        return True

    def _begin_stop(self, r: _Run, reason: str, tk: _Tick) -> None:
        """Start the controlled stop from the acceleration the current pedals ask for."""
        r.state = "stopping"
        r.stop["reason"], r.stop["detected_t_s"] = reason, tk.t
        r.stop_accel = self._accel_now(r.ap_cmd, r.bp_cmd, tk.v_meas)
        r.stop_bp = r.bp_cmd

    def _tick_clock(self, r: _Run) -> _Tick:
        """Step 1: wait for the tick, read the loop clock (fault: frozen), run the clock
        watchdog."""
        cfg = self.config
        target = r.mono0 + r.k * cfg.tick_s
        delay = target - self.clock.monotonic()
        if delay > 0:
            self.clock.sleep(delay)
        mono = self.clock.monotonic()
        t_mono = mono - r.mono0
        if fault_active(self.faults, "clock_freeze", t_mono) and not r.use_mono:
            r.t_freeze = r.t_freeze if r.t_freeze is not None else t_mono
            t = r.t_freeze
        else:
            t = t_mono
        reason = r.wd.clock(t, t_mono)
        if reason and not r.use_mono:
            r.use_mono = True  # the stop runs on the monotonic clock
            t = t_mono
            r.stop_reason_pending = r.stop_reason_pending or reason
        return _Tick(t=t, t_mono=t_mono)

    def _receive(self, r: _Run, tk: _Tick) -> None:
        """Step 2: drain the bus, log and decode what arrived, read the measured speed and angle."""
        fb = r.fb
        r.writer.reading(r.epoch0 + tk.t_mono)  # the tick began before this read
        tk.seen = fb.update(self._drain(r, tk), tk.t) + r.late_seen
        r.late_seen = []
        # eq. 1's speed is the front-axle centre's: the front wheels' mean (the
        # signal map's `speed`, the four-wheel mean, reads low by cos(delta) in turns)
        v_meas = 0.5 * (fb.value("wheel_speed_fl") + fb.value("wheel_speed_fr"))
        if not np.isfinite(v_meas):
            v_meas = fb.value("speed")
        tk.v_meas = v_meas
        tk.sw_meas = fb.value("steering_wheel_angle")
        # the wheel-speed period, learned from the frames' arrival times
        tk.period_ws = fb.wheel_speed_period()
        tk.last_ws = fb.ws_times[-1] if fb.ws_times else None

    def _drain(self, r: _Run, tk: _Tick) -> list:
        """Every frame waiting on the bus, logged as received (none while the
        ``feedback_loss`` fault is active: lost on the way, never seen, never logged)."""
        rx: list[can.Message] = []
        while True:
            m = r.bus.recv(timeout=0.0)
            if m is None:
                return rx
            if fault_active(self.faults, "feedback_loss", tk.t_mono):
                continue
            m.channel = 0
            m.is_rx = True
            r.writer.on_message_received(m)
            rx.append(m)

    def _estimate(self, r: _Run, tk: _Tick) -> None:
        """The state estimate, every tick from the start (the car starts on the reference)."""
        fb, t, v_meas, sw_meas = r.fb, tk.t, tk.v_meas, tk.sw_meas
        if r.ekf is not None:
            ekf = r.ekf
            ekf.predict(
                max(t, ekf.time_s),
                (sw_meas if np.isfinite(sw_meas) else r.sw_cmd, r.ap_cmd, r.bp_cmd),
            )
            if fb.speed_msg in tk.seen:
                yaw = fb.value("yaw_rate")
                ekf.update_can(
                    t,
                    wheel_speeds_mps=[
                        fb.value(f"wheel_speed_{w}") for w in ("fl", "fr", "rl", "rr")
                    ],
                    steering_wheel_angle_rad=sw_meas,
                    yaw_rate_radps=yaw if np.isfinite(yaw) else None,
                )
            r.est = ekf.state()
        elif r.t_est is not None and np.isfinite(v_meas) and np.isfinite(sw_meas) and t > r.t_est:
            est = r.est
            h = t - r.t_est
            delta = float(self.plant.road_wheel_angle(sw_meas))
            dpsi = heading_rate(v_meas, delta, self.plant.wheelbase_m, math) * h
            est[0] += v_meas * math.cos(est[2] + 0.5 * dpsi + delta) * h
            est[1] += v_meas * math.sin(est[2] + 0.5 * dpsi + delta) * h
            est[2] += dpsi
            est[3] = v_meas
        r.t_est = t
        if self.adapter is not None:
            c0 = time.thread_time()
            self._feed_adapter(r, tk)
            self._adapt_pending_s += time.thread_time() - c0

    def _feed_adapter(self, r: _Run, tk: _Tick) -> None:
        """This tick's fresh feedback to the adapter: wheel speeds and steering angle when the
        wheel-speed message came, the yaw rate and the acceleration when theirs did."""
        fb, t, sig = r.fb, tk.t, self.adapter.signals
        if fb.speed_msg in tk.seen:
            sig.add_can(
                t, [fb.value(f"wheel_speed_{w}") for w in ("fl", "fr", "rl", "rr")], tk.sw_meas
            )
        for ch, add in (("yaw_rate", sig.add_yaw), ("accel_x", sig.add_accel)):
            tv = fb.channels.get(ch)
            if tv is not None and tv[0] == t:
                add(t, tv[1])

    def _adapt(self, r: _Run, t: float) -> None:
        """The adapter's learning step at ``t`` [s]; a changed model to the controller, the
        estimator and the dead reckoning's eq. 7."""
        c0 = time.thread_time()
        bias = r.ekf.model_inputs()[1] if r.ekf is not None else 0.0
        model = self.adapter.learn(t, float(r.est[3]), bias if bias == bias else 0.0)
        if model is not None:
            use = getattr(self.controller, "use_model", None)
            if use is not None:
                use(model)
            if r.ekf is not None:
                r.ekf.use_model(model)
            self.plant.offset_rad, self.plant.scale = model.offset_rad, model.scale
        self._adapt_pending_s += time.thread_time() - c0

    def _poll_source(self, r: _Run, tk: _Tick) -> None:
        """Command-source hook (tele-operation, ``controller/teleop/vehicle.py``): a controller
        with ``poll`` is polled every tick, engaged or not; it says whether its operator has
        engaged (the loop engages only then) and may ask for a controlled stop by reason."""
        poll = getattr(self.controller, "poll", None)
        if poll is None:
            return
        gate = poll(
            tk.t, loop_state=r.state, speed_mps=tk.v_meas, steering_wheel_angle_rad=tk.sw_meas
        )
        self._source_engage = bool(gate.engage)
        if gate.stop and r.state == "disengaged":
            self.request_stop(gate.stop)  # never engaged: the run ends
        elif gate.stop:
            r.stop_reason_pending = r.stop_reason_pending or gate.stop

    def _engagement(self, r: _Run, tk: _Tick) -> bool:
        """Step 3: engagement, override, the car's status. True: end the run now (never engaged)."""
        cfg, prof, fb, t = self.config, self.profile, r.fb, tk.t
        accepts = fb.flag("accepts_steer") and fb.flag("accepts_long")
        tk.fresh = tk.period_ws is not None and not r.wd.feedback(
            t, tk.last_ws, max(tk.period_ws, 1e-3)
        )
        src = getattr(self, "_source_engage", None)  # None: no command source (_poll_source)
        if (
            r.state == "disengaged"
            and t >= cfg.engage_at_s
            and tk.fresh
            and accepts
            and src is not False
        ):
            r.state, r.engaged_at = "engaged", t
        if r.state == "engaged":
            why = ""
            if not tk.fresh:
                why = "feedback_loss"
            elif (
                abs(fb.item("driver_torque")) > prof.driver_torque_threshold
                or fb.flag("brake_pressed")
                or fb.flag("gas_pressed")
            ):
                why = "driver_override"
            elif not accepts:
                why = "vehicle_rejects"
            elif "rejected_frames" in prof.feedback:
                nrej = fb.item("rejected_frames")
                if r.rejected_seen is None:
                    r.rejected_seen = nrej
                elif nrej != r.rejected_seen:
                    why = "vehicle_rejects"
            why = r.stop_reason_pending or self._stop_request or why
            if why:
                self._begin_stop(r, why, tk)
            elif r.engaged_at is not None and t - r.engaged_at >= self.duration_s:
                self._begin_stop(r, "duration", tk)
        elif r.state == "disengaged" and self._stop_request:
            r.stop["reason"] = self._stop_request  # never engaged: nothing to stop
            return True
        elif (
            r.state == "disengaged"
            and t > cfg.engage_at_s + 5.0
            and not (src is False and tk.fresh and accepts)
        ):  # a source waits for its operator
            r.stop["reason"] = "car_not_accepting" if tk.fresh else "no_feedback"
            return True
        return False

    def _control_step(self, r: _Run, tk: _Tick) -> None:
        """Step 4: the controller, every control period; a failed solve or a missed deadline
        starts the controlled stop."""
        cfg, t, ref = self.config, tk.t, self.reference
        c0 = self.clock.monotonic()
        if r.last_ctl_start is not None:
            r.periods.append(c0 - r.last_ctl_start)
        r.last_ctl_start = c0
        t_ref = float(ref.time_s[0]) + t
        if self.adapter is not None:
            self._adapt(r, t)
        elif r.ekf is not None:  # offset-free steering (a learner takes the offset itself)
            correct = getattr(self.controller, "use_steering_correction", None)
            if correct is not None:
                correct(r.ekf.steering_correction_rad(), t_ref)
        res = self.controller.step(r.est.copy(), ref, t_ref)
        if fault_active(self.faults, "solver_failure", t):
            res = replace(res, status=Status.SHIFTED_PLAN, reason="solver failure (injected)")
        r.res = res
        r.statuses.append(str(res.status))
        r.solve_ms.append(1e3 * float(getattr(res, "solve_time_s", 0.0)))
        if not res.ok:
            r.failures += 1
            self._begin_stop(r, "solver_failure", tk)
        else:
            r.sw_cmd, r.ap_cmd, r.bp_cmd = (float(x) for x in res.command.as_tuple())
        if self.adapter is not None:
            c0 = time.thread_time()
            self.adapter.commanded(t, r.sw_cmd, r.ap_cmd, r.bp_cmd, float(r.est[3]))
            self.adapt_cpu_s.append(self._adapt_pending_s + time.thread_time() - c0)
            self._adapt_pending_s = 0.0
        record_row(
            r.trace,
            self.node,
            ref,
            t,
            t_ref,
            r.est,
            r.sw_cmd,
            tk.sw_meas,
            r.ap_cmd,
            r.bp_cmd,
            r.act.last_accel_req,
            res,
            engaged=1,
            stopping=0,
        )
        late = (self.clock.monotonic() - (r.mono0 + r.k * cfg.tick_s)) > cfg.control_period_s
        r.late_steps += int(late)
        why = r.wd.deadline(late)
        if why and r.state == "engaged":
            self._begin_stop(r, why, tk)

    def _stop_profile(self, r: _Run, tk: _Tick) -> None:
        """Step 5: the jerk-limited stop to standstill, then the hold (brake pedal ramp)."""
        cfg, t, v_meas = self.config, tk.t, tk.v_meas
        if (
            r.state == "stopping"
            and np.isfinite(v_meas)
            and tk.fresh
            and v_meas < cfg.standstill_mps
            and r.stop["t_s"] is not None
        ):
            r.state = "holding"
            r.stop["standstill_t_s"] = t
            r.hold_from = t
        dt = cfg.tick_s
        r.stop_accel = (
            max(r.stop_accel - cfg.stop_jerk_mps3 * dt, -cfg.stop_decel_mps2)
            if r.state == "stopping"
            else cfg.hold_accel_mps2
        )
        z = self.params.zones[self.plant.zone_by_speed(v_meas if np.isfinite(v_meas) else 0.0)]
        target_bp = min(max((z.offset_mps2 - r.stop_accel) / z.brake_scale_mps2, 0.0), 1.0)
        r.stop_bp = (
            min(target_bp, r.stop_bp + cfg.stop_jerk_mps3 / z.brake_scale_mps2 * dt)
            if target_bp > r.stop_bp
            else target_bp
        )
        r.ap_cmd, r.bp_cmd = 0.0, r.stop_bp
        if r.k % self.ctl_every == 0:
            record_row(
                r.trace,
                self.node,
                self.reference,
                t,
                math.nan,
                r.est,
                r.sw_cmd,
                tk.sw_meas,
                r.ap_cmd,
                r.bp_cmd,
                r.act.last_accel_req,
                None,
                engaged=0,
                stopping=1,
            )

    def _send_frames(self, r: _Run, tk: _Tick) -> None:
        """Step 6: each command frame at its own rate, limited, checked, encoded and sent."""
        t = tk.t
        # a last look at the bus before encoding: a status frame that arrived since step 2 (the
        # car no longer accepting commands) must reach the checks, as it reaches the panda
        # before our frame does
        late = self._drain(r, tk)
        if late:
            r.late_seen = r.fb.update(late, t)
        active = r.state in ("engaged", "stopping", "holding")
        steer_active = r.state == "engaged" or (
            r.state in ("stopping", "holding")
            and r.stop["reason"] not in ("driver_override", "feedback_loss")
        )
        act, fb = r.act, r.fb
        for role, spec in self.profile.commands.items():
            if r.k % self.ticks[role]:
                continue
            cnt = r.counters[role]  # advanced only when the frame left (below)
            if role == "steer_torque":
                msg = act.steer_torque(
                    fb, spec, cnt, t, tk.sw_meas, tk.v_meas, r.sw_cmd, steer_active
                )
            elif role == "accel":
                if r.state == "engaged":
                    a = self._accel_now(r.ap_cmd, r.bp_cmd, tk.v_meas)
                elif r.state in ("stopping", "holding"):
                    a = r.stop_accel
                else:
                    a = 0.0
                msg = act.accel(fb, spec, a, active)
            elif role == "steer_angle":
                msg = act.steer_angle(fb, spec, cnt, tk.sw_meas, tk.v_meas, r.sw_cmd, steer_active)
            elif role == "pedals":
                msg = act.pedals(
                    spec, cnt, r.ap_cmd, r.bp_cmd, active, self.config.tick_s * self.ticks[role]
                )
            else:  # heartbeat
                msg = builders.bw_heartbeat(spec, active or t >= self.config.engage_at_s, cnt)
            ok = self._send(r, msg, t)
            if ok:
                r.counters[role] = (cnt + 1) % max(spec.counter_modulo, 1)
            if (
                ok
                and r.state == "stopping"
                and r.stop["t_s"] is None
                and role in ("accel", "pedals")
            ):
                r.stop["t_s"] = t  # the first stop command that left

    def _run_over(self, r: _Run, tk: _Tick) -> bool:
        """Step 7: the hold has lasted ``hold_s``, or the stop has timed out."""
        cfg, t = self.config, tk.t
        if r.state == "holding" and r.hold_from is not None and t - r.hold_from >= cfg.hold_s:
            return True
        return (
            r.state == "stopping"
            and r.stop["detected_t_s"] is not None
            and t - r.stop["detected_t_s"] > cfg.stop_timeout_s
        )

    # ---------------------------------------------------------------- helpers
    def _accel_now(self, ap: float, bp: float, v_mps: float) -> float:
        """Eq. 8 forward in the zone of the current speed: the acceleration the pedal plan asks
        for (the Toyota path's request; the hybrid model still does the planning)."""
        v = v_mps if np.isfinite(v_mps) else 0.0
        z = self.params.zones[self.plant.zone_by_speed(v)]
        return float(z.offset_mps2 + z.scale_mps2 * ap - z.brake_scale_mps2 * bp)
