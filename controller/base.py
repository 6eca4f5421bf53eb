"""The controller contract: what every controller's ``step`` takes and returns.

A controller (MPC, NMPC, PID, and the operator pass-through to come) implements
:class:`Controller`: ``reset()`` before a run, then one ``step(state, reference, t_s)`` per
control period, which RETURNS a :class:`ControlResult` (it never sends the command; the
loop that owns the bus does, docs/style.md 1). A step never raises and never returns None: it
always returns a safe command and a :class:`Status` that says how it was obtained, with a
free-text ``reason`` for people (never parsed).

An unexpected exception inside a controller (a programming error, not a solver failure the
controller knows about) is :attr:`Status.INTERNAL_ERROR`, with the traceback in
``ControlResult.traceback`` and a controlled stop as the command: it is counted apart from
normal fallbacks (``internal_errors`` in the closed-loop metrics) so tests can assert that
none happened.
"""

from __future__ import annotations

import enum
import traceback as _traceback
from dataclasses import dataclass, field
from typing import Protocol, runtime_checkable

import numpy as np

from hmpc.controller.limits import Command
from hmpc.controller.modes import PedalMode


class Status(str, enum.Enum):
    """How a step's command was obtained. The value is the stable text used in run JSON
    (``statuses`` counts by value)."""

    SOLVED = "solved"  # the optimiser converged
    SOLVED_INACCURATE = "solved_inaccurate"  # converged to a looser tolerance (accepted)
    OK = "ok"  # a controller without an optimiser (PID) computed it
    HOLD = "hold"  # standstill hold: brake on, no solve needed
    SHIFTED_PLAN = "shifted_plan"  # this solve failed: the previous plan, shifted
    CONTROLLED_STOP = "controlled_stop"  # no usable plan (or a bad input): brake ramp
    INTERNAL_ERROR = "internal_error"  # an unexpected exception: controlled stop

    def __str__(self) -> str:
        return self.value

    @property
    def ok(self) -> bool:
        """True when this step's own computation succeeded (or needed none)."""
        return self in _OK


_OK = frozenset({Status.SOLVED, Status.SOLVED_INACCURATE, Status.OK, Status.HOLD})


@dataclass
class ControlResult:
    """What a controller step returns: always a safe command and a status.

    Attributes:
        command: the command to apply now (limits applied).
        status: how it was obtained (:class:`Status`).
        reason: why, for people (solver status text, the failure); "" when solved.
        traceback: the formatted traceback of an internal error, else None.
        solve_time_s: time in the solver [s] (0 when it did not run).
        step_time_s: wall time of the whole step [s].
        plan: predicted states (N+1, 4) of the plan followed, or None.
        plan_inputs: planned inputs (N, 3), or None.
        zone_plan: zone index per stage (N,), or None.
        mode_plan: pedal mode per stage (N,), or None.
        zone: the zone the controller believes the car is in.
        pedal_mode: the pedal mode of this command.
        iterations: solver iterations (summed over SQP iterations).
        info: extra figures of the step (free keys, for plots and benchmarks).
    """

    command: Command
    status: Status
    reason: str = ""
    traceback: str | None = None
    solve_time_s: float = 0.0
    step_time_s: float = 0.0
    plan: np.ndarray | None = None
    plan_inputs: np.ndarray | None = None
    zone_plan: np.ndarray | None = None
    mode_plan: np.ndarray | None = None
    zone: int = 0
    pedal_mode: int = int(PedalMode.BRAKE)
    iterations: int = 0
    info: dict = field(default_factory=dict)

    @property
    def ok(self) -> bool:
        """True when this step's optimisation succeeded (or HOLD/OK, which need none)."""
        return self.status.ok


def internal_error(result: ControlResult, exc: BaseException) -> ControlResult:
    """Mark ``result`` (the safe command chosen after ``exc``) as an internal error, with
    the reason and the traceback of ``exc``."""
    result.status = Status.INTERNAL_ERROR
    result.reason = f"{type(exc).__name__}: {exc}"
    result.traceback = "".join(_traceback.format_exception(type(exc), exc, exc.__traceback__))
    return result


@runtime_checkable
class Controller(Protocol):
    """What the closed loop, the drive loop and the benchmarks need from a controller.

    ``step`` keyword arguments: ``stop`` (a stop command: bring the car to standstill) and
    ``obstacle_distance_m`` (distance to an obstacle ahead on the path [m]); a controller
    that cannot use one accepts and ignores it.
    """

    name: str

    def reset(self) -> None:
        """Forget everything from a previous run."""

    def step(
        self,
        state,
        reference,
        t_s: float,
        *,
        stop: bool = False,
        obstacle_distance_m: float | None = None,
    ) -> ControlResult:
        """One control step from the measured ``state`` [x_m, y_m, psi_rad, v_mps] at time
        ``t_s`` [s] on the reference's clock. Never raises, never returns None."""
