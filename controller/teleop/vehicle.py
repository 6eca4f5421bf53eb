"""The vehicle side of tele-operation: the operator's link as the drive loop's command source.

:class:`TeleopController` is a :class:`~hmpc.controller.base.Controller` (``reset`` and
``step``) whose commands come from the authenticated link (``link.LinkReceiver``), so
``controller.actuation.drive.DriveLoop`` runs it exactly like the MPC: the command it returns
goes through the drive loop's limiter, the encoder-side checks and the frame builders, the
same path as every MPC command. The drive loop calls its command-source hook, ``poll``, once
per tick (100 Hz): it drains the link, sends telemetry back to the operator, and tells the
loop whether the operator has engaged and whether a stop is asked for.

What ``step`` returns, by the link's state:

- operator in control, last command ``pedals``: the steering-wheel angle and pedals, through
  ``controller.limits.apply_limits`` with the zone model in force (the same limits the MPC
  applies to its own commands; the drive loop then applies the actuation limits again);
- operator in control, last command ``references`` (speed [m/s], curvature [1/m]): the MPC
  follows an arc of that curvature at that speed, laid from the car's pose when the values
  change (:func:`arc_reference`);
- handed over (``handover_mpc``): the MPC follows the run's reference (``--scenario`` or
  ``--reference``), re-anchored on the car (:func:`anchored_reference`): it joins the
  reference where the reference's speed first reaches the car's, moved and turned so that
  point lies on the car's pose; ``take_over`` gives the operator control again (the rate limits
  continue from the MPC's last command);
- engaged but no driving command yet: steering held, throttle released, the brake at
  ``HOLD_BRAKE`` (a standstill hold; rate-limited like any command).

Stops. The receiver's stop requests (``link_lost``: no valid packet for 200 ms;
``dead_man_released``; ``operator_disengaged``) are handed to the drive loop, which makes its
own controlled stop (jerk-limited braking to standstill, then hold) and reports the reason in
the run JSON's ``stop``. The link's own record of the event, in the loop's clock, is in
``stats()["stop"]``: ``event_t_s`` (link lost: the read time of the last valid packet; a
release: the read time of the releasing packet) and ``detected_t_s``.

Clocks. The receiver runs on the wall clock (``time.time``), which the freshness check needs
(module docstring of ``link``); the drive loop's tick time ``t_s`` is its own. ``poll`` keeps
the offset between the two from the same instant, so link events are reported on the loop's
clock.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from collections.abc import Callable

import numpy as np

from hmpc.controller.base import ControlResult, Status
from hmpc.controller.limits import ActuatorLimits, Command, apply_limits
from hmpc.controller.modes import PedalMode
from hmpc.controller.teleop.link import LinkReceiver, Mode, TeleopCommand, VehicleStatus
from hmpc.models.params import Params
from hmpc.models.plant import HybridPlant
from hmpc.models.reference import Reference

#: brake pedal held when engaged before the operator's first driving command: the report's
#: brake scales (about 4-6 m/s^2 per unit) make 0.3 hold the car at a standstill
HOLD_BRAKE = 0.3
#: gaps between valid packets longer than this are counted in ``stats()["gaps"]`` [s]: two
#: operator periods (50 Hz), i.e. at least one packet missing or late
GAP_S = 0.04
#: length of an arc reference laid for a ``references`` command [s]: longer than the MPC's
#: 10 s horizon, so the horizon never reaches its end before the next command re-lays it
ARC_S = 15.0
_ARC_DT_S = 0.02
#: SQP iterations of the controller's first plan after a handover (its own default: 3). The
#: first plan is a cold start (no previous plan to warm it); three iterations took 35 ms in the
#: 100 Hz loop on the 2-core machine with the simulator node running, and the backlog made the
#: next two control steps late as well: three late steps in a row are the watchdog's
#: ``deadline_misses`` stop. One iteration linearises about the reference; every later step
#: refines the plan anyway (one warm iteration each).
HANDOVER_COLD_START_ITERATIONS = 1
#: before the run the controller is warmed on handovers at speeds this far apart [m/s] (the
#: MPC caches its terminal costs by speed in 0.5 m/s steps), ``WARM_STEPS`` steps each
WARM_SPEED_STEP_MPS = 0.5
WARM_STEPS = 4


@dataclass(frozen=True)
class SourceGate:
    """What the command-source hook tells the drive loop each tick.

    Attributes:
        engage: the operator has engaged (the loop may engage when the car accepts).
        stop: a stop reason ("" for none): the loop starts its controlled stop.
    """

    engage: bool
    stop: str = ""


def handover_config(config):
    """An MPC/NMPC configuration for handovers: ``config`` with
    ``HANDOVER_COLD_START_ITERATIONS`` (a dataclass with ``cold_start_iterations``)."""
    from dataclasses import replace

    return replace(config, cold_start_iterations=HANDOVER_COLD_START_ITERATIONS)


def arc_reference(
    state, speed_mps: float, curvature_1pm: float, t0_s: float, duration_s: float = ARC_S
) -> Reference:
    """An arc of constant curvature [1/m] at constant speed [m/s] from the pose in ``state``
    [x_m, y_m, psi_rad, v_mps], with its clock starting at ``t0_s`` [s]."""
    t = np.arange(0.0, duration_s + _ARC_DT_S / 2, _ARC_DT_S)
    v = max(float(speed_mps), 0.0)
    s = v * t
    th0 = float(state[2])
    k = float(curvature_1pm)
    th = th0 + k * s
    if abs(k) > 1e-9:
        x = state[0] + (np.sin(th) - math.sin(th0)) / k
        y = state[1] - (np.cos(th) - math.cos(th0)) / k
    else:
        x = state[0] + s * math.cos(th0)
        y = state[1] + s * math.sin(th0)
    return Reference(
        t0_s + t,
        x,
        y,
        th,
        np.full(len(t), v),
        name=f"arc v={v:g} k={k:g}",
        curvature_1pm=np.full(len(t), k),
    )


def anchored_reference(ref: Reference, state, t0_s: float) -> Reference:
    """``ref`` from the first sample whose speed reaches the car's (the last sample of the
    fastest part if it never does), moved and turned so that sample lies on the car's pose,
    with its clock starting at ``t0_s`` [s]."""
    v = float(state[3])
    i = (
        int(np.argmax(ref.speed_mps >= v))
        if np.any(ref.speed_mps >= v)
        else int(np.argmax(ref.speed_mps))
    )
    i = min(i, len(ref.time_s) - 2)
    rot = float(state[2]) - float(ref.heading_rad[i])
    c, s = math.cos(rot), math.sin(rot)
    dx, dy = ref.x_m[i:] - ref.x_m[i], ref.y_m[i:] - ref.y_m[i]
    return Reference(
        t0_s + ref.time_s[i:] - ref.time_s[i],
        state[0] + c * dx - s * dy,
        state[1] + s * dx + c * dy,
        ref.heading_rad[i:] + rot,
        ref.speed_mps[i:],
        name=f"{ref.name}@handover",
    )


class TeleopController:
    """The operator's commands as a controller (module docstring).

    Args:
        receiver: the link's receiver (bound; its clock is the wall clock).
        params: the controller's model (zones for the limits, the zone shown to the operator).
        mpc: the controller that drives after a handover and follows ``references`` commands
            (an MPC, NMPC or PID); None: handovers and references bring a controlled stop.
        limits: default ``ActuatorLimits.from_params(params)``.
        control_period_s: the drive loop's control period [s] (the limits' dt).
        telemetry_every: ticks between telemetry packets (10: 10 Hz at the 100 Hz tick).
        run_s: total run time after which ``poll`` asks for a ``duration`` stop (None: none).
        wall_clock: the receiver's clock.
    """

    name = "teleop"

    def __init__(
        self,
        receiver: LinkReceiver,
        params: Params,
        mpc=None,
        *,
        limits: ActuatorLimits | None = None,
        control_period_s: float = 0.02,
        telemetry_every: int = 10,
        run_s: float | None = None,
        wall_clock: Callable[[], float] = time.time,
    ):
        self.rx = receiver
        self.params = params
        self.mpc = mpc
        self.plant = HybridPlant(params)
        self.limits = limits or ActuatorLimits.from_params(params)
        self.dt_s = float(control_period_s)
        self.telemetry_every = max(int(telemetry_every), 1)
        self.run_s = run_s
        self.wall_clock = wall_clock
        self._polls_total = 0
        self.reset()

    # ------------------------------------------------------------------ contract
    def use_model(self, model) -> None:
        """New model values (the online model estimator's ``LearnedModel``) for the
        controller that drives after a handover; the operator's own commands pass unchanged."""
        use = getattr(self.mpc, "use_model", None)
        if use is not None:
            use(model)

    def reset(self) -> None:
        """Forget the commands of a previous run (the link's counters are the receiver's)."""
        self.last: TeleopCommand | None = None
        self.prev: Command | None = None
        self.zone: int | None = None
        self.in_control = "none"  # "operator" | "mpc" | "none"
        self._anchor: Reference | None = None
        self._arc_key: tuple | None = None
        self._arc: Reference | None = None
        self.steps = {"operator": 0, "references": 0, "mpc": 0, "hold": 0}
        self.history: list[str] = []  # who drove each control step (keys of ``steps``)
        self.handovers = 0
        self.take_overs = 0
        self._offset_s = 0.0  # wall clock minus loop clock [s]
        self._last_acc_t: float | None = None
        self._acc_seen = self.rx.accepted
        self.gaps = 0
        self.max_gap_s = 0.0
        self.stop_event: dict | None = None
        self._polls = 0
        if self.mpc is not None:
            self.mpc.reset()

    def step(
        self,
        state,
        reference,
        t_s: float,
        *,
        stop: bool = False,
        obstacle_distance_m: float | None = None,
    ) -> ControlResult:
        """The command of this control period (module docstring); never raises."""
        try:
            return self._step(np.asarray(state, dtype=float), reference, float(t_s), stop)
        except Exception as exc:  # a bug: a controlled stop, recorded as an internal error
            from hmpc.controller.base import internal_error

            sw = self.prev.steering_wheel_angle_rad if self.prev else 0.0
            return internal_error(
                ControlResult(Command(sw, 0.0, HOLD_BRAKE), Status.CONTROLLED_STOP), exc
            )

    def _step(self, x: np.ndarray, reference, t_s: float, stop: bool) -> ControlResult:
        if self._polls_total == 0:  # the drive loop's warm-up call before the run
            if self.mpc is not None:
                return self._warm_up(x, reference, t_s)
            return ControlResult(Command(0.0, 0.0, HOLD_BRAKE), Status.HOLD)
        if self.rx.mpc_in_control:
            return self._mpc_step(x, reference, t_s, stop)
        if self.in_control == "mpc":
            self.take_overs += 1
        self.in_control = "operator"
        self._anchor = None
        cmd = self.last
        if cmd is not None and cmd.mode == Mode.REFERENCES and self.mpc is not None:
            key = cmd.values[:2]
            if key != self._arc_key:
                self._arc_key, self._arc = key, arc_reference(x, *key, t_s)
                self.mpc.reset()
            res = self.mpc.step(x, self._arc, t_s, stop=stop)
            self._count("references")
            return self._remember(res)
        self._arc_key = None
        z = self.plant.select_zone(float(x[3]), self.zone)
        if cmd is not None and cmd.mode == Mode.PEDALS:
            want, status = Command(*cmd.values), Status.OK
            self._count("operator")
        else:  # engaged, no driving command yet (or references without a controller)
            held = self.prev.steering_wheel_angle_rad if self.prev else 0.0
            want, status = Command(held, 0.0, HOLD_BRAKE), Status.HOLD
            self._count("hold")
        u = apply_limits(want, self.prev, self.limits, self.dt_s, self.params.zones[z])
        mode = PedalMode.THROTTLE if u.accel_pedal > 0 else PedalMode.BRAKE
        return self._remember(
            ControlResult(u, status, zone=z, pedal_mode=int(mode), info={"source": "operator"})
        )

    def _warm_up(self, x: np.ndarray, reference, t_s: float) -> ControlResult:
        """Before the run: the controller builds its solver and meets every handover it can
        meet. A handover joins ``reference`` where its speed first reaches the car's, so for
        each speed on a ``WARM_SPEED_STEP_MPS`` grid the join is the same stretch of reference:
        a few steps on each fill the controller's caches (the MPC's terminal-cost Riccati
        solutions, tens of ms each when the loop is loaded) before they are needed in real
        time."""
        res = self.mpc.step(x, reference, t_s)
        v_max = float(np.max(reference.speed_mps)) if isinstance(reference, Reference) else 0.0
        for v in np.arange(0.0, v_max + WARM_SPEED_STEP_MPS / 2, WARM_SPEED_STEP_MPS):
            xv = np.array([0.0, 0.0, 0.0, v])
            ref_v = anchored_reference(reference, xv, t_s)
            self.mpc.reset()
            for k in range(WARM_STEPS):
                self.mpc.step(xv, ref_v, t_s + k * self.dt_s)
        self.mpc.reset()
        return res

    def _mpc_step(self, x: np.ndarray, reference, t_s: float, stop: bool) -> ControlResult:
        if self.mpc is None:
            sw = self.prev.steering_wheel_angle_rad if self.prev else 0.0
            return ControlResult(
                Command(sw, 0.0, HOLD_BRAKE),
                Status.CONTROLLED_STOP,
                reason="handed over, but no controller to hand over to",
            )
        if self.in_control != "mpc" or self._anchor is None:
            self.handovers += 1
            self.in_control = "mpc"
            self._anchor = anchored_reference(reference, x, t_s)
            self.mpc.reset()
        self._count("mpc")
        return self._remember(self.mpc.step(x, self._anchor, t_s, stop=stop))

    def _count(self, who: str) -> None:
        self.steps[who] += 1
        self.history.append(who)

    def _remember(self, res: ControlResult) -> ControlResult:
        if res.ok:
            self.prev = res.command
            self.zone = int(res.zone)
        return res

    # --------------------------------------------------------- the drive loop's hook
    def poll(
        self,
        t_s: float,
        *,
        loop_state: str = "",
        speed_mps: float = math.nan,
        steering_wheel_angle_rad: float = math.nan,
    ) -> SourceGate:
        """Drain the link once (the drive loop calls this every tick, at loop time ``t_s``
        [s]), send telemetry every ``telemetry_every`` calls, and say whether the operator has
        engaged and whether a stop is asked for."""
        now = self.wall_clock()
        self._offset_s = now - t_s
        res = self.rx.poll(now)
        self._polls += 1
        self._polls_total += 1
        for cmd in res.commands:
            if cmd.mode in (Mode.PEDALS, Mode.REFERENCES):
                self.last = cmd
            elif cmd.mode == Mode.ENGAGE:
                self.last = None
        self._count_gaps(now)
        why = ""
        if res.stop is not None:
            why = res.stop.reason
            self.stop_event = {
                "reason": why,
                "event_t_s": round(res.stop.t_s - self._offset_s, 4),
                "detected_t_s": round(res.stop.detected_t_s - self._offset_s, 4),
            }
        if not why and self.run_s is not None and t_s >= self.run_s:
            why = "duration"
        if self._polls % self.telemetry_every == 1 or self.telemetry_every == 1:
            self.rx.send_telemetry(
                self._status(loop_state, speed_mps, steering_wheel_angle_rad), now
            )
        return SourceGate(engage=self.rx.engaged, stop=why)

    def loop_time(self, wall_s: float) -> float:
        """A wall-clock time [s since the epoch] on the drive loop's clock [s] (last poll's
        offset)."""
        return float(wall_s) - self._offset_s

    def _count_gaps(self, now: float) -> None:
        if self.rx.accepted != self._acc_seen:
            if self._last_acc_t is not None:
                gap = now - self._last_acc_t
                self.max_gap_s = max(self.max_gap_s, gap)
                self.gaps += int(gap > GAP_S + 0.01)  # + one tick: the poll's own resolution
            self._last_acc_t = now
            self._acc_seen = self.rx.accepted

    def _status(self, loop_state: str, v: float, sw: float) -> VehicleStatus:
        z = self.plant.zone_by_speed(v) if math.isfinite(v) else -1
        p = self.prev
        if loop_state in ("stopping", "holding"):
            pedal = loop_state
        elif p is None or loop_state != "engaged":
            pedal = ""
        elif p.brake_pedal > 0:
            pedal = "hold" if math.isfinite(v) and v < 0.05 else "brake"
        else:
            pedal = "throttle" if p.accel_pedal > 0 else "coast"
        return VehicleStatus(v, sw, z, self.params.zones[z].name if z >= 0 else "", pedal)

    # ----------------------------------------------------------------- reporting
    def stats(self) -> dict:
        """The run JSON's ``link`` object: the receiver's statistics, the gaps between valid
        packets, who drove how many control steps, and the link's stop event (loop clock)."""
        s = self.rx.stats()
        s["gaps"] = {
            "over_ms": round((GAP_S + 0.01) * 1e3, 1),
            "count": self.gaps,
            "max_ms": round(self.max_gap_s * 1e3, 3),
            "lost_packets": s["lost"],
        }
        s["steps"] = dict(self.steps)
        s["handovers"] = self.handovers
        s["take_overs"] = self.take_overs
        s["stop"] = self.stop_event
        return s
