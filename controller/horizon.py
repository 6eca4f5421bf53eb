"""What the MPC (OSQP) and the NMPC (CasADi) share about one horizon: small typed records.

- :class:`InFlight`: commands already issued that will act during the first stages (dead
  times), fixed in the optimisation;
- :class:`Plan`: the last good solution, kept to warm-start the next step and followed,
  shifted in time, when a solve fails;
- :class:`PathReference`, :class:`SpeedBand` and :class:`StageData`: everything one solve
  takes, per stage (the fast path writes it into its QP, the NMPC into its NLP parameters);
- :class:`SolveOutcome`: what one solve returns.

Shapes: N stages, states (N+1, 4) = [x_m, y_m, psi_rad, v_mps], inputs (N, 3) =
[steering_wheel_angle_rad, accel_pedal, brake_pedal].
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass(frozen=True)
class InFlight:
    """Inputs in flight at the start of the horizon (see ``MpcController._predict_through_delay``).

    Attributes:
        steer_stages: number of first stages whose steering is already issued.
        steer_rad: those steering-wheel angles [rad], (steer_stages,).
        pedal_stages: number of first stages whose pedals are already issued.
        pedals: those (accel, brake) pedals [1], (pedal_stages, 2).
    """

    steer_stages: int = 0
    steer_rad: np.ndarray = field(default_factory=lambda: np.zeros(0))
    pedal_stages: int = 0
    pedals: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))


@dataclass(frozen=True)
class Plan:
    """The last good solution.

    Attributes:
        t0_s: time of its first stage [s].
        states: (N+1, 4) predicted states.
        inputs: (N, 3) planned inputs.
        zones: (N,) zone per stage.
        modes: (N,) pedal mode per stage.
    """

    t0_s: float
    states: np.ndarray
    inputs: np.ndarray
    zones: np.ndarray
    modes: np.ndarray


@dataclass(frozen=True)
class PathReference:
    """The reference path at the nominal stage positions (stages 0..N).

    Attributes:
        x_m, y_m: reference points [m].
        heading_rad: path tangent direction [rad].
        psi_rad: the vehicle heading that follows the path (tangent minus the steady-state
            road-wheel angle, unwrapped to the nominal heading) [rad].
        road_wheel_angle_rad: steady-state road-wheel angle of the path curvature [rad].
        steering_ff_rad: its steering-wheel angle (eq. 7 inverted, within limits) [rad].
    """

    x_m: np.ndarray
    y_m: np.ndarray
    heading_rad: np.ndarray
    psi_rad: np.ndarray
    road_wheel_angle_rad: np.ndarray
    steering_ff_rad: np.ndarray


@dataclass(frozen=True)
class SpeedBand:
    """Soft lower/upper speed targets of stages 1..N [m/s] and their slack weights (linear
    penalty per m/s of violation)."""

    v_lo_mps: np.ndarray
    w_lo: np.ndarray
    v_hi_mps: np.ndarray
    w_hi: np.ndarray


@dataclass(frozen=True)
class StageData:
    """Everything one solve takes.

    Attributes:
        x0: initial state (after delay compensation).
        states: nominal states (N+1, 4): the linearisation point / initial guess.
        inputs: nominal inputs (N, 3).
        zones: zone per stage (N,).
        modes: pedal mode per stage (N,).
        path: the path reference at the nominal positions.
        v_ref_mps: speed reference, stages 0..N [m/s].
        band: the speed band.
        a_prev_mps2: the acceleration of the stage before the first [m/s^2] (jerk limit).
    """

    x0: np.ndarray
    states: np.ndarray
    inputs: np.ndarray
    zones: np.ndarray
    modes: np.ndarray
    path: PathReference
    v_ref_mps: np.ndarray
    band: SpeedBand
    a_prev_mps2: float


@dataclass
class SolveOutcome:
    """What one solve returns: the solution vector (None when it failed) and its figures.

    Attributes:
        solution: the QP variable vector z (``_QpLayout`` order), or None.
        solver_status: the solver's own status text.
        solver: "osqp" or "ipopt".
        inaccurate: solved to the looser tolerance only.
        solve_time_s: time in the solver [s].
        update_time_s: time writing the new values into the solver [s].
        iterations: solver iterations.
    """

    solution: np.ndarray | None
    solver_status: str
    solver: str
    inaccurate: bool = False
    solve_time_s: float = 0.0
    update_time_s: float = 0.0
    iterations: int = 0

    @property
    def reason(self) -> str:
        return f"{self.solver}: {self.solver_status}"
