"""The QP's objective (J = 1/2 z'Pz + q'z): its weights, built once from :class:`MpcConfig`,
and the values of P and q written each step.

- tracking: lateral and heading error to the reference path, speed error to the speed
  profile (per stage, weights per second of horizon);
- terminal cost: the DARE solution (dlqr) on the path-error linearisation;
- effort: pedal changes cost more than steering changes (report VI: "velocity control
  should have a higher cost"; checked in :class:`MpcConfig`);
- smoothness, terms of their own beside tracking: the change of the input rates (second
  differences, against the rate the last plan had), the unplanned part of the rate
  (distance of the first ``replan_window_s`` of inputs from the last plan, shifted to now;
  for the steering faded out over twice that, :func:`replan_fade`)
  and the steering-wheel rate per metre driven (path sharpness, weight 1/v^2);
- slack penalties of the soft limits (jerk, the speed band).

The input terms form banded blocks (:func:`difference_bands`); only steering's rate weight
changes from step to step (it follows the nominal speed), the rest is written from
templates built once. The NMPC (controller/nmpc.py) writes the same terms as a CasADi
expression from this object's weights.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.linalg import solve_discrete_are

from hmpc.models.plant import HybridPlant, bicycle_jacobian

from hmpc.controller.horizon import StageData
from hmpc.controller.limits import ActuatorLimits
from hmpc.controller.mpc.config import MpcConfig
from hmpc.controller.mpc.qp import NS, NU, NX, UT4, QpLayout

UT4_ROWS = np.array([a for a, _ in UT4])
UT4_COLS = np.array([b for _, b in UT4])
STRICT_LOWER4 = np.tril(np.ones((4, 4)), -1)


def difference_bands(
    w_rate: np.ndarray, w_rate_change: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Bands of the Hessian (1/2 u'Hu convention) over [u_-2, u_-1, u_0 .. u_{n-1}] of
    sum_k w_rate[k]/2 (u_k - u_{k-1})^2 + w_rate_change[k]/2 (u_k - 2 u_{k-1} + u_{k-2})^2,
    k = 0 .. n-1 (u_-1, u_-2: the inputs before the horizon). Returns (diag (n+2,),
    first off-diagonal (n+1,): entry j couples j and j+1, second (n,): j and j+2)."""
    w1 = np.asarray(w_rate, dtype=float)
    w2 = np.asarray(w_rate_change, dtype=float)
    n = len(w1)
    buf = np.zeros(3 * n + 3)  # one allocation (run every MPC step for the steering)
    diag, off1, off2 = buf[: n + 2], buf[n + 2 : 2 * n + 3], buf[2 * n + 3 :]
    diag[2:] += w1  # first differences: +1 at k+2, -1 at k+1
    diag[1:-1] += w1
    off1[1:] -= w1
    diag[:-2] += w2  # second differences: (1, -2, 1) at k, k+1, k+2
    diag[1:-1] += 4.0 * w2
    diag[2:] += w2
    w2x2 = 2.0 * w2
    off1[:-1] -= w2x2
    off1[1:] -= w2x2
    off2 += w2
    return diag, off1, off2


def replan_fade(window_s: float, dt_s: float, n_stages: int) -> np.ndarray:
    """(n_stages,) weight of the replan term per stage: a raised cosine from 1 at stage 0
    to 0 at twice ``window_s``, one half at ``window_s`` (the same sum as a window of
    ``window_s`` at full weight). A weight that ends in a step bends every plan where it
    ends (the inputs just past it are free to take the whole correction), and that bend
    reaches the command one step later as a steering reversal."""
    k = np.arange(n_stages) * dt_s
    fade_s = 2.0 * window_s
    if fade_s <= 0:
        return np.zeros(n_stages)
    return np.where(k < fade_s, 0.5 * (1.0 + np.cos(np.pi * np.minimum(k / fade_s, 1.0))), 0.0)


_BLAS_THREADS = None  # threadpoolctl's controller of the loaded BLAS libraries, made once


def _one_blas_thread():
    """Context in which BLAS runs on one thread: the 3x3 DARE (scipy's) calls
    LAPACK's triangular solve, which OpenBLAS spreads over its threads; on a loaded machine
    waking them costs many times the solve itself (tools/bench_mpc.py's p99). Same
    arithmetic on one thread for matrices this small."""
    global _BLAS_THREADS
    if _BLAS_THREADS is None:
        from threadpoolctl import ThreadpoolController

        _BLAS_THREADS = ThreadpoolController()
    return _BLAS_THREADS.limit(limits=1, user_api="blas")


class QpCost:
    """The objective's weights (per stage, normalised: steering-wheel angle by its maximum,
    pedals as fractions) and the P and q values of one step (:meth:`values`).

    Args:
        config: the tuning.
        limits: the steering-wheel angle's maximum normalises the steering terms.
        layout: the QP's pattern (where the values go).
    """

    def __init__(self, config: MpcConfig, limits: ActuatorLimits, layout: QpLayout):
        N, dt, c = layout.N, layout.dt, config
        self.config, self.layout, self.N, self.dt = config, layout, N, dt
        sw_n = 1.0 / limits.steering_wheel_angle_max_rad**2
        self.w_sr = c.w_steer_effort * sw_n / dt  # per rad^2 of change per stage
        self.w_pr = c.w_speed_effort / dt  # per pedal^2 of change per stage
        self.w_sl = c.w_steer_level * sw_n * dt
        self.w_pl = c.w_pedal_level * dt
        self.w_src = c.w_steer_rate_change * sw_n / dt**3  # per rad^2 of 2nd difference
        self.w_prc = c.w_pedal_rate_change / dt**3  # per pedal^2 of 2nd difference
        # per unit of 1 / v^2 [(m/s)^2]: the sharpness term, per stage at the nominal speed
        self.w_sharp = c.w_steer_sharpness * sw_n / dt
        self.pedal_bands = difference_bands(np.full(N, self.w_pr), np.full(N, self.w_prc))
        P_slack = np.full(NS * N, c.w_slack_quadratic * dt)
        fade = replan_fade(c.replan_window_s, dt, N)
        self.w_replan = np.zeros((N, NU))  # per unit^2 of distance from the last plan
        self.w_replan[:, 0] = c.w_steer_replan * sw_n * dt * fade
        # the pedals keep the full weight over the window: faded, the speed loop reacts
        # later (idle hold 0.020 against 0.015 m/s RMS), and a pedal bend is no reversal
        k_re = min(int(round(c.replan_window_s / dt)), N)
        self.w_replan[:k_re, 1:] = c.w_pedal_replan * dt
        self._Px_vals = np.zeros(layout.P.nnz)
        self._lqr_cache: dict = {}
        # what every step would otherwise rebuild: the constant parts of P's values
        self._w_src_all = np.full(N, self.w_src)  # steer_bands
        self._w_lat, self._w_head = c.w_lateral * dt, c.w_heading * dt
        self._w_spd = c.w_speed * dt
        self._w_jerk_slack = c.w_limit_violation * dt
        self._q_template = np.zeros(len(UT4))
        self._q_template[UT4.index((2, 2))] = self._w_head
        self._q_template[UT4.index((3, 3))] = self._w_spd
        self._P_input_template = {}
        for replan in (False, True):
            ud = np.empty((N, NU))
            uo = np.empty((N - 1, NU))
            uo2 = np.empty((N - 2, NU))
            ud[:, 0] = uo[:, 0] = uo2[:, 0] = 0.0  # steering: written per step
            for i in (1, 2):
                dg, o1, o2 = self.pedal_bands
                ud[:, i] = dg[2:] + self.w_pl
                if replan:
                    ud[:, i] += self.w_replan[:, i]
                uo[:, i] = o1[2:]
                uo2[:, i] = o2[2:]
            self._P_input_template[replan] = np.concatenate(
                [ud.ravel(), uo.ravel(), uo2.ravel(), P_slack]
            )

    def values(
        self, stage: StageData, plant: HybridPlant, replan: bool, prior: np.ndarray | None
    ) -> tuple[np.ndarray, np.ndarray]:
        """P values (CSC order) and q: tracking (state blocks from the path geometry),
        terminal cost from dlqr (about ``plant``), input effort, slack penalties. ``replan``:
        a previous plan, shifted to now, is in ``stage.inputs`` (the replan term applies);
        ``prior``: the two inputs before stage 0 (the controller's ``_prior_inputs``), or
        None before the first command.

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
        qb = Px[: L.p_seg[1]].reshape(N, len(UT4))  # view: state blocks, UT4 order
        qb[:] = self._q_template
        q00, q01, q11 = wl * nxv * nxv, wl * nxv * nyv, wl * nyv * nyv
        qb[:, UT4.index((0, 0))], qb[:, UT4.index((0, 1))] = q00, q01
        qb[:, UT4.index((1, 1))] = q11
        T = np.array([[nxv[-1], nyv[-1], 0.0, 0.0], [0, 0, 1.0, 0], [0, 0, 0, 1.0]])
        P3 = self.lqr_terminal(
            float(stage.states[-1, 3]), float(path.road_wheel_angle_rad[-1]), plant
        )
        PT = T.T @ P3 @ T
        qb[-1] += PT[UT4_ROWS, UT4_COLS]  # blocks are stored as their upper triangle
        bands_s = self.steer_bands(stage.states[:N, 3])
        self.input_values(bands_s, replan, out=Px[L.p_seg[1] :])
        Pdata = Px[L.P_perm]  # slack quadratic weights stay constant; P in CSC order

        q = np.empty(L.n)
        qx = q[NX : L.nx_all].reshape(N, NX)
        x_r, y_r = path.x_m[1:], path.y_m[1:]
        # -Q_k r_k: the blocks' nonzero terms written out (the zeros an einsum over the
        # full blocks adds change no bit); the last stage's full block through the einsum
        qx[:, 0] = -(q00 * x_r + q01 * y_r)
        qx[:, 1] = -(q01 * x_r + q11 * y_r)
        qx[:, 2] = -(self._w_head * path.psi_rad[1:])
        qx[:, 3] = -(self._w_spd * stage.v_ref_mps[1:])
        QN = np.zeros((1, NX, NX))
        QN[0][UT4_ROWS, UT4_COLS] = qb[-1]
        QN[0] += QN[0].T * STRICT_LOWER4
        rN = np.array([[x_r[-1], y_r[-1], path.psi_rad[-1], stage.v_ref_mps[-1]]])
        qx[-1] = -np.einsum("kij,kj->ki", QN, rN)[0]
        q[:NX] = 0.0
        qu = q[L.nx_all : L.nx_all + L.nu_all].reshape(N, NU)
        qu[:, 0] = -self.w_sl * path.steering_ff_rad[:N]
        qu[:, 1:] = 0.0
        if replan:
            qu -= self.w_replan * stage.inputs
        if prior is not None:  # the terms that couple stage 0 and 1 to the inputs before
            for i, (_dg, o1, o2) in enumerate((bands_s, self.pedal_bands, self.pedal_bands)):
                qu[0, i] += o2[0] * prior[0, i] + o1[1] * prior[1, i]
                qu[1, i] += o2[1] * prior[1, i]
        qs = q[L.nx_all + L.nu_all :].reshape(N, NS)
        qs[:, 0] = self._w_jerk_slack
        qs[:, 1] = stage.band.w_lo
        qs[:, 2] = stage.band.w_hi
        return Pdata, q

    def steer_bands(self, v_nominal_mps: np.ndarray):
        """Steering's rate and rate-change bands (:func:`difference_bands`): the rate weight
        is the effort plus the sharpness term at each stage's nominal speed."""
        v = np.maximum(
            np.asarray(v_nominal_mps, dtype=float), self.config.steer_sharpness_speed_floor_mps
        )
        return difference_bands(self.w_sr + self.w_sharp / (v * v), self._w_src_all)

    def input_values(self, bands_s, replan: bool, out: np.ndarray | None = None) -> np.ndarray:
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
        ud = dg[2:] + self.w_sl
        if replan:
            ud += self.w_replan[:, 0]
        out[0 : NU * N : NU] = ud
        out[NU * N : NU * (2 * N - 1) : NU] = o1[2:]
        out[NU * (2 * N - 1) : NU * (3 * N - 3) : NU] = o2[2:]
        return out

    def warm_terminal(self, plant: HybridPlant, v_max_mps: float) -> None:
        """The terminal costs of a straight road solved now, for every cached speed up to
        ``v_max_mps``: each is a 0.4-1 ms DARE that would otherwise fall on a control step
        the first time the horizon's end reaches that speed (on ramp_sequence they were the
        16 slowest steps of 1,550 at 0.2 s stages). About 15 ms for 20 m/s; at most the
        speeds to 100 m/s (a limit set higher is not a road car's: the rest are solved on use).
        A learned steering scale drops the cache (``MpcController.use_model``); it refills on
        use."""
        for k in range(1, int(min(v_max_mps, 100.0) * 2) + 1):
            self.lqr_terminal(0.5 * k, 0.0, plant)

    def lqr_terminal(self, v_mps: float, delta_rad: float, plant: HybridPlant) -> np.ndarray:
        """3x3 DARE solution on (lateral, heading, speed) errors about ``plant``'s eq. 1
        (cached per rounded speed and road-wheel angle).

        The error model is eq. 1 linearised in the path's frame (vehicle heading plus
        road-wheel angle along the path tangent): the lateral error rate is the y' row of
        ``models.plant.bicycle_jacobian`` there. Solved by ``scipy.linalg.
        solve_discrete_are``, what ``control.dlqr`` solves it with, called directly: a cache
        miss is a step of the 50 Hz loop, and python-control's checks and its gain and
        closed-loop poles, which are not used here, took half the miss's time."""
        vq = max(round(v_mps * 2) / 2, 0.5)
        dq = round(delta_rad * 20) / 20
        key = (vq, dq)
        P3 = self._lqr_cache.get(key)
        if P3 is None:
            c, dt, pl = self.config, self.dt, plant
            j = bicycle_jacobian(-dq, vq, dq, pl.wheelbase_m, pl.scale, ops=math)
            Ac = np.array([[0.0, j.dy_dpsi, j.dy_dv], [0.0, 0.0, j.dpsi_dv], [0.0, 0.0, 0.0]])
            Bc = np.array([[j.dy_du, 0.0], [j.dpsi_du, 0.0], [0.0, 1.0]])
            Ad = np.eye(3) + Ac * dt + Ac @ Ac * dt * dt / 2
            Bd = (np.eye(3) * dt + Ac * dt * dt / 2) @ Bc
            Q = np.diag([c.w_lateral, c.w_heading, c.w_speed]) * dt
            R = np.diag([c.r_terminal_steer, c.r_terminal_accel]) * dt
            with _one_blas_thread():
                P3 = solve_discrete_are(Ad, Bd, Q, R)
            if len(self._lqr_cache) > 512:
                self._lqr_cache.clear()
            self._lqr_cache[key] = P3
        return P3
