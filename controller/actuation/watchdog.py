"""The drive loop's watchdog: each check returns the reason for a controlled stop, or "".

Reasons (stable strings, in the run JSON's ``stop.reason``): ``feedback_loss``,
``clock_freeze``, ``clock_jump``, ``deadline_misses``, ``solver_failure``, ``bus_error``,
``driver_override``, ``vehicle_rejects``, ``duration`` (the run ended; not a fault),
``interrupted`` (Ctrl-C). A run that never engaged ends with ``no_feedback`` (no wheel speeds
on the bus within 5 s) or ``car_not_accepting`` (the car's status never allowed commands).
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class WatchdogConfig:
    """Thresholds, each with its reason."""

    # The rule: no wheel speeds for 3 of their periods is stale feedback.
    stale_periods: float = 3.0
    # A tick whose loop clock advanced by less than this fraction of the monotonic time
    # that passed (at least ``clock_min_elapsed_s``) has a frozen clock.
    clock_freeze_fraction: float = 0.1
    clock_min_elapsed_s: float = 0.005
    # The loop clock running ahead of the monotonic clock by more than this in one tick
    # (or going backwards) is a jump: 100 ms, ten 100 Hz ticks, far beyond scheduling jitter.
    clock_jump_s: float = 0.1
    # Consecutive late control steps that stop the car: one late step is counted and
    # reported; three in a row (60 ms at 50 Hz) mean the loop cannot keep its rate.
    deadline_misses_to_stop: int = 3


class Watchdog:
    """Stateful checks, called by the drive loop every tick."""

    def __init__(self, config: WatchdogConfig = WatchdogConfig()):
        self.config = config
        self.consecutive_misses = 0
        self._prev: tuple[float, float] | None = None  # (loop clock, monotonic), previous tick

    def clock(self, loop_t_s: float, mono_s: float) -> str:
        c = self.config
        reason = ""
        if self._prev is not None:
            d_loop = loop_t_s - self._prev[0]
            d_mono = mono_s - self._prev[1]
            if d_loop < 0 or d_loop > d_mono + c.clock_jump_s:
                reason = "clock_jump"
            elif d_mono >= c.clock_min_elapsed_s and d_loop < c.clock_freeze_fraction * d_mono:
                reason = "clock_freeze"
        self._prev = (loop_t_s, mono_s)
        return reason

    def feedback(self, now_s: float, last_wheel_speed_s: float | None, period_s: float) -> str:
        if last_wheel_speed_s is None:
            return "feedback_loss"
        stale = now_s - last_wheel_speed_s > self.config.stale_periods * period_s
        return "feedback_loss" if stale else ""

    def deadline(self, late: bool) -> str:
        self.consecutive_misses = self.consecutive_misses + 1 if late else 0
        return (
            "deadline_misses"
            if self.consecutive_misses >= self.config.deadline_misses_to_stop
            else ""
        )
