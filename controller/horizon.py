"""What the MPC (OSQP) and the NMPC (CasADi) share about one horizon: small typed records,
and the reference sampled at the stages.

- :class:`InFlight`: commands already issued that will act during the first stages (dead
  times), fixed in the optimisation;
- :class:`Plan`: the last good solution, kept to warm-start the next step and followed,
  shifted in time, when a solve fails;
- :class:`PathReference`, :class:`SpeedBand` and :class:`StageData`: everything one solve
  takes, per stage (the fast path writes it into its QP, the NMPC into its NLP parameters);
- :class:`SolveOutcome`: what one solve returns;
- :func:`path_reference` and :func:`speed_reference`: the reference path at the nominal
  stage positions and the speed reference at the stage times (a stop command or an obstacle
  brings it down).

Shapes: N stages, states (N+1, 4) = [x_m, y_m, psi_rad, v_mps], inputs (N, 3) =
[steering_wheel_angle_rad, accel_pedal, brake_pedal].
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from hmpc.models.plant import HybridPlant, steering_wheel_angle_for
from hmpc.models.reference import Reference


@dataclass(frozen=True)
class InFlight:
    """Inputs in flight at the start of the horizon (see ``controller/mpc/delay.py``).

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
        solution: the QP variable vector z (``controller.mpc.qp.QpLayout`` order), or None.
        solver_status: the solver's own status text.
        solver: "osqp" or "ipopt".
        inaccurate: solved to the looser tolerance only.
        solve_time_s: time in the solver [s] (wall).
        solve_cpu_s: the same in CPU time of the calling thread [s] (a loaded host's
            preemptions excluded).
        update_time_s: time writing the new values into the solver [s].
        iterations: solver iterations.
        capped: the solver stopped at its iteration cap (``MpcConfig.warm_iteration_cap``)
            and its iterate was close enough to use (``MpcConfig.capped_prim_tol``,
            ``capped_dual_tol``).
    """

    solution: np.ndarray | None
    solver_status: str
    solver: str
    inaccurate: bool = False
    solve_time_s: float = 0.0
    update_time_s: float = 0.0
    iterations: int = 0
    capped: bool = False
    solve_cpu_s: float = 0.0

    @property
    def reason(self) -> str:
        return f"{self.solver}: {self.solver_status}"


def path_reference(
    ref: Reference,
    s_k: np.ndarray,
    Xb: np.ndarray,
    Ub: np.ndarray,
    x0: np.ndarray,
    seed_guess: bool,
    plant: HybridPlant,
    sw_max_rad: float,
) -> PathReference:
    """The path at the stage positions ``s_k`` [m], its steering feed-forward on ``plant``'s
    eq. 7 within +-``sw_max_rad``. With ``seed_guess`` (the first iteration of a cold start)
    the nominal states ``Xb`` and steering ``Ub`` are first put on the path, in place (``x0``:
    the initial state, whose heading the path's is unwrapped to)."""
    pl = plant
    xr, yr, th, kap = ref.point_at(s_k)
    dref = np.arcsin(np.minimum(np.maximum(kap * pl.wheelbase_m, -0.95), 0.95))  # clip
    psi_r = th - dref
    if seed_guess:  # the cold guess lies on the path
        Xb[1:, 0], Xb[1:, 1], Xb[1:, 2] = xr[1:], yr[1:], psi_r[1:]
        Xb[1:, 2] += 2 * np.pi * np.round((x0[2] - psi_r[0]) / (2 * np.pi))
    psi_r = psi_r + 2 * np.pi * np.round((Xb[:, 2] - psi_r) / (2 * np.pi))
    sw_max = sw_max_rad
    sw_ff = np.minimum(
        np.maximum(steering_wheel_angle_for(dref, pl.offset_rad, pl.scale), -sw_max), sw_max
    )
    if seed_guess:
        Ub[:, 0] = sw_ff[:-1]
    return PathReference(xr, yr, th, psi_r, dref, sw_ff)


def speed_reference(
    ref: Reference,
    tk: np.ndarray,
    v0: float,
    stop: bool,
    obstacle_m: float | None,
    s_rel: np.ndarray,
    stop_decel_mps2: float,
    obstacle_margin_m: float,
) -> np.ndarray:
    """The speed reference at the stage times ``tk`` [s]: the reference's, brought down at
    ``stop_decel_mps2`` from the speed ``v0`` [m/s] on a ``stop`` command, and to a stop
    ``obstacle_margin_m`` before an obstacle ``obstacle_m`` ahead [m] (``s_rel``: the
    stages' distance along the nominal [m])."""
    v_r = ref.speed_at(tk)
    dec = stop_decel_mps2
    if stop:
        v_r = np.minimum(v_r, np.maximum(v0 - dec * (tk - tk[0]), 0.0))
    if obstacle_m is not None and math.isfinite(obstacle_m):
        room = np.maximum(obstacle_m - obstacle_margin_m - s_rel, 0.0)
        v_r = np.minimum(v_r, np.sqrt(2 * dec * room))
    return v_r
