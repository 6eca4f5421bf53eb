"""The discrete part of the hybrid controller: pedal modes, standstill hold, zone gating.

Why a pedal mode. Eq. 8 with a brake term makes the coast acceleration of a zone (both
pedals released) its ``offset_mps2``: above it only the throttle can reach, below it only
the brake. In the idle zone the offset is positive (idle creep, report section II-D and
V): holding any speed below the idle speed needs the brake, and a controller that may use
both pedals in one optimisation flips between them on every small speed error. Here each
QP stage has ONE free pedal, chosen before the solve by :class:`PedalModeLogic`:

- the desired acceleration ``a_des`` (reference acceleration + speed error / tau) is
  compared with the zone's coast acceleration, with a hysteresis band of
  ``accel_hysteresis_mps2`` on each side, and
- a mode, once entered, is kept at least ``min_dwell_s`` unless the demand is far beyond
  the band (``urgent_mps2``: braking hard is never delayed by the dwell).

Inside the band the free pedal can still reach the coast acceleration (pedal 0), so
small errors are corrected by the same pedal. This is mode logic inside the MPC's design,
not a filter on its output. :class:`StandstillLogic` adds the third mode, HOLD: stopped
with a stop requested, the brake holds the car against idle creep.

:func:`transition_allowed` is the report's section VI rule: a change of speed zone is
allowed only when the horizon shows no acceleration change coming around the crossing.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass

import numpy as np


#: a pedal planned below this fraction counts as released (0.5 % of travel, about the
#: resolution of a pedal position sensor)
PEDAL_RELEASED = 0.005


class PedalMode(enum.IntEnum):
    """Which pedal is free in a QP stage."""

    THROTTLE = 0  #: accelerator free in [0, 1], brake fixed at 0
    BRAKE = 1  #: brake free in [0, 1], accelerator fixed at 0
    HOLD = 2  #: standstill: brake held, accelerator 0 (no QP stage uses it)


@dataclass(frozen=True)
class ModeConfig:
    """Tuning of the mode logic (units in the names, reasons in comments)."""

    # Half-width of the hysteresis band about the zone's coast acceleration: 0.15 m/s^2 is
    # 3x the a_des noise that 0.05 m/s of wheel-speed noise causes through the 1 s error
    # time constant below, and the speed error it allows (0.15 m/s at most, transiently)
    # stays within the 0.2 m/s idle target.
    accel_hysteresis_mps2: float = 0.15
    # Time constant of the speed-error feedback in a_des: 1 s, faster than the reference
    # ramps (>= 2 s), slow enough that measurement noise does not decide the pedal.
    error_time_constant_s: float = 1.0
    # Minimum time in a pedal mode: 1 s keeps switches well under the 6/min target even
    # with noise, while a ramp reversal still gets its pedal within a second.
    min_dwell_s: float = 1.0
    # A demand this far below coast brakes at once, dwell or not (safety first).
    urgent_mps2: float = 0.8
    # The current pedal counts as exhausted when the plan releases it over this long [s].
    exhausted_lookahead_s: float = 0.4
    # Standstill: below this speed and with the reference at (near) zero, HOLD.
    standstill_speed_mps: float = 0.1
    # Leave HOLD when the reference asks for more than this speed (within the lookahead).
    go_speed_mps: float = 0.15
    # How far ahead the reference is checked before HOLD is entered [s].
    hold_lookahead_s: float = 1.0
    # Brake held at standstill = margin x the brake that cancels the idle creep, at least
    # hold_brake_min: 2x covers a 50 % weaker brake than identified.
    hold_brake_margin: float = 2.0
    hold_brake_min: float = 0.2

    def __post_init__(self):
        for name in (
            "accel_hysteresis_mps2",
            "error_time_constant_s",
            "urgent_mps2",
            "standstill_speed_mps",
            "go_speed_mps",
            "hold_lookahead_s",
            "hold_brake_margin",
        ):
            if not getattr(self, name) > 0:
                raise ValueError(f"ModeConfig.{name} must be positive")
        if self.min_dwell_s < 0:
            raise ValueError("ModeConfig.min_dwell_s must be >= 0")
        if not 0 <= self.hold_brake_min <= 1:
            raise ValueError("ModeConfig.hold_brake_min must be in [0, 1]")


def desired_accel(
    v_ref_mps: np.ndarray, v_mps: np.ndarray, dt_s: float, tau_s: float
) -> np.ndarray:
    """a_des[k] = (v_ref[k+1] - v_ref[k]) / dt + (v_ref[k] - v[k]) / tau  [m/s^2].

    Args:
        v_ref_mps: reference speed at stages 0..N [m/s].
        v_mps: nominal (predicted) speed at stages 0..N-1 or 0..N [m/s].
        dt_s: stage length [s].
        tau_s: time constant of the speed-error correction [s].
    """
    vr = np.asarray(v_ref_mps, dtype=float)
    n = len(vr) - 1
    return (vr[1:] - vr[:-1]) / dt_s + (vr[:n] - np.asarray(v_mps, dtype=float)[:n]) / tau_s


def next_mode(mode: PedalMode, a_des_mps2: float, coast_mps2: float, h_mps2: float) -> PedalMode:
    """One hysteresis decision (no dwell)."""
    if mode == PedalMode.BRAKE and a_des_mps2 > coast_mps2 + h_mps2:
        return PedalMode.THROTTLE
    if mode != PedalMode.BRAKE and a_des_mps2 < coast_mps2 - h_mps2:
        return PedalMode.BRAKE
    return PedalMode.THROTTLE if mode == PedalMode.HOLD else mode


class PedalModeLogic:
    """Pedal mode of the first stage (with dwell) and the schedule along the horizon."""

    def __init__(self, config: ModeConfig):
        self.config = config
        self.mode: PedalMode | None = None
        self._t_switch_s = -np.inf

    def reset(self) -> None:
        self.mode = None
        self._t_switch_s = -np.inf

    def first(
        self, a_des_mps2: float, coast_mps2: float, t_s: float, exhausted: bool = True
    ) -> PedalMode:
        """Mode of stage 0 at time ``t_s``; remembers it.

        ``exhausted``: the current pedal is released in the plan's first stages, i.e. it
        has nothing left to give in the direction the demand asks; only then may the mode
        change (unless urgent). A throttle is never pressed while releasing the brake
        would still do.
        """
        c = self.config
        if self.mode is None or self.mode == PedalMode.HOLD:
            new = PedalMode.THROTTLE if a_des_mps2 > coast_mps2 else PedalMode.BRAKE
            if self.mode == PedalMode.HOLD:
                new = (
                    PedalMode.BRAKE
                    if a_des_mps2 <= coast_mps2 + c.accel_hysteresis_mps2
                    else PedalMode.THROTTLE
                )
        else:
            new = next_mode(self.mode, a_des_mps2, coast_mps2, c.accel_hysteresis_mps2)
            dwell_ok = t_s - self._t_switch_s >= c.min_dwell_s - 1e-9
            urgent = new == PedalMode.BRAKE and a_des_mps2 < coast_mps2 - c.urgent_mps2
            if new != self.mode and not ((dwell_ok and exhausted) or urgent):
                new = self.mode
        if new != self.mode:
            self._t_switch_s = t_s
        self.mode = new
        return new

    def hold(self, t_s: float) -> None:
        """Enter HOLD (standstill)."""
        if self.mode != PedalMode.HOLD:
            self._t_switch_s = t_s
        self.mode = PedalMode.HOLD

    def schedule(
        self,
        first: PedalMode,
        a_des_mps2: np.ndarray,
        coast_mps2: np.ndarray,
        dt_s: float,
        since_switch_s: float | None = None,
        pedals: np.ndarray | None = None,
    ) -> np.ndarray:
        """Modes of stages 0..N-1: ``first``, then hysteresis with dwell along the horizon.

        ``pedals`` (N, 2): the nominal plan's [accel, brake] pedal per stage; a stage may
        leave a mode only where the nominal has released that mode's pedal.

        :func:`next_mode` and the dwell rule, stage by stage (each decision depends on the
        last). Run every MPC step, so the loop works on plain floats and ints: the band
        edges are computed for all stages at once, the same sums as :func:`next_mode`'s.
        """
        c = self.config
        n = len(a_des_mps2)
        coast = np.asarray(coast_mps2, dtype=float)
        a_arr = np.asarray(a_des_mps2, dtype=float)
        up_arr = coast + c.accel_hysteresis_mps2  # brake -> throttle above
        down_arr = coast - c.accel_hysteresis_mps2  # else -> brake below
        mode = int(first)
        # the common case, no stage asks to leave the first mode: it holds throughout
        if mode == PedalMode.BRAKE and not (a_arr[1:] > up_arr[1:]).any():
            return np.full(n, mode, dtype=np.int8)
        if mode == PedalMode.THROTTLE and not (a_arr[1:] < down_arr[1:]).any():
            return np.full(n, mode, dtype=np.int8)
        a, up, down = a_arr.tolist(), up_arr.tolist(), down_arr.tolist()
        urgent = (coast - c.urgent_mps2).tolist()
        released = None if pedals is None else (np.asarray(pedals) <= PEDAL_RELEASED).tolist()
        thr, brk, hold = int(PedalMode.THROTTLE), int(PedalMode.BRAKE), int(PedalMode.HOLD)
        dwell = c.min_dwell_s
        out = [mode] * n
        age = 0.0 if since_switch_s is None else since_switch_s
        for k in range(1, n):
            age += dt_s
            ak = a[k]
            if mode == brk:
                new = thr if ak > up[k] else brk
            elif ak < down[k]:
                new = brk
            else:
                new = thr if mode == hold else mode
            if new != mode:
                free = released is None or released[k][0 if mode == thr else 1]
                if (age >= dwell and free) or (new == brk and ak < urgent[k]):
                    mode, age = new, 0.0
            out[k] = mode
        return np.array(out, dtype=np.int8)

    def since_switch_s(self, t_s: float) -> float:
        return float(t_s - self._t_switch_s)


class StandstillLogic:
    """HOLD mode: stopped and asked to stay stopped -> brake held, no QP pedal needed."""

    def __init__(self, config: ModeConfig):
        self.config = config
        self.holding = False

    def reset(self) -> None:
        self.holding = False

    def update(self, v_mps: float, v_ref_ahead_max_mps: float, stop_requested: bool) -> bool:
        """Return True while the car must be held at standstill.

        Args:
            v_mps: measured speed [m/s].
            v_ref_ahead_max_mps: largest reference speed within the hold lookahead [m/s].
            stop_requested: a stop command or an obstacle at the car.
        """
        c = self.config
        want_stop = stop_requested or v_ref_ahead_max_mps <= c.standstill_speed_mps
        if self.holding:
            if not stop_requested and v_ref_ahead_max_mps > c.go_speed_mps:
                self.holding = False
        elif want_stop and v_mps <= c.standstill_speed_mps:
            self.holding = True
        return self.holding

    def hold_brake(self, idle_offset_mps2: float, idle_brake_scale_mps2: float) -> float:
        """Brake pedal that holds the car against creep, with margin (0..1)."""
        c = self.config
        need = max(idle_offset_mps2, 0.0) / max(idle_brake_scale_mps2, 1e-6)
        return float(min(1.0, max(c.hold_brake_min, c.hold_brake_margin * need)))


def transition_allowed(a_plan_mps2: np.ndarray, k_cross: int, window: int, tol_mps2: float) -> bool:
    """Report section VI: a zone transition at stage ``k_cross`` is allowed only if the
    planned acceleration around it (``window`` stages before and after) changes by at most
    ``tol_mps2`` and does not change sign (no acceleration change is coming).
    """
    n = len(a_plan_mps2)
    if n == 0:
        return True
    # a crossing near either end of the horizon is judged on a full-length window shifted
    # inside it: "now" is never a reason to look at less of the horizon
    span = min(2 * window + 1, n)
    lo = min(max(0, k_cross - window), n - span)
    hi = lo + span
    seg = np.asarray(a_plan_mps2[lo:hi], dtype=float)
    if seg.size == 0:
        return True
    if float(seg.max() - seg.min()) > tol_mps2:
        return False
    # a steady acceleration of one sign (or steady cruise): a sign change means a reversal
    return not (seg.max() > tol_mps2 / 2 and seg.min() < -tol_mps2 / 2)
