"""The real-time drive loop: the only owner of a ``can.Bus`` in hmpc.

Every tick (100 Hz, the fastest command's rate) the loop:

1. reads its clock and checks it against the monotonic clock (watchdog: frozen / jumping);
2. drains the bus, logs every received frame (candump ``-L``) and decodes the feedback with
   ingest's own signal map and decoder (``models.logs.signalmap`` / ``models.logs.decode``: one
   source of truth for what a frame means);
3. every control period (50 Hz by default) estimates the state and runs the controller (MPC,
   NMPC, PID, or an operator's commands passed through); the step RETURNS a command;
4. turns the command into the profile's quantities (Toyota: an inner angle loop gives the EPS
   torque, the zone model eq. 8 forward gives the acceleration request; by-wire: angle and
   pedals as they are), applies the limits (``safety.py`` limiter), checks them again
   independently at the encoder (``safety.py`` checks), encodes (``builders.py``) and sends each
   message at its own rate, logging every frame sent;
5. runs the watchdog: stale feedback (no wheel speeds for 3 periods), missed deadlines, a
   frozen or jumping clock, a failed solve, bus send errors, the car's status refusing the
   commands, and driver override (steering torque over the profile's threshold, brake or gas
   pressed) each start a controlled stop (steering held, braking at ``stop_decel_mps2`` with a
   jerk-limited ramp, to standstill, then held); the reason and times are reported.

Commands are sent only after an explicit engage (``engage_at_s``) and while the car's status
says it accepts them; before that the frames carry no request (torque 0 without the request
bit, acceleration 0, enable bits cleared).

State estimate (default): minimal dead reckoning: speed = the mean of the front wheel speeds
(eq. 1's point is the front-axle centre; the signal map's ``speed``, the four-wheel mean, is the
fallback), heading and position integrated every tick with eq. 1 (midpoint heading) from the
measured steering-wheel angle through the controller's own steering map (eq. 7).
``DriveConfig(estimator="ekf")`` feeds the shared estimator (``controller/estimator.py``,
issue 9) the decoded wheel speeds, steering angle and yaw rate instead; not the default yet
(see :class:`DriveConfig`: the Toyota's quantised yaw rate biases its heading when
straight). No GNSS reaches the bus, so position is dead reckoning either way; it drifts
with any steering-map mismatch, and the run JSON's tracking figures are measured on the
simulator node's true state when a node is present.
The run starts with the car on the reference's start, so the reference's clock is the loop's
clock (the controller takes over at engagement).

Toyota inner angle loop (tuned on the simulator node, whose EPS and steering column are
modelled in ``vehicle_node.py``): torque = k_ff(v) * angle_cmd + kp * e + ki * int(e)
- kd * rate, gains in :class:`InnerAngleLoop`; the integral is frozen while the torque
limiter binds (anti-windup).
"""
from __future__ import annotations

import gc
import math
import time
from collections import deque
from contextlib import contextmanager
from dataclasses import dataclass, field, replace
from pathlib import Path

import can
import numpy as np
from threadpoolctl import threadpool_limits

from hmpc.models.errors import InputError, Problems
from hmpc.models.logs.decode import decode_frames
from hmpc.models.logs.frames import FrameTable
from hmpc.models.params import Params
from hmpc.models.plant import HybridPlant, heading_rate
from hmpc.models.reference import Reference

from hmpc.controller.base import Status
from hmpc.controller.metrics import pedal_switches, smoothness_of
from hmpc.controller.actuation import builders
from hmpc.controller.actuation.profiles import ActuationProfile
from hmpc.controller.actuation.safety import (AngleCheck, AngleLimiter, AngleLimits, ToyotaLimits,
                                              ToyotaSteerCheck, ToyotaTorqueLimiter, accel_ok,
                                              clip_accel, clip_pedals, pedals_ok)
from hmpc.controller.actuation.watchdog import Watchdog, WatchdogConfig

#: injectable faults (``--fault NAME@T_S``)
FAULTS = ("feedback_loss", "clock_freeze", "solver_failure", "bus_error", "driver_override",
          "vehicle_rejects")
#: how long a transient injected fault lasts [s] (the controlled stop is latched)
FAULT_WINDOW_S = {"feedback_loss": 1.0, "clock_freeze": 0.5, "bus_error": 0.015,
                  "driver_override": 1.0, "vehicle_rejects": 0.3}


@dataclass(frozen=True)
class Fault:
    name: str
    t_s: float


def parse_fault(text: str) -> Fault:
    """``NAME@T_S`` -> Fault. Raises InputError naming the text."""
    name, sep, t = str(text).partition("@")
    if not sep or name not in FAULTS:
        raise InputError(f"--fault '{text}': expected NAME@T_S with NAME one of {', '.join(FAULTS)}")
    try:
        ts = float(t)
    except ValueError:
        raise InputError(f"--fault '{text}': '{t}' is not a time in seconds") from None
    if not (math.isfinite(ts) and ts >= 0):
        raise InputError(f"--fault '{text}': time must be >= 0")
    return Fault(name, ts)


@dataclass(frozen=True)
class InnerAngleLoop:
    """Gains of the Toyota path's inner angle loop [raw torque units], tuned on the simulator
    node (J 0.04 kg m^2, g 0.005 N m/unit): kp and kd place the loop at about 10 rad/s with
    damping 0.8; the feedforward cancels the self-aligning stiffness (k(v)/g)."""

    kff0: float = 60.0     # units/rad: 0.3 N m/rad / 0.005 N m/unit
    kff2: float = 0.8      # units s^2/(rad m^2): 0.004 / 0.005
    kp: float = 800.0      # units/rad
    ki: float = 400.0      # units/(rad s)
    kd: float = 110.0      # units/(rad/s)


INNER = InnerAngleLoop()


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
    # angle; "ekf": the shared estimator (controller/estimator.py, the one simulate and replay
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


class _Feedback:
    """Latest decoded feedback: canonical channels (signal map) and status items (profile)."""

    def __init__(self, profile: ActuationProfile):
        self.profile = profile
        self.smap = profile.signal_map
        self.names = profile.feedback_messages()
        self.channels: dict[str, tuple[float, float]] = {}   # channel -> (t_s, SI value)
        self.items: dict[str, tuple[float, float]] = {}      # item -> (t_s, value)
        self.eps = deque([0.0] * ToyotaLimits().eps_samples, maxlen=ToyotaLimits().eps_samples)
        self.ws_times: deque = deque(maxlen=40)    # ticks that decoded wheel speeds [s]
        self.ws_counts: deque = deque(maxlen=40)   # wheel-speed frames in each of them
        self.problems = Problems()
        by_msg: dict[str, list] = {}
        for ch in self.smap.channels.values():
            if ch.gear is None:
                by_msg.setdefault(ch.message, []).append(ch)
        self._maps = by_msg
        self._items: dict[str, list] = {}
        for it in profile.feedback.values():
            self._items.setdefault(it.message, []).append(it)
        self.ids = {profile.db.get_message_by_name(n).frame_id for n in self.names}
        ws = profile.signal_map.channels.get("speed")
        self.speed_msg = ws.message if ws is not None else None

    def update(self, msgs: list, t_s: float) -> list[str]:
        """Decode this tick's frames; returns the message names seen."""
        msgs = [m for m in msgs if m.arbitration_id in self.ids]
        if not msgs:
            return []
        n = len(msgs)
        data = np.zeros((n, 8), np.uint8)
        for i, m in enumerate(msgs):
            data[i, : len(m.data)] = np.frombuffer(bytes(m.data), np.uint8)[:8]
        ft = FrameTable(np.full(n, t_s), np.zeros(n, np.int16),
                        np.array([m.arbitration_id for m in msgs], np.uint32), np.zeros(n, bool),
                        np.array([len(m.data) for m in msgs], np.uint8), data,
                        np.arange(1, n + 1, dtype=np.int64), "<bus>")
        present = {self.profile.db.get_message_by_frame_id(i).name for i in set(ft.arb_id.tolist())}
        dec = decode_frames(ft, self.profile.db, self.problems,
                            names=[x for x in self.names if x in present])
        for name, d in dec.items():
            if len(d) == 0:
                continue
            for ch in self._maps.get(name, ()):
                if ch.bus is not None and ch.bus != 0:
                    continue
                v = ch.evaluate(d.signals)[-1]
                if np.isfinite(v):
                    self.channels[ch.channel] = (t_s, float(v))
            for it in self._items.get(name, ()):
                vals = d.signals[it.signal]
                self.items[it.name] = (t_s, float(vals[-1]))
                if it.name == "eps_torque":
                    for x in vals:
                        self.eps.append(float(x) * ToyotaLimits().eps_torque_factor)
            if name == self.speed_msg:
                # one arrival time per tick, with the number of frames that tick: frames
                # decoded twice in a tick (step 2 and the last look before encoding) must not
                # add zero intervals, and two frames in one tick are two periods
                if self.ws_times and self.ws_times[-1] == t_s:
                    self.ws_counts[-1] += len(d)
                else:
                    self.ws_times.append(t_s)
                    self.ws_counts.append(len(d))
        return list(dec)

    def wheel_speed_period(self) -> float | None:
        """The wheel speeds' period [s] learned from the last ~40 ticks that decoded them:
        their time span over the frames after the first tick. The median interval between
        such ticks would be quantised to the 10 ms tick (83 Hz Toyota frames arrive 10 or
        20 ms apart: median 10 ms, the stale rule's 3 periods 30 ms instead of 36 ms)."""
        if len(self.ws_times) <= 5:
            return None
        n = sum(self.ws_counts) - self.ws_counts[0]
        return (self.ws_times[-1] - self.ws_times[0]) / n if n > 0 else None

    def value(self, channel: str, default: float = math.nan) -> float:
        x = self.channels.get(channel)
        return default if x is None else x[1]

    def flag(self, item: str) -> bool:
        it = self.profile.feedback.get(item)
        x = self.items.get(item)
        return False if it is None or x is None else it.flag(x[1])

    def item(self, item: str, default: float = 0.0) -> float:
        x = self.items.get(item)
        return default if x is None else x[1]


@dataclass
class _Actuation:
    """The command path's limiters, checks and inner-loop state, kept across ticks."""

    tl: ToyotaLimits
    lim_t: ToyotaTorqueLimiter
    chk_t: ToyotaSteerCheck
    al: AngleLimits
    lim_a: AngleLimiter
    chk_a: AngleCheck | None
    integ: float = 0.0              # inner angle loop's integral [raw torque units]
    rate_f: float = 0.0             # filtered steering-wheel rate [rad/s]
    last_sw: float | None = None    # last measured steering-wheel angle [rad]
    prev_pedals: tuple | None = None


@dataclass
class _Run:
    """The drive loop's state carried from tick to tick (and the figures it collects)."""

    fb: _Feedback
    wd: Watchdog
    act: _Actuation
    bus: can.BusABC
    writer: _OrderedCandump
    counters: dict
    sent: dict
    trace: dict
    est: np.ndarray
    ekf: object
    mono0: float
    epoch0: float
    blocked: dict = field(default_factory=dict)
    clips: dict = field(default_factory=lambda: {"steer": 0, "long": 0})
    periods: list = field(default_factory=list)
    late_steps: int = 0
    solve_ms: list = field(default_factory=list)
    statuses: list = field(default_factory=list)
    failures: int = 0
    state: str = "disengaged"
    engaged_at: float | None = None
    stop: dict = field(default_factory=lambda: {"reason": None, "t_s": None,
                                                "detected_t_s": None, "standstill_t_s": None})
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


class _OrderedCandump:
    """The run's candump, written in time order without work between reading and sending.

    A sent frame is stamped when it is sent, a received one when it reached the bus; a frame
    that arrives while the loop encodes and sends (after its last look at the bus) is read
    on the next tick, after frames stamped later were logged. The loop's calls only keep the
    frame (``on_message_received``); after the tick's frames are sent, ``flush`` writes, in
    time order, those older than the previous tick's first read (every frame that old was
    on the bus then, and has been read: one tick of margin for a sender stamped before it
    queued its frame). ``stop`` writes the rest, sorted, and closes the file."""

    def __init__(self, path: Path):
        self._writer = can.CanutilsLogWriter(str(path), channel="can0")
        self._held: list = []
        self._mark = -math.inf   # the previous tick's first read [s, the frames' clock]
        self._read_at = -math.inf

    def on_message_received(self, msg: can.Message) -> None:
        self._held.append(msg)

    def reading(self, t_s: float) -> None:
        """The tick's first read of the bus starts at ``t_s`` [s, the frames' clock]."""
        self._mark, self._read_at = self._read_at, t_s

    def flush(self) -> None:
        held = self._held
        if not held:
            return
        held.sort(key=lambda m: m.timestamp)  # stable: a tie keeps its logging order
        n = 0
        while n < len(held) and held[n].timestamp < self._mark:
            self._writer.on_message_received(held[n])
            n += 1
        del held[:n]

    def stop(self) -> None:
        self._mark = math.inf
        self.flush()
        self._writer.stop()


class SystemClock:
    """The drive loop's default clock: the real ones (``time.monotonic`` [s], ``time.time``
    [s since the epoch], ``time.sleep``). A replay injects a simulated clock with the same three
    methods, so that a recorded log runs through the loop deterministically."""

    monotonic = staticmethod(time.monotonic)
    sleep = staticmethod(time.sleep)
    time = staticmethod(time.time)   # last: it shadows the module name in this class body


@dataclass
class _Tick:
    """One tick's clock and measurements."""

    t: float
    t_mono: float
    seen: object = ()
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
            :class:`SystemClock`, the real clocks; ``controller/replay.py`` injects a simulated one).
    """

    def __init__(self, profile: ActuationProfile, params: Params, controller, reference: Reference,
                 bus_kwargs: dict, candump: str | Path, *, duration_s: float,
                 faults: list[Fault] = (), node=None, config: DriveConfig = DriveConfig(),
                 clock=None):
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
        if any(f.name in ("driver_override", "vehicle_rejects") for f in self.faults) and node is None:
            raise InputError("faults driver_override and vehicle_rejects act on the car: they need "
                             "the vehicle simulator node (--vehicle-sim)")
        ticks = {}
        for role, spec in profile.commands.items():
            k = spec.period_s / config.tick_s
            if abs(k - round(k)) > 0.02 * k or round(k) < 1:
                raise InputError(f"command {role} at {spec.rate_hz:g} Hz is not a whole number of "
                                 f"{config.tick_s * 1e3:g} ms ticks", profile.path)
            ticks[role] = int(round(k))
        self.ticks = ticks
        self.ctl_every = int(round(config.control_period_s / config.tick_s))
        self._stop_request = ""

    def request_stop(self, reason: str = "interrupted") -> None:
        """Ask for a controlled stop (e.g. from a SIGINT handler): safe from another thread."""
        self._stop_request = self._stop_request or str(reason)

    # ------------------------------------------------------------------ faults
    def _fault_active(self, name: str, t: float) -> bool:
        for f in self.faults:
            if f.name == name and t >= f.t_s and (name not in FAULT_WINDOW_S
                                                   or t < f.t_s + FAULT_WINDOW_S[name]):
                return True
        return False

    def _fault_time(self, name: str):
        return next((f.t_s for f in self.faults if f.name == name), None)

    # --------------------------------------------------------------------- run
    def run(self) -> DriveResult:
        # BLAS on one thread for the whole run: every matrix of the loop is small (EKF 7x7,
        # the terminal cost's 3x3 DARE; the QP is OSQP's own C), where OpenBLAS's threads
        # only add wake-up latency: control.dlqr took 33 ms median with two threads on a
        # loaded 2-core machine against 1.1 ms on one (the loop's period is 20 ms)
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
        self._car_rejected = int(fb.item("rejected_frames")) \
            if "rejected_frames" in self.profile.feedback else None
        return DriveResult(self._summary(r.trace, r.periods, r.late_steps, r.solve_ms, r.statuses,
                                         r.failures, r.sent, r.blocked, r.clips, r.engaged_at,
                                         r.stop, r.k),
                           {kk: np.asarray(vv) for kk, vv in r.trace.items()})

    def _start_run(self) -> _Run:
        """Limiters and checks, the warmed controller, the bus, the log, the estimator and the
        simulator node's scheduled faults: everything the loop's first tick needs."""
        cfg = self.config
        prof = self.profile
        tl = ToyotaLimits()
        al = AngleLimits.from_params(self.params)
        act = _Actuation(
            tl=tl, lim_t=ToyotaTorqueLimiter(tl), chk_t=ToyotaSteerCheck(tl), al=al,
            lim_a=AngleLimiter(al),
            chk_a=AngleCheck(al, prof.commands["steer_angle"].period_s)
            if "steer_angle" in prof.commands else None)
        ref = self.reference
        # warm the controller (first solve builds the solver), then start clean
        x0 = ref.initial_state(self.params)
        self.controller.step(x0, ref, float(ref.time_s[0]))
        self.controller.reset()
        try:
            bus = can.Bus(**self.bus_kwargs)
        except (OSError, can.CanError, ValueError) as exc:   # no such interface, no driver
            where = ":".join(str(self.bus_kwargs.get(k)) for k in ("interface", "channel"))
            raise InputError(f"bus {where}: cannot open it ({exc})") from None
        self.candump.parent.mkdir(parents=True, exist_ok=True)
        writer = _OrderedCandump(self.candump)  # time-ordered, written after the sends
        ekf = None
        if cfg.estimator == "ekf":
            from hmpc.controller.estimator import Estimator, EstimatorConfig
            # CAN resolution, not a phone-grade sensor: the wheel speeds are quantised to
            # 0.01 km/h (Toyota) / 1 mm/s (kit) and carry no other noise on the node
            ekf = Estimator(self.params, EstimatorConfig(can_speed_mps=0.005, init_wheel_scale=0.002))
            ekf.reset(0.0, x0)
        r = _Run(
            fb=_Feedback(prof), wd=Watchdog(cfg.watchdog), act=act, bus=bus, writer=writer,
            counters={role: 0 for role in prof.commands},
            sent={spec.message.name: 0 for spec in prof.commands.values()},
            trace={k: [] for k in ("t_s", "x", "y", "v", "v_ref", "sw_cmd", "sw", "ap_cmd",
                                   "bp_cmd", "accel_req", "zone", "t_ref", "engaged", "stopping")},
            est=x0.copy(), ekf=ekf, mono0=self.clock.monotonic(),
            epoch0=self.clock.time())
        if self.node is not None:
            self.node.start(r.mono0)
            if self._fault_time("driver_override") is not None:
                self.node.driver_steers(self._fault_time("driver_override"),
                                        FAULT_WINDOW_S["driver_override"])
            if self._fault_time("vehicle_rejects") is not None:
                self.node.reject_commands(self._fault_time("vehicle_rejects"),
                                          FAULT_WINDOW_S["vehicle_rejects"])
        return r

    def _send(self, r: _Run, msg: can.Message, t: float) -> bool:
        """Send one frame and log it; a bus error asks for a controlled stop."""
        try:
            if self._fault_active("bus_error", t):
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
        """Step 1: wait for the tick, read the loop clock (fault: frozen), run the clock watchdog."""
        cfg = self.config
        target = r.mono0 + r.k * cfg.tick_s
        delay = target - self.clock.monotonic()
        if delay > 0:
            self.clock.sleep(delay)
        mono = self.clock.monotonic()
        t_mono = mono - r.mono0
        if self._fault_active("clock_freeze", t_mono) and not r.use_mono:
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
        # the wheel-speed period, learned from the frames (median interval)
        tk.period_ws = fb.wheel_speed_period()
        tk.last_ws = fb.ws_times[-1] if fb.ws_times else None

    def _drain(self, r: _Run, tk: _Tick) -> list:
        """Every frame waiting on the bus, logged as received (none while the
        ``feedback_loss`` fault is active: lost on the way, never seen, never logged)."""
        rx = []
        while True:
            m = r.bus.recv(timeout=0.0)
            if m is None:
                return rx
            if self._fault_active("feedback_loss", tk.t_mono):
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
            ekf.predict(max(t, ekf.time_s), (sw_meas if np.isfinite(sw_meas) else r.sw_cmd,
                                             r.ap_cmd, r.bp_cmd))
            if fb.speed_msg in tk.seen:
                yaw = fb.value("yaw_rate")
                ekf.update_can(t, wheel_speeds_mps=[fb.value(f"wheel_speed_{w}")
                                                    for w in ("fl", "fr", "rl", "rr")],
                               steering_wheel_angle_rad=sw_meas,
                               yaw_rate_radps=yaw if np.isfinite(yaw) else None)
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

    def _poll_source(self, r: _Run, tk: _Tick) -> None:
        """Command-source hook (tele-operation, ``controller/teleop/vehicle.py``): a controller
        with ``poll`` is polled every tick, engaged or not; it says whether its operator has
        engaged (the loop engages only then) and may ask for a controlled stop by reason."""
        poll = getattr(self.controller, "poll", None)
        if poll is None:
            return
        gate = poll(tk.t, loop_state=r.state, speed_mps=tk.v_meas,
                    steering_wheel_angle_rad=tk.sw_meas)
        self._source_engage = bool(gate.engage)
        if gate.stop and r.state == "disengaged":
            self.request_stop(gate.stop)          # never engaged: the run ends
        elif gate.stop:
            r.stop_reason_pending = r.stop_reason_pending or gate.stop

    def _engagement(self, r: _Run, tk: _Tick) -> bool:
        """Step 3: engagement, override, the car's status. True: end the run now (never engaged)."""
        cfg, prof, fb, t = self.config, self.profile, r.fb, tk.t
        accepts = fb.flag("accepts_steer") and fb.flag("accepts_long")
        tk.fresh = tk.period_ws is not None \
            and not r.wd.feedback(t, tk.last_ws, max(tk.period_ws, 1e-3))
        src = getattr(self, "_source_engage", None)  # None: no command source (_poll_source)
        if r.state == "disengaged" and t >= cfg.engage_at_s and tk.fresh and accepts \
                and src is not False:
            r.state, r.engaged_at = "engaged", t
        if r.state == "engaged":
            why = ""
            if not tk.fresh:
                why = "feedback_loss"
            elif abs(fb.item("driver_torque")) > prof.driver_torque_threshold \
                    or fb.flag("brake_pressed") or fb.flag("gas_pressed"):
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
            elif t - r.engaged_at >= self.duration_s:
                self._begin_stop(r, "duration", tk)
        elif r.state == "disengaged" and self._stop_request:
            r.stop["reason"] = self._stop_request  # never engaged: nothing to stop
            return True
        elif r.state == "disengaged" and t > cfg.engage_at_s + 5.0 \
                and not (src is False and tk.fresh and accepts):  # a source waits for its operator
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
        res = self.controller.step(r.est.copy(), ref, t_ref)
        if self._fault_active("solver_failure", t):
            res = replace(res, status=Status.SHIFTED_PLAN, reason="solver failure (injected)")
        r.res = res
        r.statuses.append(str(res.status))
        r.solve_ms.append(1e3 * float(getattr(res, "solve_time_s", 0.0)))
        if not res.ok:
            r.failures += 1
            self._begin_stop(r, "solver_failure", tk)
        else:
            r.sw_cmd, r.ap_cmd, r.bp_cmd = (float(x) for x in res.command.as_tuple())
        self._record(r.trace, t, t_ref, r.est, r.sw_cmd, tk.sw_meas, r.ap_cmd, r.bp_cmd, res,
                     engaged=1, stopping=0)
        late = (self.clock.monotonic() - (r.mono0 + r.k * cfg.tick_s)) > cfg.control_period_s
        r.late_steps += int(late)
        why = r.wd.deadline(late)
        if why and r.state == "engaged":
            self._begin_stop(r, why, tk)

    def _stop_profile(self, r: _Run, tk: _Tick) -> None:
        """Step 5: the jerk-limited stop to standstill, then the hold (brake pedal ramp)."""
        cfg, t, v_meas = self.config, tk.t, tk.v_meas
        if r.state == "stopping" and np.isfinite(v_meas) and tk.fresh \
                and v_meas < cfg.standstill_mps and r.stop["t_s"] is not None:
            r.state = "holding"
            r.stop["standstill_t_s"] = t
            r.hold_from = t
        dt = cfg.tick_s
        r.stop_accel = max(r.stop_accel - cfg.stop_jerk_mps3 * dt, -cfg.stop_decel_mps2) \
            if r.state == "stopping" else cfg.hold_accel_mps2
        z = self.params.zones[self.plant.zone_by_speed(v_meas if np.isfinite(v_meas) else 0.0)]
        target_bp = min(max((z.offset_mps2 - r.stop_accel) / z.brake_scale_mps2, 0.0), 1.0)
        r.stop_bp = min(target_bp, r.stop_bp + cfg.stop_jerk_mps3 / z.brake_scale_mps2 * dt) \
            if target_bp > r.stop_bp else target_bp
        r.ap_cmd, r.bp_cmd = 0.0, r.stop_bp
        if r.k % self.ctl_every == 0:
            self._record(r.trace, t, math.nan, r.est, r.sw_cmd, tk.sw_meas, r.ap_cmd, r.bp_cmd,
                         None, engaged=0, stopping=1)

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
        steer_active = r.state == "engaged" or (r.state in ("stopping", "holding")
                                                and r.stop["reason"] not in ("driver_override",
                                                                             "feedback_loss"))
        for role, spec in self.profile.commands.items():
            if r.k % self.ticks[role]:
                continue
            cnt = r.counters[role]  # advanced only when the frame left (below)
            if role == "steer_torque":
                msg = self._frame_steer_torque(r, tk, spec, cnt, active, steer_active)
            elif role == "accel":
                msg = self._frame_accel(r, tk, spec, active)
            elif role == "steer_angle":
                msg = self._frame_steer_angle(r, tk, spec, cnt, steer_active)
            elif role == "pedals":
                msg = self._frame_pedals(r, spec, cnt, active, self.config.tick_s * self.ticks[role])
            else:  # heartbeat
                msg = builders.bw_heartbeat(spec, active or t >= self.config.engage_at_s, cnt)
            ok = self._send(r, msg, t)
            if ok:
                r.counters[role] = (cnt + 1) % max(spec.counter_modulo, 1)
            if ok and r.state == "stopping" and r.stop["t_s"] is None \
                    and role in ("accel", "pedals"):
                r.stop["t_s"] = t   # the first stop command that left

    def _block(self, r: _Run, why: str) -> None:
        r.blocked[why] = r.blocked.get(why, 0) + 1

    def _frame_steer_torque(self, r: _Run, tk: _Tick, spec, cnt: int, active: bool,
                            steer_active: bool) -> can.Message:
        """Toyota: the inner angle loop's EPS torque, limited and checked (STEERING_LKA)."""
        cfg, fb, a, t, sw_meas = self.config, r.fb, r.act, tk.t, tk.sw_meas
        if np.isfinite(sw_meas):
            if a.last_sw is not None:
                a.rate_f += ((sw_meas - a.last_sw) / cfg.tick_s - a.rate_f) * 0.3
            a.last_sw = sw_meas
        # panda: controls allowed = cruise on; and no request while the EPS
        # reports a fault (it re-engages from 0 after one)
        allowed = fb.flag("accepts_long")
        steer_ok = allowed and fb.flag("accepts_steer")
        want = 0.0
        if steer_active and np.isfinite(sw_meas):
            vv = tk.v_meas if np.isfinite(tk.v_meas) else 0.0
            e = r.sw_cmd - sw_meas
            want = (INNER.kff0 + INNER.kff2 * vv * vv) * r.sw_cmd + INNER.kp * e + a.integ \
                - INNER.kd * a.rate_f
        emin, emax = min(fb.eps), max(fb.eps)
        tq = a.lim_t.clip(want, t, emin, emax, active=steer_active and steer_ok)
        if steer_active and np.isfinite(sw_meas):
            if abs(tq - want) < 1:
                a.integ += INNER.ki * (r.sw_cmd - sw_meas) * cfg.tick_s
            else:
                r.clips["steer"] += 1
        else:
            a.integ = 0.0
        req = bool(steer_active and steer_ok)
        a.chk_t.meas.clear()          # the check's EPS samples: the decoded ones
        a.chk_t.meas.extend(fb.eps)
        why = a.chk_t.check(tq, req, t, allowed)
        if why:
            self._block(r, why)
            a.lim_t.reset(t)
            tq, req = 0, False
        return builders.steering_lka(spec, tq, req, cnt)

    def _frame_accel(self, r: _Run, tk: _Tick, spec, active: bool) -> can.Message:
        """Toyota: the acceleration request (eq. 8 forward, or the stop's), limited and checked."""
        tl = r.act.tl
        allowed = r.fb.flag("accepts_long")
        if r.state == "engaged":
            a = self._accel_now(r.ap_cmd, r.bp_cmd, tk.v_meas)
        elif r.state in ("stopping", "holding"):
            a = r.stop_accel
        else:
            a = 0.0
        a2 = clip_accel(a, tl, active=active and allowed)
        if active and allowed and abs(a2 - a) > 1e-9:
            r.clips["long"] += 1
        why = accel_ok(a2, active and allowed, tl)
        if why:
            self._block(r, why)
            a2 = tl.accel_inactive_mps2 if not (active and allowed) else -1.0
        self._last_accel_req = a2
        return builders.acc_control(spec, a2)

    def _frame_steer_angle(self, r: _Run, tk: _Tick, spec, cnt: int,
                           steer_active: bool) -> can.Message:
        """By-wire: the steering-wheel angle command, limited and checked (BW_STEER_CMD)."""
        a_, sw_meas = r.act, tk.sw_meas
        vv = self._limit_speed(r, tk)
        ang = r.sw_cmd if steer_active else (sw_meas if np.isfinite(sw_meas) else 0.0)
        a = a_.lim_a.clip(ang, vv, spec.period_s)
        if steer_active and abs(a - ang) > 1e-3:
            r.clips["steer"] += 1
        why = a_.chk_a.check(a, vv)
        if why:
            self._block(r, why)
            a = a_.chk_a.last if a_.chk_a.last is not None else 0.0
        return builders.bw_steer_cmd(spec, a, steer_active, cnt)

    @staticmethod
    def _limit_speed(r: _Run, tk: _Tick) -> float:
        """The speed [m/s] the speed-scheduled steering limits are taken at: the highest of
        the tick's reading and the freshest wheel speeds (the last look before encoding may
        have decoded newer ones, logged before this frame). The ISO 11270 bounds tighten as
        the speed grows: a stale, lower speed would allow more than the car's state does,
        and the candump audit, which takes the latest speed frame, would count it."""
        fb = r.fb
        vals = [v for v in (tk.v_meas, fb.value("speed"),
                            0.5 * (fb.value("wheel_speed_fl") + fb.value("wheel_speed_fr")))
                if np.isfinite(v)]
        return max(vals) if vals else 0.0

    def _frame_pedals(self, r: _Run, spec, cnt: int, active: bool, dt: float) -> can.Message:
        """By-wire: the pedal positions, rate-limited and checked (BW_PEDAL_CMD)."""
        a = r.act
        ap, bp = (r.ap_cmd, r.bp_cmd) if active else (0.0, 0.0)
        ap2, bp2 = clip_pedals(ap, bp, a.prev_pedals, dt, a.al)
        if active and (abs(ap2 - ap) > 1e-3 or abs(bp2 - bp) > 1e-3):
            r.clips["long"] += 1
        why = pedals_ok(ap2, bp2, a.al)
        if why:
            self._block(r, why)
            ap2, bp2 = 0.0, (a.prev_pedals[1] if a.prev_pedals else 0.0)
        a.prev_pedals = (ap2, bp2)
        return builders.bw_pedal_cmd(spec, ap2, bp2, active, cnt)

    def _run_over(self, r: _Run, tk: _Tick) -> bool:
        """Step 7: the hold has lasted ``hold_s``, or the stop has timed out."""
        cfg, t = self.config, tk.t
        if r.state == "holding" and t - r.hold_from >= cfg.hold_s:
            return True
        return r.state == "stopping" and r.stop["detected_t_s"] is not None \
            and t - r.stop["detected_t_s"] > cfg.stop_timeout_s

    # ---------------------------------------------------------------- helpers
    def _accel_now(self, ap: float, bp: float, v_mps: float) -> float:
        """Eq. 8 forward in the zone of the current speed: the acceleration the pedal plan asks
        for (the Toyota path's request; the hybrid model still does the planning)."""
        v = v_mps if np.isfinite(v_mps) else 0.0
        z = self.params.zones[self.plant.zone_by_speed(v)]
        return float(z.offset_mps2 + z.scale_mps2 * ap - z.brake_scale_mps2 * bp)

    def _record(self, trace, t, t_ref, est, sw_cmd, sw_meas, ap, bp, res, engaged, stopping):
        truth = self.node.snapshot() if self.node is not None else None
        x, y, v = (truth["state"][0], truth["state"][1], truth["state"][3]) if truth \
            else (est[0], est[1], est[3])
        trace["t_s"].append(t)
        trace["x"].append(x)
        trace["y"].append(y)
        trace["v"].append(v)
        trace["v_ref"].append(float(self.reference.speed_at(t_ref)) if np.isfinite(t_ref) else math.nan)
        trace["t_ref"].append(t_ref)
        trace["sw_cmd"].append(sw_cmd)
        trace["sw"].append(truth["sw_rad"] if truth else sw_meas)
        trace["ap_cmd"].append(ap)
        trace["bp_cmd"].append(bp)
        trace["accel_req"].append(getattr(self, "_last_accel_req", math.nan))
        trace["zone"].append(int(getattr(res, "zone", -1)) if res is not None else -1)
        trace["engaged"].append(engaged)
        trace["stopping"].append(stopping)

    def _summary(self, trace, periods, late_steps, solve_ms, statuses, failures, sent, blocked,
                 clips, engaged_at, stop, ticks) -> dict:
        def pct(a, q):
            return float(np.percentile(a, q)) if len(a) else 0.0
        per = np.asarray(periods) * 1e3
        tr = {k: np.asarray(v, dtype=float) for k, v in trace.items()}
        eng = tr["engaged"] > 0.5 if len(tr["t_s"]) else np.zeros(0, bool)
        kpi = {"speed_error_rms_mps": None, "lateral_error_rms_m": None,
               "pedal_switches_per_min": None, "zone_transitions_per_min": None,
               "steering_reversals_per_min": None, "steering_rate_rms_radps": None,
               "accel_pedal_rate_rms_ps": None, "brake_pedal_rate_rms_ps": None}
        if eng.sum() >= 2:
            t = tr["t_ref"][eng]
            minutes = max((t[-1] - t[0]) / 60.0, 1e-9)
            ev = tr["v"][eng] - tr["v_ref"][eng]
            lat = self.reference.lateral_errors(tr["x"][eng], tr["y"][eng], t)
            ap, bp = tr["ap_cmd"][eng], tr["bp_cmd"][eng]
            z = tr["zone"][eng]
            kpi = {"speed_error_rms_mps": float(np.sqrt(np.mean(ev ** 2))),
                   "lateral_error_rms_m": float(np.sqrt(np.mean(np.asarray(lat) ** 2))),
                   "pedal_switches_per_min": pedal_switches(ap, bp) / minutes,
                   "zone_transitions_per_min": int(np.count_nonzero(np.diff(z))) / minutes,
                   # issue 9's smoothness of the commands the controller gave, as simulate's:
                   # the engaged rows are the control updates, so a rate is each update's
                   # change over the control period (metrics.rate_rms)
                   **smoothness_of(tr["t_s"][eng], tr["sw_cmd"][eng], ap, bp)}
        sm = np.asarray(solve_ms)
        node = self.node.stats.to_dict() if self.node is not None else None
        # the node's count; without a node, what the car reports (the kit's REJECTED_FRAMES)
        rejected = node["rejected_total"] if node is not None else self._car_rejected
        jitter = np.abs(per - self.config.control_period_s * 1e3)
        out = {
            "profile": self.profile.name,
            "controller": getattr(self.controller, "name", type(self.controller).__name__),
            "reference": self.reference.name,
            "steps": int(len(statuses)),
            "ticks": int(ticks),
            "loop_period_ms": {"p50": pct(per, 50), "p99": pct(per, 99),
                               "max": float(per.max()) if len(per) else 0.0},
            "loop_jitter_ms": {"p99": pct(jitter, 99), "max": float(jitter.max()) if len(jitter) else 0.0},
            "deadline_misses": int(late_steps),
            "frames_sent": dict(sent),
            "frames_rejected_by_vehicle": rejected,
            "limit_clips": dict(clips),
            "blocked_at_encoder": dict(blocked),
            "limit_violations": None,  # filled by audit_candump
            "engaged_s": (float(tr["t_s"][eng][-1] - engaged_at) if engaged_at is not None
                          and eng.any() else 0.0),
            "stop": {k: (round(v, 4) if isinstance(v, float) else v) for k, v in stop.items()},
            **kpi,
            "solve_time_ms": {"p50": pct(sm, 50), "p99": pct(sm, 99),
                              "max": float(sm.max()) if len(sm) else 0.0},
            "failures": int(failures),
            "node": node,
            "candump": str(self.candump),
            "estimator": self.config.estimator,
        }
        return out


def audit_candump(profile: ActuationProfile, params: Params, path: str | Path) -> dict:
    """Re-check every command frame of a drive's candump, read back with hmpc's own reader and
    decoder, with fresh limit checks (independent of the loop's state): the ``limit_violations``
    of the run JSON. Returns {"limit_violations": n, "by_reason": {...}, "frames_checked": n}."""
    from hmpc.models.logs.canlog import read_log

    probs = Problems()
    ft = read_log(path, probs)
    db = profile.db
    tl = ToyotaLimits()
    chk_t = ToyotaSteerCheck(tl)
    al = AngleLimits.from_params(params)
    chk_a = AngleCheck(al, profile.commands["steer_angle"].period_s) \
        if "steer_angle" in profile.commands else None
    by: dict[str, int] = {}
    checked = 0
    allowed = False
    v = 0.0
    ids = {c.message.frame_id: c for c in profile.commands.values()}
    speed_ch = profile.signal_map.channels["speed"]
    for i in range(len(ft)):
        fid = int(ft.arb_id[i])
        data = bytes(ft.data[i, : ft.dlc[i]])
        t = float(ft.t_s[i])
        try:
            m = db.get_message_by_frame_id(fid)
        except KeyError:
            continue
        if fid in ids:
            spec = ids[fid]
            raw = m.decode(data, decode_choices=False, scaling=False)
            checked += 1
            why = ""
            if spec.role == "steer_torque":
                why = chk_t.check(int(raw[spec.values["steer_torque"]]),
                                  bool(raw[spec.enable[0]]), t, allowed)
            elif spec.role == "accel":
                s = m.get_signal_by_name(spec.values["accel_mps2"])
                a = raw[spec.values["accel_mps2"]] * s.scale
                why = accel_ok(a, allowed or a == 0.0, tl)
            elif spec.role == "steer_angle":
                s = m.get_signal_by_name(spec.values["steering_wheel_angle_rad"])
                why = chk_a.check(raw[spec.values["steering_wheel_angle_rad"]] * s.scale, v)
            elif spec.role == "pedals":
                sa = m.get_signal_by_name(spec.values["accel_pedal"]).scale
                sb = m.get_signal_by_name(spec.values["brake_pedal"]).scale
                why = pedals_ok(raw[spec.values["accel_pedal"]] * sa,
                                raw[spec.values["brake_pedal"]] * sb, al)
            if why:
                by[why] = by.get(why, 0) + 1
            continue
        if m.name == speed_ch.message:
            sig = m.decode(data, decode_choices=False)
            v = float(speed_ch.evaluate({k: np.array([x]) for k, x in sig.items()})[0])
        if m.name == "STEER_TORQUE_SENSOR" and profile.steering == "torque":
            chk_t.eps_torque(m.decode(data, decode_choices=False)["STEER_TORQUE_EPS"])
        it = profile.feedback.get("accepts_long")
        if it is not None and m.name == it.message:
            allowed = it.flag(float(m.decode(data, decode_choices=False)[it.signal]))
    return {"limit_violations": int(sum(by.values())), "by_reason": by, "frames_checked": checked}
