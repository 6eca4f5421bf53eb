"""The QP's constraints: the dynamics rows (the plant linearised about the nominal) and the
row bounds written each step.

- dynamics: x_0 = the delay-compensated state; x_{k+1} = Ad x_k + Bd u_k + c_k, eq. 1, 7, 8
  of models/plant.py linearised about the nominal and discretised (:func:`linearise`);
- inputs: steering angle within its limit; pedals in [0, 1], one free per stage (its pedal
  mode, controller/modes.py); the acceleration limits: within a stage the acceleration is
  affine in the free pedal, so they are bounds on it (the caps ``apply_limits`` puts on the
  command); the inputs still in flight (dead times) fixed;
- steering rate per stage, from the last command;
- jerk (soft, from the acceleration before stage 0) and the speed band (soft, the band of
  controller/mpc/zone_rules.py).

The bounds that do not change are built once (:class:`QpConstraints`).
"""

from __future__ import annotations

import numpy as np

from hmpc.models.plant import HybridPlant, derivative_batch, jacobians_batch

from hmpc.controller.horizon import InFlight, StageData
from hmpc.controller.limits import ActuatorLimits, Command
from hmpc.controller.modes import PedalMode
from hmpc.controller.mpc.qp import APAT_FLAT, BPAT_FLAT, NU, NX, QpLayout

_THROTTLE = int(PedalMode.THROTTLE)


def linearise(
    plant: HybridPlant, Xb: np.ndarray, Ub: np.ndarray, zones: np.ndarray, dt: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Discrete model about the nominal, per stage: x_{k+1} = Ad x_k + Bd u_k + c_k
    (2nd-order discretisation of the plant's Jacobians; c_k from the explicit midpoint
    step of the nonlinear model, the rule the NMPC integrates with). ``Xb``: the nominal
    states (N+1, 4), ``Ub`` its inputs (N, 3), ``zones`` (N,), ``dt`` the stage [s]."""
    N, pl = len(Ub), plant
    A, B = jacobians_batch(pl, Xb[:N], Ub, zones)
    A2 = A @ A
    Ad = np.eye(NX) + A * dt + A2 * (dt * dt / 2)
    Bd = (dt * B) + (dt * dt / 2) * (A @ B)
    f1 = derivative_batch(pl, Xb[:N], Ub, zones)
    f2 = derivative_batch(pl, Xb[:N] + 0.5 * dt * f1, Ub, zones)
    xnext = Xb[:N] + dt * f2
    ck = xnext - np.einsum("kij,kj->ki", Ad, Xb[:N]) - np.einsum("kij,kj->ki", Bd, Ub)
    return Ad, Bd, ck


def _pedal_bound_table(plant: HybridPlant, limits: ActuatorLimits) -> np.ndarray:
    """(2, n_zones, 4): [accel lo, accel hi, brake lo, brake hi] pedal bounds of a stage
    whose free pedal is the throttle (row 0) or the brake (row 1), per zone: the
    acceleration limits as bounds on the free pedal (the other is fixed at 0). Built
    once: they depend only on the zone models and the limits."""
    pl, lim = plant, limits
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


class QpConstraints:
    """The constraints' values: :meth:`dynamics_values` (A) and :meth:`row_bounds` (l, u),
    written into the layout's pattern.

    Args:
        layout: the QP's pattern.
        limits: actuator and comfort limits.
        plant: the prediction model (its zone models turn the acceleration limits into
            pedal bounds, once).
    """

    def __init__(self, layout: QpLayout, limits: ActuatorLimits, plant: HybridPlant):
        L, N, dt, lim = layout, layout.N, layout.dt, limits
        self.layout, self.limits, self.N, self.dt = layout, limits, N, dt
        self._l0 = np.full(L.m, -np.inf)
        self._u0 = np.full(L.m, np.inf)
        self._l0[L.r_sr] = -lim.steering_wheel_rate_max_radps * dt
        self._u0[L.r_sr] = lim.steering_wheel_rate_max_radps * dt
        # jerk rows in speed units (QpLayout): the change of acceleration per stage times dt
        self._l0[L.r_jl] = -lim.jerk_max_mps3 * dt * L.jerk_row_scale
        self._u0[L.r_jh] = lim.jerk_max_mps3 * dt * L.jerk_row_scale
        self._u0[L.r_vh] = lim.speed_max_mps
        self._l0[L.r_s] = 0.0
        # input bounds: steering
        swmax = lim.steering_wheel_angle_max_rad
        self._u_lo = np.zeros((N, NU))
        self._u_hi = np.zeros((N, NU))
        self._u_lo[:, 0], self._u_hi[:, 0] = -swmax, swmax
        self._pedal_bounds = _pedal_bound_table(plant, limits)
        self._sr_free = np.full(N, lim.steering_wheel_rate_max_radps * dt)  # _rate_and_fixed

    def use_zone_models(self, plant: HybridPlant) -> None:
        """The pedal bounds again, from ``plant``'s zone models (new model values)."""
        self._pedal_bounds = _pedal_bound_table(plant, self.limits)

    def dynamics_values(self, Ad: np.ndarray, Bd: np.ndarray) -> np.ndarray:
        """A values (CSC order): the dynamics blocks written into the fixed pattern."""
        L = self.layout
        Av = L.A_vals
        Av[L.a_dynA : L.a_dynB] = -Ad.reshape(-1, NX * NX)[:, APAT_FLAT].ravel()
        Av[L.a_dynB : L.a_dyn_end] = -Bd.reshape(-1, NX * NU)[:, BPAT_FLAT].ravel()
        return Av[L.A_perm]

    def row_bounds(
        self, stage: StageData, ck: np.ndarray, fixed: InFlight, last_cmd: Command | None
    ) -> tuple[np.ndarray, np.ndarray]:
        """Row bounds: initial state, dynamics offsets ``ck``, inputs and steering rate
        (:meth:`input_bounds`), jerk from the acceleration before stage 0, the speed band."""
        L = self.layout
        lo, hi = self._l0.copy(), self._u0.copy()
        lo[:NX] = hi[:NX] = stage.x0
        lo[NX : L.nx_all] = hi[NX : L.nx_all] = ck.ravel()
        ulo, uhi, srlo, srhi = self.input_bounds(stage.modes, stage.zones, fixed, last_cmd)
        lo[L.r_u] = ulo.ravel()
        hi[L.r_u] = uhi.ravel()
        lo[L.r_sr] = srlo
        hi[L.r_sr] = srhi
        jd = self.limits.jerk_max_mps3 * self.dt
        lo[L.r_jl.start] = (stage.a_prev_mps2 - jd) * L.jerk_row_scale
        hi[L.r_jh.start] = (stage.a_prev_mps2 + jd) * L.jerk_row_scale
        lo[L.r_vl] = stage.band.v_lo_mps
        hi[L.r_vh] = stage.band.v_hi_mps
        return lo, hi

    def input_bounds(
        self, modes: np.ndarray, zones: np.ndarray | None, fixed: InFlight, last_cmd: Command | None
    ):
        """Input bounds (N, 3) and steering-rate row bounds (N,): pedal modes, the inputs in
        flight (``fixed``) fixed, rate relative to the last command (``last_cmd``; None: the
        first stage's rate is free). With ``zones`` (zone per stage), the acceleration
        limits too, as bounds on the free pedal (the stage's zone model); without (the NMPC
        keeps them as soft constraints), the free pedal spans [0, 1]."""
        ulo, uhi = self._u_lo.copy(), self._u_hi.copy()
        thr = modes == _THROTTLE
        if zones is None:
            uhi[:, 1] = np.where(thr, 1.0, 0.0)
            uhi[:, 2] = np.where(thr, 0.0, 1.0)
            return self._rate_and_fixed(ulo, uhi, fixed, last_cmd)
        tab = self._pedal_bounds[(~thr).view(np.int8), zones]  # (N, 4), per mode and zone
        ulo[:, 1:] = tab[:, 0::2]
        uhi[:, 1:] = tab[:, 1::2]
        return self._rate_and_fixed(ulo, uhi, fixed, last_cmd)

    def _rate_and_fixed(
        self, ulo: np.ndarray, uhi: np.ndarray, fixed: InFlight, last_cmd: Command | None
    ):
        """Steering-rate row bounds; in-flight inputs fixed in ``ulo``/``uhi``."""
        srhi = self._sr_free.copy()
        srlo = -srhi
        prev = last_cmd
        if prev is not None:
            srlo[0] += prev.steering_wheel_angle_rad
            srhi[0] += prev.steering_wheel_angle_rad
        else:
            srlo[0], srhi[0] = -np.inf, np.inf
        f = fixed
        k_s, k_l = f.steer_stages, f.pedal_stages
        if k_s:
            ulo[:k_s, 0] = uhi[:k_s, 0] = f.steer_rad
            srlo[:k_s], srhi[:k_s] = -np.inf, np.inf
        if k_l:
            ulo[:k_l, 1:] = uhi[:k_l, 1:] = f.pedals
        return ulo, uhi, srlo, srhi
