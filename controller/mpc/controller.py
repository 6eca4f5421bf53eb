"""Hybrid-mode MPC, fast path: an OSQP linear time-varying QP (issue 4, report section VI).

Prediction model: the hybrid plant (models/plant.py): kinematic bicycle (eq. 1), steering
map (eq. 7), one linear accelerator model per speed zone (eq. 8, with brake). Every step:

1. **Delay compensation.** The state is predicted forward through the commands still in
   flight (``steering.dead_time_s``, ``longitudinal.dead_time_s``): the QP starts where
   the car will be when this step's command takes effect.
2. **Schedules.** Along the horizon, the zone of each stage follows the speed profile of
   the previous solution (with the plant's hysteresis), and each stage gets ONE free
   pedal (controller/modes.py): within one QP throttle and brake are never both free.
3. **Re-linearisation** of eq. 1 about the previous solution (shifted in time),
   discretised (2nd order), the zone's eq. 8 per stage. The QP's sparsity pattern is
   built ONCE; each step writes new values in place (OSQP ``update(Px=, Ax=, q=, l=, u=)``)
   and warm-starts from the previous solution (primal and dual, shifted in time).
4. **Costs** (J = 1/2 z'Pz + q'z):
   - lateral and heading error to the reference path, speed error to the speed profile;
   - effort: pedal changes cost more than steering changes (report VI: "velocity control
     should have a higher cost"; checked in :class:`MpcConfig`);
   - smoothness (issue 9), terms of their own beside tracking: the change of the input
     rates (second differences, against the rate the last plan had), the unplanned part of
     the rate (distance of the first second's inputs from the last plan, shifted to now)
     and the steering-wheel rate per metre driven (path sharpness, weight 1/v^2). Tuned so
     that the EKF's estimate noise at the default sensor noise (about 1 cm, 1 mrad,
     0.02 m/s) does not move the wheel by a degree (tests/test_smooth_control.py);
   - terminal cost from python-control's ``dlqr`` on the path-error linearisation;
   - soft limits (slack variables, exact L1 penalties): jerk, speed >= 0;
   - the report's two ways to stay in the most accurate zone (VI): a **minimum-speed
     floor** (default: the preferred zone's lower bound) that applies while the reference
     is at or above it and that a stop command or an obstacle overrides, and a
     **zone-transition penalty**: the speed is kept inside the current zone's hysteresis
     band unless the reference leaves the band AND the horizon shows no acceleration
     change around the crossing (modes.transition_allowed). Entering the preferred
     zone (the one with the lowest ``nmse_pct`` in the parameter file; default the
     zone holding 2-5 m/s) is always allowed.
5. **Constraints**: steering angle and rate; pedals in [0, 1], one free per stage;
   acceleration limits: within a stage the acceleration is affine in the free pedal, so
   they are bounds on it (the caps ``apply_limits`` puts on the command).
6. **Idle speed**: the pedal mode logic (hysteresis about the zone's coast acceleration,
   minimum dwell) and the standstill HOLD mode keep the brake in charge below the idle
   speed, so holding 1 m/s against idle creep does not chatter.
7. **Failures**: a step never raises and never returns None. On a solver failure or
   time-out the previous plan is shifted and followed; when it has run out, a controlled
   stop (brake ramp, steering held). An unexpected exception (a bug, not a solver failure)
   is an internal error: the plan is dropped, a controlled stop begins and the result
   carries the traceback. The status (controller/base.py ``Status``) says which, and
   ``reason`` why.

The step RETURNS a command; it never sends it. Every command goes through
``controller.limits.apply_limits`` before it is returned. The model's physics (eq. 1, 7, 8,
the zone rule) is models/plant.py's; this module only discretises it.
"""
from __future__ import annotations

import bisect
import math
import time
from collections import deque
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from hmpc.models.params import Params
from hmpc.models.plant import HybridPlant, bicycle_jacobian, derivative_batch, jacobians_batch, \
    steering_wheel_angle_for
from hmpc.models.plant import first_order_lag
from hmpc.models.reference import Reference

from hmpc.controller.base import ControlResult, Status, internal_error
from hmpc.controller.horizon import InFlight, PathReference, Plan, SolveOutcome, SpeedBand, \
    StageData
from hmpc.controller.limits import ActuatorLimits, Command, apply_limits
from hmpc.controller.modes import PEDAL_RELEASED, ModeConfig, PedalMode, PedalModeLogic, StandstillLogic, \
    desired_accel, transition_allowed

__all__ = ["ControlResult", "MpcConfig", "MpcController", "Status", "derivative_batch",
           "jacobians_batch", "preferred_zone"]

NX, NU, NS = 4, 3, 3  # state, input, slack (per stage)
_UT4 = [(a, b) for a in range(4) for b in range(a, 4)]   # upper triangle of a 4x4 block
_APAT = [(0, 0), (1, 1), (2, 2), (3, 3), (0, 2), (0, 3), (1, 2), (1, 3), (2, 3)]  # A_d pattern
_BPAT = [(i, j) for i in range(4) for j in range(3)]
_APAT_FLAT = np.array([NX * i + j for i, j in _APAT])  # _APAT in a flattened 4x4 block
_BPAT_FLAT = np.array([NU * i + j for i, j in _BPAT])  # _BPAT in a flattened 4x3 block
_STRICT_UPPER4 = np.triu(np.ones((4, 4)), 1)
_THROTTLE, _BRAKE = int(PedalMode.THROTTLE), int(PedalMode.BRAKE)
_STRICT_LOWER4 = np.tril(np.ones((4, 4)), -1)
_UT4_ROWS = np.array([a for a, _ in _UT4])
_UT4_COLS = np.array([b for _, b in _UT4])


@dataclass(frozen=True)
class MpcConfig:
    """MPC tuning. Weights are per second of horizon (tracking) or per change (effort), so
    the balance does not move when ``dt_s`` changes."""

    horizon_s: float = 10.0        # issue 4: 10-15 s
    dt_s: float = 0.2              # QP stage length: 0.1 or 0.2 s
    # tracking
    w_lateral: float = 4.0         # per m^2 of lateral error, per s
    w_heading: float = 4.0         # per rad^2 of heading error, per s
    w_speed: float = 10.0          # per (m/s)^2 of speed error, per s
    # effort on the change of an input per stage, normalised to its range (steering-wheel
    # angle / its max, pedals as fractions). Report VI: velocity effort above steering.
    w_speed_effort: float = 4.0
    w_steer_effort: float = 1.0
    # smoothness (issue 9), separate from tracking: the effort weights above are the RATE
    # terms (a change per stage is the rate times dt: w * (du/range/dt)^2 * dt per stage);
    # these weight the change of that rate, per (normalised rate change per s)^2 per s
    # (second differences: w * (d2u/range/dt^2)^2 * dt per stage). A reversal of the
    # command is a large second difference, a steady ramp (a curve coming) none, so they
    # damp the chatter that estimate noise causes without holding back a planned turn.
    # Velocity above steering here too (report VI). Tuned at the default sensor noise
    # (estimate noise about 1 cm, 1 mrad, 0.02 m/s) on report_2008; checked on a parameter
    # set not used for tuning (tests/test_smooth_control.py holds the figures).
    w_steer_rate_change: float = 0.3
    w_pedal_rate_change: float = 1.0
    # the standstill HOLD brake is reached at this rate [full travel / s] from the brake the
    # plan already had on (the car is already stopping; a step jolts it and the pedal)
    hold_brake_rate_ps: float = 0.25
    # path sharpness: the steering-wheel rate per metre driven, (d sw / ds)^2 = (d sw/dt)^2
    # / v^2, normalised like the effort, per s. Noise in the estimate (1 cm, 1 mrad) asks
    # for a steering correction that grows as 1 / v^2 (a lateral offset y is undone over a
    # time T with a road-wheel angle of about 2 b y / (v T)^2): without this the wheel
    # chases 1 cm of estimate noise by several degrees at 1 m/s. At speed it fades (8 m/s:
    # 1/64 of its 1 m/s weight). Below the floor speed the weight stops growing [m/s].
    w_steer_sharpness: float = 100.0
    steer_sharpness_speed_floor_mps: float = 0.5
    # the UNPLANNED part of the rate: each step the inputs of the first ``replan_window_s``
    # cost their squared distance from the previous plan (shifted to now), normalised like
    # the effort, per s. A turn the reference announced is in that plan and passes freely;
    # what a new estimate adds (noise, 1 cm / 1 mrad) is low-pass filtered step to step.
    # Pedals above steering (report VI).
    w_steer_replan: float = 3000.0
    w_pedal_replan: float = 6000.0
    replan_window_s: float = 1.0
    w_pedal_level: float = 0.02    # per pedal^2 per s: prefer the lighter pedal
    w_steer_level: float = 0.02    # per (sw - feedforward)^2 / max^2 per s
    # terminal LQR input weights (per rad^2 of steering wheel, per (m/s^2)^2)
    r_terminal_steer: float = 0.05
    r_terminal_accel: float = 2.0
    # soft constraints: linear (exact) penalty per unit of violation per s
    w_limit_violation: float = 100.0   # accel [m/s^2], jerk [m/s^2 per stage]
    w_standstill: float = 500.0        # speed below 0 [m/s]
    w_floor: float = 10.0              # speed below the minimum-speed floor [m/s]
    w_transition: float = 10.0         # speed outside the current zone's band [m/s]; 0 = off
    w_slack_quadratic: float = 1.0
    w_speed_max: float = 100.0
    # zone-transition rule (report VI)
    transition_accel_tol_mps2: float = 0.2   # "no acceleration change": spread <= tol
    transition_window_s: float = 1.0         # checked this long either side of the crossing
    transition_dwell_s: float = 2.0          # the reference must stay in the new zone this long
    # the band kept is the zone's hysteresis band narrowed by this margin [m/s], so that
    # tracking error and the controller's 10 Hz view of the speed do not let the plant cross
    transition_band_margin_mps: float = 0.15
    # minimum-speed floor [m/s]; None: the preferred zone's lower bound; 0 disables
    min_speed_mps: float | None = None
    # stop command / obstacle: reference speed brought down at this deceleration [m/s^2]
    stop_decel_mps2: float = 1.5
    obstacle_margin_m: float = 3.0
    # controlled stop after the plan ran out: brake decel target and ramp (jerk) [m/s^2, m/s^3]
    stop_brake_decel_mps2: float = 2.0
    # OSQP
    max_iter: int = 4000
    eps_abs: float = 1e-3          # 1 mm, 1 mm/s: far below what the plant can act on
    eps_rel: float = 1e-3
    # OSQP: test convergence every this many iterations. Warm-started (shifted primal and
    # dual) the QP converges in 10-20 iterations; checking every 25 doubled the solve time
    check_termination: int = 5
    # OSQP rho adaptation every this many iterations (0: OSQP's timing-based choice, which
    # adapted too late for a 15-iteration solve) and the factor that triggers it
    adaptive_rho_interval: int = 5
    adaptive_rho_tolerance: float = 3.0
    # OSQP relaxation (its default 1.6): from a shifted warm start strong over-relaxation
    # overshoots; 1.2 cut the median iteration count 15 -> 10 in tools/bench_mpc.py. (1.0
    # stopped as early but with a visibly less converged steering plan: the MPC/NMPC
    # agreement test's steering difference rose 0.12 -> 0.22 rad; with 1.2 it is 0.10.)
    admm_alpha: float = 1.2
    time_limit_s: float = 0.0      # 0: none (OSQP time_limit)
    cold_start_iterations: int = 3  # SQP iterations when no previous plan exists
    accept_inaccurate: bool = True  # OSQP "solved inaccurate" is used (status says so)
    warm_start_shifted: bool = True  # warm-start x with the shifted plan (else OSQP's last x, y)

    def __post_init__(self):
        n = self.horizon_s / self.dt_s
        if not (self.dt_s > 0 and self.horizon_s > 0 and abs(n - round(n)) < 1e-6 and round(n) >= 2):
            raise ValueError("MpcConfig: horizon_s must be a whole number (>= 2) of dt_s steps")
        if not self.w_speed_effort > self.w_steer_effort:
            raise ValueError("MpcConfig: the report (section VI) weights velocity effort above "
                             "steering effort: need w_speed_effort > w_steer_effort")
        for name in ("w_lateral", "w_heading", "w_speed", "w_steer_effort", "w_slack_quadratic",
                     "r_terminal_steer", "r_terminal_accel", "w_limit_violation", "w_standstill"):
            if not getattr(self, name) > 0:
                raise ValueError(f"MpcConfig.{name} must be positive")
        if self.w_steer_rate_change > 0 and not self.w_pedal_rate_change > self.w_steer_rate_change:
            raise ValueError("MpcConfig: the report (section VI) weights velocity effort above "
                             "steering effort: need w_pedal_rate_change > w_steer_rate_change")
        if self.w_steer_replan > 0 and not self.w_pedal_replan > self.w_steer_replan:
            raise ValueError("MpcConfig: the report (section VI) weights velocity effort above "
                             "steering effort: need w_pedal_replan > w_steer_replan")
        if not self.hold_brake_rate_ps > 0:
            raise ValueError("MpcConfig.hold_brake_rate_ps must be positive")
        for name in ("w_floor", "w_transition", "w_pedal_level", "w_steer_level",
                     "w_steer_rate_change", "w_pedal_rate_change", "w_steer_sharpness",
                     "w_steer_replan", "w_pedal_replan", "replan_window_s"):
            if getattr(self, name) < 0:
                raise ValueError(f"MpcConfig.{name} must be >= 0")
        if self.check_termination < 1 or self.adaptive_rho_interval < 0:
            raise ValueError("MpcConfig: check_termination must be >= 1 and "
                             "adaptive_rho_interval >= 0")
        if not self.adaptive_rho_tolerance >= 1:
            raise ValueError("MpcConfig.adaptive_rho_tolerance must be >= 1")
        if not 0 < self.admm_alpha < 2:
            raise ValueError("MpcConfig.admm_alpha must be in (0, 2)")
        if self.max_iter < 1:
            raise ValueError("MpcConfig.max_iter must be >= 1")

    @property
    def n_stages(self) -> int:
        return int(round(self.horizon_s / self.dt_s))


def preferred_zone(params: Params) -> int:
    """The most accurate zone: lowest ``nmse_pct``; without fit metrics, the zone that
    holds 3.5 m/s (the report's low zone, 2-5 m/s, section VI)."""
    scored = [(z.nmse_pct, i) for i, z in enumerate(params.zones) if z.nmse_pct is not None]
    if scored:
        return min(scored)[1]
    return max(params.zone_for(3.5), 0)


class _QpLayout:
    """Index bookkeeping of the QP. Variables z = [x_0..x_N | u_0..u_{N-1} | s_0..s_{N-1}],
    slack s_k = (jerk limit, speed low, speed high) of the transition k -> k+1."""

    def __init__(self, n_stages: int, dt_s: float):
        N = self.N = n_stages
        self.dt = dt_s
        self.nx_all = NX * (N + 1)
        self.nu_all = NU * N
        self.n = self.nx_all + self.nu_all + NS * N
        ix = lambda k, i: NX * k + i                        # noqa: E731
        iu = lambda k, i: self.nx_all + NU * k + i          # noqa: E731
        isl = lambda k, i: self.nx_all + self.nu_all + NS * k + i  # noqa: E731
        self.ix, self.iu, self.isl = ix, iu, isl

        # ---------------- P pattern (upper triangle), COO order = value order
        pr, pc = [], []
        for k in range(1, N + 1):
            for a, b in _UT4:
                pr.append(ix(k, a)); pc.append(ix(k, b))
        for k in range(N):
            for i in range(NU):
                pr.append(iu(k, i)); pc.append(iu(k, i))
        for k in range(1, N):
            for i in range(NU):
                pr.append(iu(k - 1, i)); pc.append(iu(k, i))
        for k in range(2, N):  # second differences (rate changes) couple k-2 and k
            for i in range(NU):
                pr.append(iu(k - 2, i)); pc.append(iu(k, i))
        for k in range(N):
            for i in range(NS):
                pr.append(isl(k, i)); pc.append(isl(k, i))
        self.p_seg = np.cumsum([0, 10 * N, NU * N, NU * (N - 1), NU * (N - 2), NS * N])
        self.P, self.P_perm = _pattern(pr, pc, self.n, self.n)

        # ---------------- A pattern, rows by block
        ar, ac, av = [], [], []
        row = 0

        def put(r, c, v):
            ar.append(r); ac.append(c); av.append(v)
        # dynamics: x_0 = x_init; x_{k+1} - Ad x_k - Bd u_k = c_k
        for i in range(NX):
            put(i, ix(0, i), 1.0)
        for k in range(N):
            for i in range(NX):
                put(NX * (k + 1) + i, ix(k + 1, i), 1.0)
        self.a_dynA = len(av)
        for k in range(N):
            for i, j in _APAT:
                put(NX * (k + 1) + i, ix(k, j), 0.0)
        self.a_dynB = len(av)
        for k in range(N):
            for i, j in _BPAT:
                put(NX * (k + 1) + i, iu(k, j), 0.0)
        self.a_dyn_end = len(av)
        row = NX * (N + 1)
        self.r_dyn = slice(0, row)
        # input bounds
        self.r_u = slice(row, row + NU * N)
        for k in range(N):
            for i in range(NU):
                put(row + NU * k + i, iu(k, i), 1.0)
        row += NU * N
        # steering rate
        self.r_sr = slice(row, row + N)
        for k in range(N):
            put(row + k, iu(k, 0), 1.0)
            if k:
                put(row + k, iu(k - 1, 0), -1.0)
        row += N
        inv = 1.0 / dt_s
        # acceleration limits: no rows. Within a stage the acceleration (v_{k+1} - v_k)/dt
        # is exactly affine in the one free pedal (zone offset + scale * accel pedal, or
        # offset - brake_scale * brake pedal): they are bounds on that pedal
        # (MpcController._input_bounds), the same caps apply_limits puts on the command.
        # jerk low / high (per stage): a_k - a_{k-1}; a_{-1} enters the bounds
        for sign, name in ((1.0, "r_jl"), (-1.0, "r_jh")):
            setattr(self, name, slice(row, row + N))
            for k in range(N):
                if k == 0:
                    put(row, ix(1, 3), inv)
                    put(row, ix(0, 3), -inv)
                else:
                    put(row + k, ix(k + 1, 3), inv)
                    put(row + k, ix(k, 3), -2 * inv)
                    put(row + k, ix(k - 1, 3), inv)
                put(row + k, isl(k, 0), sign)
            row += N
        # speed low: v_{k+1} + s1 >= lo ; speed high: v_{k+1} - s2 <= hi
        self.r_vl = slice(row, row + N)
        for k in range(N):
            put(row + k, ix(k + 1, 3), 1.0)
            put(row + k, isl(k, 1), 1.0)
        row += N
        self.r_vh = slice(row, row + N)
        for k in range(N):
            put(row + k, ix(k + 1, 3), 1.0)
            put(row + k, isl(k, 2), -1.0)
        row += N
        # slacks >= 0
        self.r_s = slice(row, row + NS * N)
        for k in range(N):
            for i in range(NS):
                put(row + NS * k + i, isl(k, i), 1.0)
        row += NS * N
        self.m = row
        # row blocks of one row group per stage: (rows, rows per stage), for shifting duals
        self.row_blocks = [(self.r_dyn, NX), (self.r_u, NU), (self.r_sr, 1)] + [
            (getattr(self, r), 1) for r in ("r_jl", "r_jh", "r_vl", "r_vh")
        ] + [(self.r_s, NS)]
        self.A_vals = np.array(av)
        self.A, self.A_perm = _pattern(ar, ac, self.m, self.n)
        self.slack_shift = _Shift([(slice(0, NS * N), NS)])  # warm start: slacks
        self.dual_shift = _Shift(self.row_blocks)             # and the dual


def _difference_bands(w_rate: np.ndarray, w_rate_change: np.ndarray
                      ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Bands of the Hessian (1/2 u'Hu convention) over [u_-2, u_-1, u_0 .. u_{n-1}] of
    sum_k w_rate[k]/2 (u_k - u_{k-1})^2 + w_rate_change[k]/2 (u_k - 2 u_{k-1} + u_{k-2})^2,
    k = 0 .. n-1 (u_-1, u_-2: the inputs before the horizon). Returns (diag (n+2,),
    first off-diagonal (n+1,): entry j couples j and j+1, second (n,): j and j+2)."""
    w1 = np.asarray(w_rate, dtype=float)
    w2 = np.asarray(w_rate_change, dtype=float)
    n = len(w1)
    buf = np.zeros(3 * n + 3)  # one allocation (run every MPC step for the steering)
    diag, off1, off2 = buf[:n + 2], buf[n + 2:2 * n + 3], buf[2 * n + 3:]
    diag[2:] += w1           # first differences: +1 at k+2, -1 at k+1
    diag[1:-1] += w1
    off1[1:] -= w1
    diag[:-2] += w2          # second differences: (1, -2, 1) at k, k+1, k+2
    diag[1:-1] += 4.0 * w2
    diag[2:] += w2
    w2x2 = 2.0 * w2
    off1[:-1] -= w2x2
    off1[1:] -= w2x2
    off2 += w2
    return diag, off1, off2


class _Shift:
    """Shifts a vector made of per-stage blocks ((slice, entries per stage), contiguous
    from 0) in time by ``sh`` stages: each entry is linearly interpolated between the same
    entry of stages floor(k + sh) and the next, clipped to its block's last stage (the
    warm start, :meth:`MpcController._warm_start_vectors`).

    The interpolation indices and weights are kept for the last few shifts: at a steady
    control rate the shift takes only a few values (the same period, up to round-off)."""

    def __init__(self, blocks):
        stage, last, base, width, start = [], [], [], [], 0
        for sl, w in blocks:
            if sl.start != start:
                raise RuntimeError("_Shift: blocks must be contiguous")  # a layout bug
            n = (sl.stop - sl.start) // w
            stage.append(np.repeat(np.arange(n), w))
            last.append(np.full(n * w, n - 1))
            base.append(sl.start + np.tile(np.arange(w), n))
            width.append(np.full(n * w, w))
            start = sl.stop
        self.stage = np.concatenate(stage).astype(float)
        self.last = np.concatenate(last).astype(float)
        self.base = np.concatenate(base)
        self.width = np.concatenate(width).astype(float)
        self._cache: dict = {}

    def __call__(self, v: np.ndarray, sh: float) -> np.ndarray:
        got = self._cache.get(sh)
        if got is None:
            pos = np.clip(self.stage + sh, 0, self.last)
            k0 = np.floor(pos)
            f = pos - k0
            k1 = np.minimum(k0 + 1, self.last)
            got = (self.base + (k0 * self.width).astype(np.int64), 1 - f,
                   self.base + (k1 * self.width).astype(np.int64), f)
            if len(self._cache) >= 16:
                self._cache.clear()
            self._cache[sh] = got
        i0, g0, i1, g1 = got
        return v[i0] * g0 + v[i1] * g1


_STEPS6 = np.arange(6.0)


def _linspace6(start: float, stop: float) -> np.ndarray:
    """``np.linspace(start, stop, 6)``, the same arithmetic without its generality (called
    every step)."""
    step = (stop - start) / 5
    if step == 0:  # np.linspace's branch for a denormal step
        y = _STEPS6 / 5 * (stop - start)
    else:
        y = _STEPS6 * step
    y += start
    y[-1] = stop
    return y


_BLAS_THREADS = None  # threadpoolctl's controller of the loaded BLAS libraries, made once


def _one_blas_thread():
    """Context in which BLAS runs on one thread: the 3x3 DARE (``control.dlqr``) calls
    LAPACK's triangular solve, which OpenBLAS spreads over its threads; on a loaded machine
    waking them took 10-40 ms instead of 0.6 ms (tools/bench_mpc.py's p99). Same
    arithmetic on one thread for matrices this small."""
    global _BLAS_THREADS
    if _BLAS_THREADS is None:
        from threadpoolctl import ThreadpoolController
        _BLAS_THREADS = ThreadpoolController()
    return _BLAS_THREADS.limit(limits=1, user_api="blas")


def _pattern(rows, cols, m, n):
    """CSC matrix of the pattern and the permutation CSC-data-order -> value order."""
    ids = np.arange(1, len(rows) + 1, dtype=float)
    M = sp.coo_matrix((ids, (np.array(rows), np.array(cols))), shape=(m, n)).tocsc()
    M.sort_indices()
    if M.nnz != len(rows):
        raise RuntimeError("duplicate entries in a QP pattern")  # a bug in _QpLayout
    perm = (M.data - 1).astype(np.int64)
    return M, perm


def _lag_through(e: float, t0_s: float, t1_s: float, times_s: list, values: list,
                 tau_s: float) -> float:
    """A first-order lag's output at ``t1_s`` from ``e`` at ``t0_s`` [s], its input
    piecewise constant: ``values[i]`` from ``times_s[i]`` on (before the first: ``values[0]``);
    exact (models.plant.first_order_lag per piece)."""
    i = bisect.bisect_right(times_s, t0_s) - 1
    t = t0_s
    while t < t1_s - 1e-12:
        tn = min(times_s[i + 1] if i + 1 < len(times_s) else math.inf, t1_s)
        e = first_order_lag(e, values[max(i, 0)], tn - t, tau_s)
        t, i = tn, i + 1
    return e


@dataclass
class _LagState:
    """The actuator lags' outputs (steering-wheel angle, accel, brake pedal) at ``t_s``, as
    the MPC simulates them from the commands it issued (``history``: a reset starts anew)."""

    t_s: float
    e: list
    history: object


class MpcController:
    """The OSQP fast path. ``step`` returns a :class:`ControlResult`; see the module doc.

    Args:
        params: the model the controller believes (a complete parameter file).
        config: tuning (:class:`MpcConfig`).
        limits: actuator/comfort limits (default: from ``params``).
        mode_config: pedal/standstill mode logic tuning.
    """

    name = "mpc"

    def __init__(self, params: Params, config: MpcConfig | None = None,
                 limits: ActuatorLimits | None = None, mode_config: ModeConfig | None = None):
        if not params.is_model:
            raise ValueError("MpcController needs a complete model (steering and zones)")
        self.params = params
        self.config = config or MpcConfig()
        self.limits = limits or ActuatorLimits.from_params(params)
        self.mode_config = mode_config or ModeConfig()
        # the prediction model: the report's, plus the physics of ``extensions:`` that a
        # prediction model has (models.plant.plant_extensions; none: bit-identical)
        self.plant = HybridPlant(params, extensions=True)
        self.N = self.config.n_stages
        self.dt = self.config.dt_s
        self.layout = _QpLayout(self.N, self.dt)
        self.pref_zone = preferred_zone(params)
        floor = self.config.min_speed_mps
        self.floor_mps = params.zones[self.pref_zone].v_min_mps if floor is None else float(floor)
        self.dead_time_steer_s = float(params.steering.dead_time_s or 0.0)
        self.dead_time_long_s = float(params.longitudinal_dead_time_s or 0.0)
        ext = self.plant.ext
        #: actuator_lag time constants [s] (steering, pedals): see :meth:`_lag_command`
        self.lag_s = (0.0, 0.0) if ext is None else (ext.lag_steer_s, ext.lag_long_s)
        self._lag = None  # the simulated lag states: _LagState, set on the first step
        self._lqr_cache: dict = {}
        self._solver = None
        self._update_s = 0.0
        self._pedal = PedalModeLogic(self.mode_config)
        self._standstill = StandstillLogic(self.mode_config)
        self._build_constant_parts()
        self.reset()

    # ----------------------------------------------------------------- state
    def reset(self) -> None:
        """Forget the plan, the history and the modes (a new run)."""
        self._plan: Plan | None = None  # the last good solution
        self._history: deque = deque(maxlen=256)  # (t_issue_s, Command)
        self._last_cmd: Command | None = None
        self._last_t: float | None = None
        self._zone: int | None = None
        self._s_prog: float | None = None
        self._pedal.reset()
        self._standstill.reset()
        self._fixed = InFlight()  # inputs in flight at the start of the horizon
        self._warm = None          # (primal, dual) of the last good solution
        # stages elapsed since that solution's first stage (None: no plan to shift)
        self._shift_stages: float | None = None
        self._last_y: np.ndarray | None = None  # dual of the last OSQP solution

    def _build_constant_parts(self) -> None:
        L, N, dt = self.layout, self.N, self.dt
        lim = self.limits
        self._l0 = np.full(L.m, -np.inf)
        self._u0 = np.full(L.m, np.inf)
        self._l0[L.r_sr] = -lim.steering_wheel_rate_max_radps * dt
        self._u0[L.r_sr] = lim.steering_wheel_rate_max_radps * dt
        self._l0[L.r_jl] = -lim.jerk_max_mps3 * dt
        self._u0[L.r_jh] = lim.jerk_max_mps3 * dt
        self._u0[L.r_vh] = lim.speed_max_mps
        self._l0[L.r_s] = 0.0
        # input bounds: steering
        swmax = lim.steering_wheel_angle_max_rad
        self._u_lo = np.zeros((N, NU))
        self._u_hi = np.zeros((N, NU))
        self._u_lo[:, 0], self._u_hi[:, 0] = -swmax, swmax
        c = self.config
        sw_n = 1.0 / swmax ** 2
        self._w_sr = c.w_steer_effort * sw_n / dt       # per rad^2 of change per stage
        self._w_pr = c.w_speed_effort / dt               # per pedal^2 of change per stage
        self._w_sl = c.w_steer_level * sw_n * dt
        self._w_pl = c.w_pedal_level * dt
        self._w_src = c.w_steer_rate_change * sw_n / dt ** 3  # per rad^2 of 2nd difference
        self._w_prc = c.w_pedal_rate_change / dt ** 3          # per pedal^2 of 2nd difference
        # per unit of 1 / v^2 [(m/s)^2]: the sharpness term, per stage at the nominal speed
        self._w_sharp = c.w_steer_sharpness * sw_n / dt
        self._pedal_bands = _difference_bands(np.full(N, self._w_pr), np.full(N, self._w_prc))
        self._P_slack = np.full(NS * N, c.w_slack_quadratic * dt)
        k_re = min(int(round(c.replan_window_s / dt)), N)
        self._w_replan = np.zeros((N, NU))  # per unit^2 of distance from the last plan
        self._w_replan[:k_re, 0] = c.w_steer_replan * sw_n * dt
        self._w_replan[:k_re, 1:] = c.w_pedal_replan * dt
        self._Px_vals = np.zeros(L.P.nnz)
        self._build_step_constants()

    def _build_step_constants(self) -> None:
        """What every step would otherwise rebuild: arrays that do not change from step to
        step, the constant parts of P's values, per-zone bounds and bands (issue 9: the
        whole step no slower than before the estimator)."""
        N, dt, lim, c = self.N, self.dt, self.limits, self.config
        self._pedal_bounds = self._pedal_bound_table()
        pl = self.plant  # each zone's hysteresis band [m/s] (models.zones.zone_with_hysteresis)
        self._zone_bands = [(-math.inf if z == 0 else pl.v_min[z] - pl.hysteresis_mps,
                             pl.v_max[z] + pl.hysteresis_mps if z < pl.n_zones - 1 else math.inf)
                            for z in range(pl.n_zones)]
        self._band_v_hi = np.full(N, lim.speed_max_mps)     # _speed_band's defaults
        self._band_w_hi = np.full(N, c.w_speed_max * dt)
        self._w_src_all = np.full(N, self._w_src)            # _steer_bands
        self._t_stages = dt * np.arange(N + 1)               # stage times from stage 0 [s]
        self._sr_free = np.full(N, lim.steering_wheel_rate_max_radps * dt)  # _rate_and_fixed
        # per-step constants of the cost (_qp_cost, _input_cost_values)
        self._w_lat, self._w_head = c.w_lateral * dt, c.w_heading * dt
        self._w_spd = c.w_speed * dt
        self._w_jerk_slack = c.w_limit_violation * dt
        self._q_template = np.zeros(len(_UT4))
        self._q_template[_UT4.index((2, 2))] = self._w_head
        self._q_template[_UT4.index((3, 3))] = self._w_spd
        self._P_input_template = {}
        for replan in (False, True):
            ud = np.empty((N, NU))
            uo = np.empty((N - 1, NU))
            uo2 = np.empty((N - 2, NU))
            ud[:, 0] = uo[:, 0] = uo2[:, 0] = 0.0  # steering: written per step
            for i in (1, 2):
                dg, o1, o2 = self._pedal_bands
                ud[:, i] = dg[2:] + self._w_pl
                if replan:
                    ud[:, i] += self._w_replan[:, i]
                uo[:, i] = o1[2:]
                uo2[:, i] = o2[2:]
            self._P_input_template[replan] = np.concatenate(
                [ud.ravel(), uo.ravel(), uo2.ravel(), self._P_slack])

    # ------------------------------------------------------------------ step
    def step(self, state, reference: Reference, t_s: float, *, stop: bool = False,
             obstacle_distance_m: float | None = None) -> ControlResult:
        """One control step at time ``t_s`` from the measured ``state`` [x, y, psi, v].

        Args:
            state: measured state (local ENU, front-wheel point, m, m, rad, m/s).
            reference: the trajectory to follow.
            t_s: time [s] on the reference's clock.
            stop: a stop command (overrides the minimum-speed floor).
            obstacle_distance_m: distance to an obstacle ahead on the path [m] (overrides
                the floor; the speed reference comes down to stop before it).

        Returns a ControlResult; never raises, never None.
        """
        t_wall = time.perf_counter()
        try:
            x = np.asarray(state, dtype=float).reshape(-1)
            if x.shape != (4,) or not np.all(np.isfinite(x)):
                res = self._fallback(float(t_s), "invalid state")
            else:
                res = self._step(x, reference, float(t_s), bool(stop), obstacle_distance_m)
        except Exception as exc:  # never raise into the loop: a bug, recorded as one
            res = internal_error(self._stop_after_error(t_s), exc)
        res.step_time_s = time.perf_counter() - t_wall
        return res

    # -------------------------------------------------------------- internals
    def _finish(self, cmd: Command, t_s: float, zone: int, *,
                controlled_stop: bool = False, plan_inputs: np.ndarray | None = None
                ) -> Command:
        """The command through ``apply_limits``, recorded; with ``plan_inputs`` (the QP's
        inputs, the lags' outputs) and an actuator lag, first its inverse
        (:meth:`_lag_command`)."""
        dt = self.dt if self._last_t is None else max(t_s - self._last_t, 1e-3)
        if plan_inputs is not None and self._lag_act is not None:
            cmd = self._lag_command(cmd, plan_inputs, zone)
        z = self.params.zones[zone]
        out = apply_limits(cmd, self._last_cmd, self.limits, dt, zone=z,
                           controlled_stop=controlled_stop)
        self._last_cmd = out
        self._last_t = t_s
        self._history.append((t_s, out))
        return out

    def _fallback(self, t_s: float, reason: str) -> ControlResult:
        """Shift the previous plan; when none remains, a controlled stop."""
        zone = self._zone if self._zone is not None else 0
        plan = self._plan
        if plan is not None:
            k = int(math.floor((t_s - plan.t0_s) / self.dt + 1e-9))
            k_s, k_l = self._fixed.steer_stages, self._fixed.pedal_stages
            if 0 <= k and k + max(k_s, k_l) < self.N - 1:
                U = plan.inputs
                sw, ap, bp = U[k + k_s, 0], U[k + k_l, 1], U[k + k_l, 2]
                cmd = self._finish(Command(float(sw), float(ap), float(bp)), t_s, zone)
                return ControlResult(cmd, Status.SHIFTED_PLAN, reason, plan=plan.states,
                                     plan_inputs=U, zone_plan=plan.zones,
                                     mode_plan=plan.modes, zone=zone,
                                     pedal_mode=int(plan.modes[k]))
            self._plan = None
        return self._controlled_stop(t_s, reason, zone)

    def _stop_after_error(self, t_s) -> ControlResult:
        """The command after an unexpected exception: the plan and warm start are dropped
        (what raised may have left them half-written) and a controlled stop begins. Should
        that raise too, the last resort: throttle released, brake pressed at its rate limit,
        steering held (``apply_limits`` on a non-finite command)."""
        self._plan = None
        self._warm = None
        try:
            zone = self._zone if self._zone is not None else 0
            return self._controlled_stop(float(t_s), "", zone)
        except Exception:  # noqa: BLE001 - the caller records the first exception
            prev = self._last_cmd
            cmd = apply_limits(Command(math.nan, 0.0, 0.0), prev, self.limits, self.dt)
            self._last_cmd = cmd
            return ControlResult(cmd, Status.CONTROLLED_STOP, pedal_mode=int(PedalMode.BRAKE))

    def _controlled_stop(self, t_s: float, reason: str, zone: int) -> ControlResult:
        """Brake ramp to a moderate deceleration (``config.stop_brake_decel_mps2``, capped by
        ``limits.controlled_stop_decel_max_mps2``), throttle released, steering held."""
        z = self.params.zones[zone]
        prev = self._last_cmd
        dt = self.dt if self._last_t is None else max(t_s - self._last_t, 1e-3)
        target = min(1.0, max(z.offset_mps2 + self.config.stop_brake_decel_mps2, 0.0)
                     / max(z.brake_scale_mps2, 1e-6))
        ramp = self.limits.jerk_max_mps3 / max(z.brake_scale_mps2, 1e-6) * dt
        bp0 = prev.brake_pedal if prev is not None else 0.0
        bp = min(target, bp0 + ramp) if bp0 < target else bp0
        sw = prev.steering_wheel_angle_rad if prev is not None else 0.0
        cmd = self._finish(Command(sw, 0.0, bp), t_s, zone, controlled_stop=True)
        return ControlResult(cmd, Status.CONTROLLED_STOP, reason, zone=zone,
                             pedal_mode=int(PedalMode.BRAKE))

    def _predict_through_delay(self, x: np.ndarray, t_s: float) -> tuple[np.ndarray, float]:
        """Predict through the inputs in flight.

        With dead times d_s (steering) and d_l (pedals), the QP starts at t + d0,
        d0 = min(d_s, d_l): the state is predicted to then with the commands already issued
        (both channels are known up to t + d0). The channel with the longer dead time has
        its first round((d_c - d0) / dt) QP stages fixed to its in-flight commands
        (``self._fixed``); its command now is the QP input at the stage where it will act.
        Returns (state at t + d0, d0). With an actuator lag, :meth:`_predict_through_lag`.
        """
        if self.lag_s != (0.0, 0.0) and self.lag_method in ("inverse", "stage"):
            return self._predict_through_lag(x, t_s)
        ds, dl = self.dead_time_steer_s, self.dead_time_long_s
        d0 = min(ds, dl)
        hist = list(self._history)
        last = self._last_cmd or Command(0.0, 0.0, 0.0)

        def issued_at(tq: float) -> Command:
            cmd = None
            for ti, c in hist:
                if ti <= tq + 1e-9:
                    cmd = c
                else:
                    break
            return cmd if cmd is not None else (hist[0][1] if hist else last)
        dt = self.dt
        k_s = int(round((ds - d0) / dt))
        k_l = int(round((dl - d0) / dt))
        t0 = t_s + d0
        steer = np.array([issued_at(t0 + k * dt - ds).steering_wheel_angle_rad
                          for k in range(k_s)])
        ped = np.array([[issued_at(t0 + k * dt - dl).accel_pedal,
                         issued_at(t0 + k * dt - dl).brake_pedal] for k in range(k_l)])
        self._fixed = InFlight(k_s, steer, k_l, ped.reshape(k_l, 2))
        if d0 <= 0:
            return x, 0.0
        n_sub = max(int(math.ceil(d0 / 0.05)), 1)
        h = d0 / n_sub
        s = x.copy()
        zone = self._zone
        for j in range(n_sub):
            tau = t_s + (j + 0.5) * h
            cs, cl = issued_at(tau - ds), issued_at(tau - dl)
            u = np.array([cs.steering_wheel_angle_rad, cl.accel_pedal, cl.brake_pedal])
            r = self.plant.step(s, u, h, zone)
            s, zone = r.state, r.zone
        return s, d0

    # ------------------------------------------------------ actuator lag (extensions)
    #: how an ``actuator_lag`` of the model is handled (chosen by evidence, see
    #: tools/bench_diagnose.py and the drive tests): "inverse" (the lag simulated in the
    #: prediction through the commands in flight, the QP plans the lag's output and the
    #: command is u + tau du/dt of the plan), "stage" (the same prediction, the command
    #: brings the lag's output to the plan's next stage in one stage), "delay" (the lag
    #: taken as a dead time of tau), "none" (ignored)
    lag_method = "inverse"
    _lag_act = None  # lag outputs (sw, ap, bp) where this step's command starts to act

    def use_lag_method(self, method: str) -> None:
        """Choose how an ``actuator_lag`` is handled (``lag_method``) before the first step."""
        if method not in ("inverse", "stage", "delay", "none"):
            raise ValueError(f"unknown lag method {method!r}")
        if self.lag_method == "delay":
            self.dead_time_steer_s -= self.lag_s[0]
            self.dead_time_long_s -= self.lag_s[1]
        self.lag_method = method
        if method == "delay":
            self.dead_time_steer_s += self.lag_s[0]
            self.dead_time_long_s += self.lag_s[1]

    def _lag_outputs(self, t_s: float, t_query: np.ndarray) -> np.ndarray:
        """The lags' outputs (sw [rad], accel, brake pedal) at the ascending times
        ``t_query`` >= ``t_s`` [s], (n, 3): the issued commands through the dead times and
        the first-order lags (models.plant.first_order_lag), from the state kept at the
        last step (advanced to ``t_s`` here: every command acting until then is issued)."""
        hist = list(self._history)
        if not hist:
            c = self._last_cmd or Command(0.0, 0.0, 0.0)
            return np.tile([c.steering_wheel_angle_rad, c.accel_pedal, c.brake_pedal],
                           (len(t_query), 1))
        taus = (self.lag_s[0], self.lag_s[1], self.lag_s[1])
        dts = (self.dead_time_steer_s, self.dead_time_long_s, self.dead_time_long_s)
        vals = [[c.steering_wheel_angle_rad for _, c in hist], [c.accel_pedal for _, c in hist],
                [c.brake_pedal for _, c in hist]]
        times = [[ti + d for ti, _ in hist] for d in dts]
        st = self._lag
        if st is None or st.history is not self._history:  # a new run: at rest on the first
            st = self._lag = _LagState(hist[0][0], [v[0] for v in vals], self._history)
        if t_s > st.t_s:
            st.e = [_lag_through(st.e[c], st.t_s, t_s, times[c], vals[c], taus[c])
                    for c in range(3)]
            st.t_s = t_s
        out = np.empty((len(t_query), 3))
        e, t = list(st.e), t_s
        for k, tq in enumerate(t_query):
            e = [_lag_through(e[c], t, tq, times[c], vals[c], taus[c]) for c in range(3)]
            t = max(t, float(tq))
            out[k] = e
        return out

    def _predict_through_lag(self, x: np.ndarray, t_s: float) -> tuple[np.ndarray, float]:
        """:meth:`_predict_through_delay` with the lags' outputs as the plant's inputs: the
        state at t + d0, the in-flight stages fixed to the lags' outputs at their middles,
        and ``_lag_act``, the outputs where this step's command starts to act (t + d of
        its channel), for :meth:`_lag_command`."""
        ds, dl = self.dead_time_steer_s, self.dead_time_long_s
        d0, dt = min(ds, dl), self.dt
        k_s, k_l = int(round((ds - d0) / dt)), int(round((dl - d0) / dt))
        n_sub = max(int(math.ceil(d0 / 0.05)), 1) if d0 > 0 else 0
        h = d0 / n_sub if n_sub else 0.0
        t_sub = t_s + (np.arange(n_sub) + 0.5) * h
        t_fix = t_s + d0 + (np.arange(max(k_s, k_l)) + 0.5) * dt
        t_act = np.array([t_s + ds, t_s + dl])
        tq = np.concatenate([t_sub, t_fix, t_act])
        order = np.argsort(tq, kind="stable")
        e = np.empty((len(tq), 3))
        e[order] = self._lag_outputs(t_s, tq[order])
        e_sub, e_fix, e_act = e[:n_sub], e[n_sub:n_sub + len(t_fix)], e[n_sub + len(t_fix):]
        self._fixed = InFlight(k_s, e_fix[:k_s, 0].copy(), k_l, e_fix[:k_l, 1:].copy())
        self._lag_act = np.array([e_act[0, 0], e_act[1, 1], e_act[1, 2]])
        s, zone = x.copy(), self._zone
        for j in range(n_sub):
            r = self.plant.step(s, e_sub[j], h, zone)
            s, zone = r.state, r.zone
        return s, d0

    def _lag_command(self, cmd: Command, U: np.ndarray, zone: int) -> Command:
        """The command that makes the lags' outputs follow the plan ``U`` (the QP's inputs
        are the lags' outputs): per ``lag_method``, u + tau (u_next - u) / dt ("inverse") or
        the lag's output at the plan's next stage one stage on ("stage"). The pedals are
        inverted as one signal, the pedal force of ``zone`` (scale ap - brake_scale bp): a
        positive result is throttle, a negative one brake, never both."""
        k_s, k_l = self._fixed.steer_stages, self._fixed.pedal_stages
        (ts, tl), e, pl, N = self.lag_s, self._lag_act, self.plant, self.N
        sw, ap, bp = cmd.steering_wheel_angle_rad, cmd.accel_pedal, cmd.brake_pedal
        if ts > 0 and k_s + 1 < N:
            sw = self._inverse_lag(sw, float(U[k_s + 1, 0]), float(e[0]), ts)
        if tl > 0 and k_l + 1 < N:
            sc, br = max(float(pl.z_scale[zone]), 1e-6), max(float(pl.z_brake[zone]), 1e-6)
            g = self._inverse_lag(sc * ap - br * bp, sc * float(U[k_l + 1, 1])
                                  - br * float(U[k_l + 1, 2]), sc * e[1] - br * e[2], tl)
            ap, bp = (min(g / sc, 1.0), 0.0) if g >= 0 else (0.0, min(-g / br, 1.0))
        return Command(float(sw), float(ap), float(bp))

    def _inverse_lag(self, u0: float, u1: float, e: float, tau_s: float) -> float:
        """One channel of :meth:`_lag_command`: plan u0 now, u1 a stage on, lag output e."""
        if self.lag_method == "stage":
            return e + (u1 - e) / (1.0 - math.exp(-self.dt / tau_s))
        return u0 + tau_s * (u1 - u0) / self.dt

    def _input_bounds(self, modes: np.ndarray, zones: np.ndarray | None = None):
        """Input bounds (N, 3) and steering-rate row bounds (N,): pedal modes, in-flight
        inputs fixed, rate relative to the last command. With ``zones`` (zone per stage),
        the acceleration limits too, as bounds on the free pedal (the stage's zone model);
        without (the NMPC keeps them as soft constraints), the free pedal spans [0, 1]."""
        ulo, uhi = self._u_lo.copy(), self._u_hi.copy()
        thr = modes == _THROTTLE
        if zones is None:
            uhi[:, 1] = np.where(thr, 1.0, 0.0)
            uhi[:, 2] = np.where(thr, 0.0, 1.0)
            return self._rate_and_fixed(ulo, uhi)
        tab = self._pedal_bounds[(~thr).view(np.int8), zones]  # (N, 4), per mode and zone
        ulo[:, 1:] = tab[:, 0::2]
        uhi[:, 1:] = tab[:, 1::2]
        return self._rate_and_fixed(ulo, uhi)

    def _pedal_bound_table(self) -> np.ndarray:
        """(2, n_zones, 4): [accel lo, accel hi, brake lo, brake hi] pedal bounds of a stage
        whose free pedal is the throttle (row 0) or the brake (row 1), per zone: the
        acceleration limits as bounds on the free pedal (the other is fixed at 0). Built
        once: they depend only on the zone models and the limits."""
        pl, lim = self.plant, self.limits
        off = np.asarray(pl.z_offset, dtype=float)
        sc = np.maximum(pl.z_scale, 1e-6)
        br = np.maximum(pl.z_brake, 1e-6)
        # throttle: -decel_max <= off + sc*ap <= accel_max; brake: same with -br*bp
        ap_lo, ap_hi = (-lim.decel_max_mps2 - off) / sc, (lim.accel_max_mps2 - off) / sc
        bp_lo, bp_hi = (off - lim.accel_max_mps2) / br, (off + lim.decel_max_mps2) / br
        out = np.zeros((2, len(off), 4))
        for row, (lo, hi) in enumerate(((ap_lo, ap_hi), (bp_lo, bp_hi))):
            p_hi = np.clip(hi, 0.0, 1.0)
            p_lo = np.minimum(np.clip(lo, 0.0, 1.0), p_hi)
            out[row, :, 2 * row], out[row, :, 2 * row + 1] = p_lo, p_hi
        return out

    def _rate_and_fixed(self, ulo: np.ndarray, uhi: np.ndarray):
        """Steering-rate row bounds; in-flight inputs fixed in ``ulo``/``uhi``."""
        srhi = self._sr_free.copy()
        srlo = -srhi
        prev = self._last_cmd
        if prev is not None:
            srlo[0] += prev.steering_wheel_angle_rad
            srhi[0] += prev.steering_wheel_angle_rad
        else:
            srlo[0], srhi[0] = -np.inf, np.inf
        f = self._fixed
        k_s, k_l = f.steer_stages, f.pedal_stages
        if k_s:
            ulo[:k_s, 0] = uhi[:k_s, 0] = f.steer_rad
            srlo[:k_s], srhi[:k_s] = -np.inf, np.inf
        if k_l:
            ulo[:k_l, 1:] = uhi[:k_l, 1:] = f.pedals
        return ulo, uhi, srlo, srhi

    def _lqr_terminal(self, v_mps: float, delta_rad: float) -> np.ndarray:
        """3x3 DARE solution on (lateral, heading, speed) errors, from control.dlqr.

        The error model is eq. 1 linearised in the path's frame (vehicle heading plus
        road-wheel angle along the path tangent): the lateral error rate is the y' row of
        ``models.plant.bicycle_jacobian`` there."""
        vq = max(round(v_mps * 2) / 2, 0.5)
        dq = round(delta_rad * 20) / 20
        key = (vq, dq)
        P3 = self._lqr_cache.get(key)
        if P3 is None:
            import control  # python-control: dlqr
            c, dt, pl = self.config, self.dt, self.plant
            j = bicycle_jacobian(-dq, vq, dq, pl.wheelbase_m, pl.scale, ops=math)
            Ac = np.array([[0.0, j.dy_dpsi, j.dy_dv], [0.0, 0.0, j.dpsi_dv], [0.0, 0.0, 0.0]])
            Bc = np.array([[j.dy_du, 0.0], [j.dpsi_du, 0.0], [0.0, 1.0]])
            Ad = np.eye(3) + Ac * dt + Ac @ Ac * dt * dt / 2
            Bd = (np.eye(3) * dt + Ac * dt * dt / 2) @ Bc
            Q = np.diag([c.w_lateral, c.w_heading, c.w_speed]) * dt
            R = np.diag([c.r_terminal_steer, c.r_terminal_accel]) * dt
            with _one_blas_thread():
                _K, P3, _E = control.dlqr(Ad, Bd, Q, R)
            P3 = np.asarray(P3)
            if len(self._lqr_cache) > 512:
                self._lqr_cache.clear()
            self._lqr_cache[key] = P3
        return P3

    def _speed_reference(self, ref: Reference, tk: np.ndarray, v0: float, stop: bool,
                         obstacle_m: float | None, s_rel: np.ndarray) -> np.ndarray:
        v_r = ref.speed_at(tk)
        dec = self.config.stop_decel_mps2
        if stop:
            v_r = np.minimum(v_r, np.maximum(v0 - dec * (tk - tk[0]), 0.0))
        if obstacle_m is not None and math.isfinite(obstacle_m):
            room = np.maximum(obstacle_m - self.config.obstacle_margin_m - s_rel, 0.0)
            v_r = np.minimum(v_r, np.sqrt(2 * dec * room))
        return v_r

    def _step(self, x_meas: np.ndarray, ref: Reference, t: float, stop: bool,
              obstacle_m: float | None) -> ControlResult:
        """One step in named stages: delay compensation, standstill hold, path progress,
        nominal trajectory, then the SQP iterations (one when warm) of
        :meth:`_stage_data` + :meth:`_solve`."""
        cfg, L, N, pl = self.config, self.layout, self.N, self.plant
        x0, d = self._predict_through_delay(x_meas, t)
        x0[3] = max(x0[3], 0.0)
        self._zone = pl.select_zone(float(x_meas[3]), self._zone)
        zone0 = pl.select_zone(float(x0[3]), self._zone)
        tk = t + d + self._t_stages
        override = stop or (obstacle_m is not None and obstacle_m < 1e9)
        held = self._standstill_hold(x_meas, ref, t, d, stop, obstacle_m, zone0)
        if held is not None:
            return held
        s0 = self._progress(x0, ref, t)
        cold = self._plan is None
        Xb, Ub, a_prev = self._nominal(x0, ref, tk)
        # the pedal-mode decision uses the speed the last plan predicted for now, not the
        # raw measurement: a noise spike must not switch pedals (the QP itself starts from
        # the measurement)
        v_mode = float(x0[3]) if cold else float(Xb[0, 3])
        Xb[0] = x0
        iters = cfg.cold_start_iterations if cold else 1
        total_solve, total_update, total_it = 0.0, 0.0, 0
        first = None
        for it in range(iters):
            stage, first = self._stage_data(
                x0, Xb, Ub, a_prev, ref, tk, s0, zone0, v_mode, t, cold=cold,
                seed_guess=cold and it == 0, first=first, stop=stop, obstacle_m=obstacle_m,
                override=override)
            out = self._solve(stage)
            total_solve += out.solve_time_s
            total_update += out.update_time_s
            total_it += out.iterations
            if out.solution is None:
                break
            sol = out.solution
            Xb = sol[:L.nx_all].reshape(N + 1, NX).copy()
            Ub = sol[L.nx_all:L.nx_all + L.nu_all].reshape(N, NU).copy()

        if out.solution is None:
            res = self._fallback(t, out.reason)
            res.solve_time_s, res.iterations = total_solve, total_it
            return res
        self._warm = (out.solution, self._last_y)
        # each channel's command is the QP input at the stage where it will act; the QP's
        # bounds make the non-free pedal exactly 0 (clean solver round-off)
        k_s, k_l = self._fixed.steer_stages, self._fixed.pedal_stages
        modes, zones = stage.modes, stage.zones
        mode_l = int(modes[k_l])  # plain ints: comparing NumPy values with an IntEnum is slow
        ap = float(Ub[k_l, 1]) if mode_l == _THROTTLE else 0.0
        bp = float(Ub[k_l, 2]) if mode_l == _BRAKE else 0.0
        cmd = self._finish(Command(float(Ub[k_s, 0]), ap, bp), t, zone0, plan_inputs=Ub)
        self._plan = Plan(float(tk[0]), Xb, Ub, zones, modes)
        status = Status.SOLVED_INACCURATE if out.inaccurate else Status.SOLVED
        return ControlResult(cmd, status, solve_time_s=total_solve, plan=Xb,
                             plan_inputs=Ub, zone_plan=zones, mode_plan=modes, zone=zone0,
                             pedal_mode=mode_l, iterations=total_it,
                             info={"v_ref_mps": stage.v_ref_mps, "s0_m": s0,
                                   "update_time_s": total_update})

    def _standstill_hold(self, x_meas: np.ndarray, ref: Reference, t: float, d: float,
                         stop: bool, obstacle_m: float | None,
                         zone0: int) -> ControlResult | None:
        """Standstill HOLD (mode logic; no QP needed while the car is held): the result of
        this step if the car is held, else None."""
        cfg = self.config
        look = ref.speed_at(_linspace6(t, t + d + self.mode_config.hold_lookahead_s))
        stop_now = stop or (obstacle_m is not None and obstacle_m <= cfg.obstacle_margin_m)
        if not self._standstill.update(float(x_meas[3]), float(look.max()), stop_now):
            return None
        self._pedal.hold(t)
        self._plan = None
        self._warm = None
        z = self.params.zones[0]
        hold_bp = self._standstill.hold_brake(z.offset_mps2, z.brake_scale_mps2)
        prev = self._last_cmd
        if prev is not None and prev.brake_pedal < hold_bp and self._last_t is not None:
            # ramp from the brake on, never below what holds idle creep
            creep_bp = max(z.offset_mps2, 0.0) / max(z.brake_scale_mps2, 1e-6)
            ramp = cfg.hold_brake_rate_ps * max(t - self._last_t, 0.0)
            hold_bp = min(hold_bp, max(prev.brake_pedal + ramp, creep_bp))
        sw = prev.steering_wheel_angle_rad if prev is not None else 0.0
        cmd = self._finish(Command(sw, 0.0, hold_bp), t, zone0)
        if self._s_prog is not None:
            self._s_prog = ref.project(float(x_meas[0]), float(x_meas[1]), self._s_prog,
                                       5.0)[0]
        return ControlResult(cmd, Status.HOLD, zone=zone0, pedal_mode=int(PedalMode.HOLD))

    def _progress(self, x0: np.ndarray, ref: Reference, t: float) -> float:
        """Progress along the path [m]: the projection of the (delay-compensated) position,
        searched near the last one."""
        if self._s_prog is None:
            hint = float(ref.s_at_time(t))
            window = 30.0
        else:
            hint = self._s_prog
            window = 5.0 + 3.0 * float(x0[3]) * max(t - (self._last_t or t), self.dt)
        s0, _lat = ref.project(float(x0[0]), float(x0[1]), hint, window)
        self._s_prog = s0
        return s0

    def _nominal(self, x0: np.ndarray, ref: Reference, tk: np.ndarray
                 ) -> tuple[np.ndarray, np.ndarray, float]:
        """Nominal trajectory (states, inputs) and the acceleration before stage 0: the
        previous plan shifted in time to the stage times ``tk``, or without one a cold
        guess (a speed ramp towards the reference; :meth:`_path_reference` puts it on the
        path). Sets the warm start's shift."""
        N, dt = self.N, self.dt
        plan = self._plan
        if plan is not None:
            Xp, Up = plan.states, plan.inputs
            tp = plan.t0_s + self._t_stages
            Xb = np.column_stack([np.interp(tk, tp, Xp[:, j]) for j in range(NX)])
            Ub = np.column_stack([np.interp(tk[:-1], tp[:-1], Up[:, j]) for j in range(NU)])
            a_prev = float(np.interp(tk[0], tp[:-1], np.diff(Xp[:, 3]) / dt))
            self._shift_stages = (float(tk[0]) - plan.t0_s) / dt
            return Xb, Ub, a_prev
        self._shift_stages = None
        v_r0 = ref.speed_at(tk).tolist()
        vb = [float(x0[3])]
        dv_lo, dv_hi = -1.5 * dt, 1.0 * dt  # the ramp's speed change per stage [m/s]
        for k in range(N):
            vb.append(max(vb[k] + min(max(v_r0[k + 1] - vb[k], dv_lo), dv_hi), 0.0))
        Xb = np.zeros((N + 1, NX))
        Xb[:, 3] = vb
        return Xb, np.zeros((N, NU)), 0.0

    def _stage_data(self, x0, Xb, Ub, a_prev, ref, tk, s0, zone0, v_mode, t, *, cold,
                    seed_guess, first, stop, obstacle_m, override
                    ) -> tuple[StageData, PedalMode]:
        """What one SQP iteration solves, about the nominal (Xb, Ub): the path at the
        nominal positions, the speed reference, the zone and pedal-mode schedules and the
        speed band. ``first`` is the pedal mode of the first free stage, decided on the
        first iteration (None) and kept for the others; returned with the data."""
        dt = self.dt
        vb = np.maximum(Xb[:, 3], 0.0)
        s_k = np.empty(self.N + 1)  # s0 + distance along the nominal (trapezoidal) [m]
        s_k[0] = 0.0
        np.cumsum(0.5 * (vb[1:] + vb[:-1]) * dt, out=s_k[1:])
        s_k += s0
        path = self._path_reference(ref, s_k, Xb, Ub, x0, seed_guess)
        v_r = self._speed_reference(ref, tk, float(x0[3]), stop, obstacle_m, s_k - s0)
        zones = self._zone_schedule(zone0, vb)
        modes, first = self._pedal_modes(v_r, vb, v_mode, zones, Ub, t, cold, first)
        band = self._speed_band(zone0, v_r, override)
        return StageData(x0, Xb, Ub, zones, modes, path, v_r, band, a_prev), first

    def _path_reference(self, ref: Reference, s_k: np.ndarray, Xb: np.ndarray,
                        Ub: np.ndarray, x0: np.ndarray, seed_guess: bool) -> PathReference:
        """The path at the stage positions ``s_k`` [m]. With ``seed_guess`` (the first
        iteration of a cold start) the nominal states and steering are first put on the
        path, in place."""
        pl = self.plant
        xr, yr, th, kap = ref.point_at(s_k)
        dref = np.arcsin(np.minimum(np.maximum(kap * pl.wheelbase_m, -0.95), 0.95))  # clip
        psi_r = th - dref
        if seed_guess:  # the cold guess lies on the path
            Xb[1:, 0], Xb[1:, 1], Xb[1:, 2] = xr[1:], yr[1:], psi_r[1:]
            Xb[1:, 2] += 2 * np.pi * np.round((x0[2] - psi_r[0]) / (2 * np.pi))
        psi_r = psi_r + 2 * np.pi * np.round((Xb[:, 2] - psi_r) / (2 * np.pi))
        sw_max = self.limits.steering_wheel_angle_max_rad
        sw_ff = np.minimum(np.maximum(steering_wheel_angle_for(dref, pl.offset_rad, pl.scale),
                                      -sw_max), sw_max)
        if seed_guess:
            Ub[:, 0] = sw_ff[:-1]
        return PathReference(xr, yr, th, psi_r, dref, sw_ff)

    def _pedal_modes(self, v_r: np.ndarray, vb: np.ndarray, v_mode: float,
                     zones: np.ndarray, Ub: np.ndarray, t: float, cold: bool,
                     first: PedalMode | None) -> tuple[np.ndarray, PedalMode]:
        """Pedal mode per stage, one free pedal each (controller/modes.py); the stages
        whose pedals are in flight keep theirs. Returns (modes, mode of the first free
        stage), that mode decided here when ``first`` is None."""
        N, dt = self.N, self.dt
        k_l = self._fixed.pedal_stages
        vb_mode = vb.copy()
        vb_mode[0] = v_mode  # the switching signal is filtered; the QP is not
        a_des = desired_accel(v_r, vb_mode, dt, self.mode_config.error_time_constant_s)
        coast = self.plant.z_offset[zones]
        if first is None:
            exhausted = True
            cur = self._pedal.mode
            if not cold and cur in (PedalMode.THROTTLE, PedalMode.BRAKE):
                k_ex = max(int(round(self.mode_config.exhausted_lookahead_s / dt)), 1)
                exhausted = bool((Ub[k_l:k_l + k_ex, 1 + int(cur)] <= PEDAL_RELEASED).all())
            first = self._pedal.first(float(a_des[k_l]), float(coast[k_l]), t, exhausted)
        modes = np.empty(N, dtype=np.int8)
        modes[k_l:] = self._pedal.schedule(first, a_des[k_l:], coast[k_l:], dt,
                                           self._pedal.since_switch_s(t),
                                           None if cold else Ub[k_l:, 1:])
        if k_l:  # pedals in flight: their own modes
            modes[:k_l] = np.where(self._fixed.pedals[:, 0] > 0, PedalMode.THROTTLE,
                                   PedalMode.BRAKE)
        return modes, first

    def _zone_schedule(self, zone0: int, vb: np.ndarray) -> np.ndarray:
        """Zone per stage along the nominal speeds, with the plant's hysteresis. Most steps
        the nominal stays inside ``zone0``'s hysteresis band: then the schedule is
        ``zone0`` throughout (what the plant's stage-by-stage loop gives, checked at once)."""
        lo, hi = self._zone_bands[zone0]
        v = vb[1:self.N]
        if ((v >= lo) & (v <= hi)).all():
            return np.full(self.N, zone0, dtype=np.int64)
        out = np.empty(self.N, dtype=np.int64)
        out[0] = zone0
        out[1:] = self.plant.zone_schedule(vb[1:self.N], zone0)
        return out

    def _speed_band(self, zone0: int, v_r: np.ndarray, override: bool) -> SpeedBand:
        """Lower/upper speed targets of stages 1..N and the weights of their slacks."""
        cfg, pl, N, dt = self.config, self.plant, self.N, self.dt
        vr = v_r[1:]
        v_lo = np.zeros(N)
        # speed >= 0: an exact (L1) penalty while the reference moves; where it asks for
        # standstill the quadratic slack term alone keeps the plan at 0 (the brake may
        # press harder than needed at rest; an L1 kink there only slows the solver down)
        w_lo = np.where(vr > self.mode_config.standstill_speed_mps, cfg.w_standstill * dt, 0.0)
        v_hi = self._band_v_hi.copy()
        w_hi = self._band_w_hi.copy()
        if self.floor_mps > 0 and cfg.w_floor > 0 and not override:
            on = vr >= self.floor_mps
            v_lo = np.where(on, self.floor_mps, v_lo)
            w_lo = np.where(on, cfg.w_floor * dt, w_lo)
        if cfg.w_transition > 0:
            m = cfg.transition_band_margin_mps
            lo = pl.v_min[zone0] - pl.hysteresis_mps + m if zone0 > 0 else 0.0
            hi = pl.v_max[zone0] + pl.hysteresis_mps - m if zone0 < pl.n_zones - 1 else np.inf
            outside = (v_r < lo) | (v_r > hi)
            allowed = True
            if outside.any():
                k = int(outside.argmax())
                target = pl.zone_by_speed(float(v_r[k]))
                # a reference that comes to a standstill is a stop command: it overrides
                # the band like the floor (report VI), whatever the acceleration does
                stopping = float(v_r[k:].min()) <= self.mode_config.standstill_speed_mps
                if target != self.pref_zone and not stopping:
                    a_ref = (v_r[1:] - v_r[:-1]) / dt  # np.diff
                    win = max(int(round(cfg.transition_window_s / dt)), 1)
                    dwell = max(int(round(cfg.transition_dwell_s / dt)), 1)
                    stays = bool(outside[k:min(k + dwell, N + 1)].all())
                    allowed = stays and transition_allowed(a_ref, k, win,
                                                           cfg.transition_accel_tol_mps2)
            else:
                allowed = False  # no transition demanded: leaving the band is penalised
            if not allowed and not override:
                if lo > 0:
                    use = lo > v_lo
                    v_lo = np.where(use, lo, v_lo)
                    w_lo = np.where(use, cfg.w_transition * dt, w_lo)
                if math.isfinite(hi):
                    use = hi < v_hi
                    v_hi = np.where(use, hi, v_hi)
                    w_hi = np.where(use, cfg.w_transition * dt, w_hi)
        return SpeedBand(v_lo, w_lo, v_hi, w_hi)

    def _solve(self, stage: StageData) -> SolveOutcome:
        """One QP about the nominal of ``stage``: linearise and discretise, write the new
        values into the fixed pattern, solve (warm-started)."""
        Ad, Bd, ck = self._linearise(stage.states, stage.inputs, stage.zones)
        Pdata, q = self._qp_cost(stage)
        Adata = self._qp_dynamics(Ad, Bd)
        lo, hi = self._qp_bounds(stage, ck)
        return self._osqp_solve(Pdata, q, Adata, lo, hi, stage.states, stage.inputs)

    def _linearise(self, Xb: np.ndarray, Ub: np.ndarray, zones: np.ndarray
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Discrete model about the nominal, per stage: x_{k+1} = Ad x_k + Bd u_k + c_k
        (2nd-order discretisation of the plant's Jacobians; c_k from the explicit midpoint
        step of the nonlinear model, the rule the NMPC integrates with)."""
        N, dt, pl = self.N, self.dt, self.plant
        A, B = jacobians_batch(pl, Xb[:N], Ub, zones)
        A2 = A @ A
        Ad = np.eye(NX) + A * dt + A2 * (dt * dt / 2)
        Bd = (dt * B) + (dt * dt / 2) * (A @ B)
        f1 = derivative_batch(pl, Xb[:N], Ub, zones)
        f2 = derivative_batch(pl, Xb[:N] + 0.5 * dt * f1, Ub, zones)
        xnext = Xb[:N] + dt * f2
        ck = xnext - np.einsum("kij,kj->ki", Ad, Xb[:N]) - np.einsum("kij,kj->ki", Bd, Ub)
        return Ad, Bd, ck

    def _qp_cost(self, stage: StageData) -> tuple[np.ndarray, np.ndarray]:
        """P values (CSC order) and q: tracking (state blocks from the path geometry),
        terminal cost from dlqr, input effort, slack penalties.

        Stage k's state block is [[wl nx^2, wl nx ny, 0, 0], [., wl ny^2, 0, 0],
        [0, 0, wh, 0], [0, 0, 0, wv]] (n = the path normal), the last one plus the
        terminal cost: only the path-dependent entries are written each step, into the
        constant ones (``_q_template``)."""
        L, N = self.layout, self.N
        path = stage.path
        th = path.heading_rad
        nxv, nyv = -np.sin(th[1:]), np.cos(th[1:])
        wl = self._w_lat
        Px = self._Px_vals
        qb = Px[:L.p_seg[1]].reshape(N, len(_UT4))  # view: state blocks, _UT4 order
        qb[:] = self._q_template
        q00, q01, q11 = wl * nxv * nxv, wl * nxv * nyv, wl * nyv * nyv
        qb[:, _UT4.index((0, 0))], qb[:, _UT4.index((0, 1))] = q00, q01
        qb[:, _UT4.index((1, 1))] = q11
        T = np.array([[nxv[-1], nyv[-1], 0.0, 0.0], [0, 0, 1.0, 0], [0, 0, 0, 1.0]])
        P3 = self._lqr_terminal(float(stage.states[-1, 3]),
                                float(path.road_wheel_angle_rad[-1]))
        PT = T.T @ P3 @ T
        qb[-1] += PT[_UT4_ROWS, _UT4_COLS]  # blocks are stored as their upper triangle
        replan = self._shift_stages is not None  # a previous plan, shifted to now
        bands_s = self._steer_bands(stage.states[:N, 3])
        self._input_cost_values(bands_s, replan, out=Px[L.p_seg[1]:])
        Pdata = Px[L.P_perm]  # slack quadratic weights stay constant; P in CSC order

        q = np.empty(L.n)
        qx = q[NX:L.nx_all].reshape(N, NX)
        x_r, y_r = path.x_m[1:], path.y_m[1:]
        # -Q_k r_k: the blocks' nonzero terms written out (the zeros an einsum over the
        # full blocks adds change no bit); the last stage's full block through the einsum
        qx[:, 0] = -(q00 * x_r + q01 * y_r)
        qx[:, 1] = -(q01 * x_r + q11 * y_r)
        qx[:, 2] = -(self._w_head * path.psi_rad[1:])
        qx[:, 3] = -(self._w_spd * stage.v_ref_mps[1:])
        QN = np.zeros((1, NX, NX))
        QN[0][_UT4_ROWS, _UT4_COLS] = qb[-1]
        QN[0] += QN[0].T * _STRICT_LOWER4
        rN = np.array([[x_r[-1], y_r[-1], path.psi_rad[-1], stage.v_ref_mps[-1]]])
        qx[-1] = -np.einsum("kij,kj->ki", QN, rN)[0]
        q[:NX] = 0.0
        qu = q[L.nx_all:L.nx_all + L.nu_all].reshape(N, NU)
        qu[:, 0] = -self._w_sl * path.steering_ff_rad[:N]
        qu[:, 1:] = 0.0
        if replan:
            qu -= self._w_replan * stage.inputs
        prior = self._prior_inputs()
        if prior is not None:  # the terms that couple stage 0 and 1 to the inputs before
            for i, (_dg, o1, o2) in enumerate((bands_s, self._pedal_bands, self._pedal_bands)):
                qu[0, i] += o2[0] * prior[0, i] + o1[1] * prior[1, i]
                qu[1, i] += o2[1] * prior[1, i]
        qs = q[L.nx_all + L.nu_all:].reshape(N, NS)
        qs[:, 0] = self._w_jerk_slack
        qs[:, 1] = stage.band.w_lo
        qs[:, 2] = stage.band.w_hi
        return Pdata, q

    def _steer_bands(self, v_nominal_mps: np.ndarray):
        """Steering's rate and rate-change bands (:func:`_difference_bands`): the rate weight
        is the effort plus the sharpness term at each stage's nominal speed."""
        v = np.maximum(np.asarray(v_nominal_mps, dtype=float),
                       self.config.steer_sharpness_speed_floor_mps)
        return _difference_bands(self._w_sr + self._w_sharp / (v * v), self._w_src_all)

    def _input_cost_values(self, bands_s, replan: bool,
                           out: np.ndarray | None = None) -> np.ndarray:
        """P values of the inputs (diagonal, first and second off-diagonal, in the layout's
        order) and of the slacks, written into ``out`` when given. Only steering's change
        per step (its rate weight follows the nominal speed); the pedals' and slacks'
        values are constant (``_P_input_template``, with and without a plan to replan
        from)."""
        N = self.N
        if out is None:
            out = np.empty(len(self._P_input_template[replan]))
        out[:] = self._P_input_template[replan]
        dg, o1, o2 = bands_s
        ud = dg[2:] + self._w_sl
        if replan:
            ud += self._w_replan[:, 0]
        out[0:NU * N:NU] = ud
        out[NU * N:NU * (2 * N - 1):NU] = o1[2:]
        out[NU * (2 * N - 1):NU * (3 * N - 3):NU] = o2[2:]
        return out

    def _prior_inputs(self) -> np.ndarray | None:
        """(2, NU): the two inputs before stage 0 as the rate terms see them, one stage
        apart: the last command, and before it the last command minus the change the last
        plan had over one stage then (its planned rate: a planned turn keeps its rate, while
        the step-to-step jitter of the commands gives the rate-change terms no momentum).
        None before the first command."""
        prev = self._last_cmd
        if prev is None:
            return None
        u1 = (prev.steering_wheel_angle_rad, prev.accel_pedal, prev.brake_pedal)
        out = np.array((u1, u1))
        plan = self._plan
        if plan is not None and self._last_t is not None:
            tp = plan.t0_s + self._t_stages[:self.N]
            k = min(max(int(np.searchsorted(tp, self._last_t + self.dt)), 1), self.N - 1)
            out[0] = out[1] - (plan.inputs[k] - plan.inputs[k - 1])
        return out

    def _qp_dynamics(self, Ad: np.ndarray, Bd: np.ndarray) -> np.ndarray:
        """A values (CSC order): the dynamics blocks written into the fixed pattern."""
        L = self.layout
        Av = L.A_vals
        Av[L.a_dynA:L.a_dynB] = -Ad.reshape(-1, NX * NX)[:, _APAT_FLAT].ravel()
        Av[L.a_dynB:L.a_dyn_end] = -Bd.reshape(-1, NX * NU)[:, _BPAT_FLAT].ravel()
        return Av[L.A_perm]

    def _qp_bounds(self, stage: StageData, ck: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Row bounds: initial state, dynamics offsets, inputs and steering rate, jerk
        from the acceleration before stage 0, the speed band."""
        L = self.layout
        lo, hi = self._l0.copy(), self._u0.copy()
        lo[:NX] = hi[:NX] = stage.x0
        lo[NX:L.nx_all] = hi[NX:L.nx_all] = ck.ravel()
        ulo, uhi, srlo, srhi = self._input_bounds(stage.modes, stage.zones)
        lo[L.r_u] = ulo.ravel()
        hi[L.r_u] = uhi.ravel()
        lo[L.r_sr] = srlo
        hi[L.r_sr] = srhi
        jd = self.limits.jerk_max_mps3 * self.dt
        lo[L.r_jl.start] = stage.a_prev_mps2 - jd
        hi[L.r_jh.start] = stage.a_prev_mps2 + jd
        lo[L.r_vl] = stage.band.v_lo_mps
        hi[L.r_vh] = stage.band.v_hi_mps
        return lo, hi

    def _osqp_solve(self, Pdata: np.ndarray, q: np.ndarray, Adata: np.ndarray,
                    lo: np.ndarray, hi: np.ndarray, Xb: np.ndarray,
                    Ub: np.ndarray) -> SolveOutcome:
        """Set up OSQP once (pattern), else update the values in place; warm start; solve."""
        cfg, L = self.config, self.layout
        if self._solver is None:
            import osqp
            Pm = L.P.copy()
            Pm.data = Pdata
            Am = L.A.copy()
            Am.data = Adata
            self._solver = osqp.OSQP()
            settings = dict(verbose=False, warm_starting=True, polishing=False,
                            eps_abs=cfg.eps_abs, eps_rel=cfg.eps_rel, max_iter=cfg.max_iter,
                            adaptive_rho=True, check_termination=cfg.check_termination,
                            adaptive_rho_interval=cfg.adaptive_rho_interval,
                            adaptive_rho_tolerance=cfg.adaptive_rho_tolerance,
                            alpha=cfg.admm_alpha)
            if cfg.time_limit_s > 0:
                settings["time_limit"] = cfg.time_limit_s
            self._solver.setup(Pm, q, Am, lo, hi, **settings)
        else:
            t_up = time.perf_counter()
            self._solver.update(Px=Pdata, Ax=Adata, q=q, l=lo, u=hi)  # values in place
            self._update_s = time.perf_counter() - t_up  # includes OSQP's KKT refactorisation
        if self._warm is not None and self.config.warm_start_shifted:
            xw, yw = self._warm_start_vectors(Xb, Ub)
            if yw is None:
                self._solver.warm_start(x=xw)
            else:
                self._solver.warm_start(x=xw, y=yw)
        t0 = time.perf_counter()
        res = self._solver.solve(raise_error=False)
        solve_s = time.perf_counter() - t0
        sv = int(res.info.status_val)
        out = SolveOutcome(None, str(res.info.status), "osqp", solve_time_s=solve_s,
                           update_time_s=self._update_s, iterations=int(res.info.iter))
        ok = sv == 1 or (sv == 2 and cfg.accept_inaccurate)
        if not ok or res.x is None or not np.isfinite(res.x).all():
            return out
        out.inaccurate = sv != 1
        self._last_y = np.array(res.y)
        out.solution = np.array(res.x)
        return out

    def _warm_start_vectors(self, Xb: np.ndarray, Ub: np.ndarray
                            ) -> tuple[np.ndarray, np.ndarray | None]:
        """Primal and dual warm start: the previous solution shifted in time by the
        stages elapsed (linear interpolation per stage block, last stage repeated). The
        dual is None when the previous solution has none. Every block moves by the same
        shift, so slacks and all row blocks are shifted at once (:class:`_Shift`)."""
        L = self.layout
        x_prev, y_prev = self._warm
        sh = self._shift_stages
        z = np.empty(L.n)
        z[:L.nx_all] = Xb.ravel()
        z[L.nx_all:L.nx_all + L.nu_all] = Ub.ravel()
        if sh is None:  # cold guess: no previous plan to shift
            z[L.nx_all + L.nu_all:] = 0.0
            return z, None
        z[L.nx_all + L.nu_all:] = L.slack_shift(x_prev[L.nx_all + L.nu_all:], sh)
        if y_prev is None or len(y_prev) != L.m:
            return z, None
        return z, L.dual_shift(y_prev, sh)
