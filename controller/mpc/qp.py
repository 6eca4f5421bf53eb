"""The QP's fixed structure and its solver: the sparsity pattern built once, OSQP set up
once on it and updated in place.

Variables z = [x_0..x_N | u_0..u_{N-1} | s_0..s_{N-1}] (``NX`` states per stage, ``NU``
inputs, ``NS`` slacks); :class:`QpLayout` says where every variable and constraint row sits
and holds the patterns of P (upper triangle) and A with the permutation from the order the
values are written in to CSC order. Each step the cost (controller/mpc/cost.py) and the
constraints (controller/mpc/constraints.py) write new values in that order;
:class:`QpSolver` hands them to OSQP (``update(Px=, Ax=, q=, l=, u=)``: no new pattern, no
new solver) and warm-starts it from the previous solution, primal and dual, shifted in time
by the stages elapsed (:class:`_Shift`). A warm-started solve stops at
``MpcConfig.warm_iteration_cap`` iterations: its iterate is used when close enough
(``capped_prim_tol``, ``capped_dual_tol``), else the step fails (the controller shifts its
last plan) and the next solve continues from that iterate.
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np
import scipy.sparse as sp

from hmpc.controller.horizon import SolveOutcome
from hmpc.controller.mpc.config import MpcConfig

NX, NU, NS = 4, 3, 3  # state, input, slack (per stage)
#: OSQP 1.x's status values (its C enum ``osqp_status_type``; 0.6 numbered them otherwise)
_SOLVED, _SOLVED_INACCURATE, _MAX_ITER = 1, 2, 7
_OSQP_INFTY = 1e30  # OSQP's infinity (its OSQP_INFTY): bounds beyond it are clipped to it
UT4 = [(a, b) for a in range(4) for b in range(a, 4)]  # upper triangle of a 4x4 block
APAT = [(0, 0), (1, 1), (2, 2), (3, 3), (0, 2), (0, 3), (1, 2), (1, 3), (2, 3)]  # A_d pattern
BPAT = [(i, j) for i in range(4) for j in range(3)]
APAT_FLAT = np.array([NX * i + j for i, j in APAT])  # APAT in a flattened 4x4 block
BPAT_FLAT = np.array([NU * i + j for i, j in BPAT])  # BPAT in a flattened 4x3 block


class QpLayout:
    """Index bookkeeping of the QP. Variables z = [x_0..x_N | u_0..u_{N-1} | s_0..s_{N-1}],
    slack s_k = (jerk limit, speed low, speed high) of the transition k -> k+1."""

    #: constraint rows of the jerk limit, low and high (set in ``__init__`` by name)
    r_jl: slice
    r_jh: slice

    def __init__(self, n_stages: int, dt_s: float):
        N = self.N = n_stages
        self.dt = dt_s
        self.nx_all = NX * (N + 1)
        self.nu_all = NU * N
        self.n = self.nx_all + self.nu_all + NS * N
        ix = lambda k, i: NX * k + i  # noqa: E731
        iu = lambda k, i: self.nx_all + NU * k + i  # noqa: E731
        isl = lambda k, i: self.nx_all + self.nu_all + NS * k + i  # noqa: E731
        self.ix, self.iu, self.isl = ix, iu, isl

        # ---------------- P pattern (upper triangle), COO order = value order
        pr, pc = [], []
        for k in range(1, N + 1):
            for a, b in UT4:
                pr.append(ix(k, a))
                pc.append(ix(k, b))
        for k in range(N):
            for i in range(NU):
                pr.append(iu(k, i))
                pc.append(iu(k, i))
        for k in range(1, N):
            for i in range(NU):
                pr.append(iu(k - 1, i))
                pc.append(iu(k, i))
        for k in range(2, N):  # second differences (rate changes) couple k-2 and k
            for i in range(NU):
                pr.append(iu(k - 2, i))
                pc.append(iu(k, i))
        for k in range(N):
            for i in range(NS):
                pr.append(isl(k, i))
                pc.append(isl(k, i))
        self.p_seg = np.cumsum([0, 10 * N, NU * N, NU * (N - 1), NU * (N - 2), NS * N])
        self.P, self.P_perm = _pattern(pr, pc, self.n, self.n)

        # ---------------- A pattern, rows by block
        ar, ac, av = [], [], []
        row = 0

        def put(r, c, v):
            ar.append(r)
            ac.append(c)
            av.append(v)

        # dynamics: x_0 = x_init; x_{k+1} - Ad x_k - Bd u_k = c_k
        for i in range(NX):
            put(i, ix(0, i), 1.0)
        for k in range(N):
            for i in range(NX):
                put(NX * (k + 1) + i, ix(k + 1, i), 1.0)
        self.a_dynA = len(av)
        for k in range(N):
            for i, j in APAT:
                put(NX * (k + 1) + i, ix(k, j), 0.0)
        self.a_dynB = len(av)
        for k in range(N):
            for i, j in BPAT:
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
        # acceleration limits: no rows. Within a stage the acceleration (v_{k+1} - v_k)/dt
        # is exactly affine in the one free pedal (zone offset + scale * accel pedal, or
        # offset - brake_scale * brake pedal): they are bounds on that pedal
        # (controller/mpc/constraints.py), the same caps apply_limits puts on the command.
        # jerk low / high (per stage): (a_k - a_{k-1}) dt = v_{k+1} - 2 v_k + v_{k-1}, with
        # a_{-1} in the bounds; the slack (jerk violation, m/s^2 per stage) enters times dt.
        # The rows are written in speed units, the unit of the dynamics and speed-band rows
        # they meet: divided by dt (coefficients 1/dt, 2/dt) the same constraint took OSQP
        # longer, a third of the warm solves at 0.1 s stages stopping at the iteration cap
        # on ramp_sequence against 5 % (tools/bench_mpc.py)
        self.jerk_row_scale = dt_s  # a jerk row's value per m/s^2 per stage
        for sign, name in ((1.0, "r_jl"), (-1.0, "r_jh")):
            setattr(self, name, slice(row, row + N))
            for k in range(N):
                if k == 0:
                    put(row, ix(1, 3), 1.0)
                    put(row, ix(0, 3), -1.0)
                else:
                    put(row + k, ix(k + 1, 3), 1.0)
                    put(row + k, ix(k, 3), -2.0)
                    put(row + k, ix(k - 1, 3), 1.0)
                put(row + k, isl(k, 0), sign * dt_s)
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
        self.row_blocks = (
            [(self.r_dyn, NX), (self.r_u, NU), (self.r_sr, 1)]
            + [(getattr(self, r), 1) for r in ("r_jl", "r_jh", "r_vl", "r_vh")]
            + [(self.r_s, NS)]
        )
        self.A_vals = np.array(av)
        self.A, self.A_perm = _pattern(ar, ac, self.m, self.n)
        self.slack_shift = _Shift([(slice(0, NS * N), NS)])  # warm start: slacks
        self.dual_shift = _Shift(self.row_blocks)  # and the dual
        self.nominal_shift = _Shift(  # a plan's states and inputs, to the new stage times
            [(slice(0, self.nx_all), NX), (slice(self.nx_all, self.nx_all + self.nu_all), NU)]
        )
        self.primal_shift = _Shift(
            [
                (slice(0, self.nx_all), NX),  # an unfinished iterate
                (slice(self.nx_all, self.nx_all + self.nu_all), NU),
                (slice(self.nx_all + self.nu_all, self.n), NS),
            ]
        )


def _pattern(rows, cols, m, n):
    """CSC matrix of the pattern and the permutation CSC-data-order -> value order."""
    ids = np.arange(1, len(rows) + 1, dtype=float)
    M = sp.coo_matrix((ids, (np.array(rows), np.array(cols))), shape=(m, n)).tocsc()
    M.sort_indices()
    if M.nnz != len(rows):
        raise RuntimeError("duplicate entries in a QP pattern")  # a bug in QpLayout
    perm = (M.data - 1).astype(np.int64)
    return M, perm


class _Shift:
    """Shifts a vector made of per-stage blocks ((slice, entries per stage), contiguous
    from 0) in time by ``sh`` stages: each entry is linearly interpolated between the same
    entry of stages floor(k + sh) and the next, clipped to its block's first and last stage
    (the warm start, :meth:`QpSolver.warm_start_vectors`; the nominal, the controller's
    ``_nominal``).

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
            got = (
                self.base + (k0 * self.width).astype(np.int64),
                1 - f,
                self.base + (k1 * self.width).astype(np.int64),
                f,
            )
            if len(self._cache) >= 16:
                self._cache.clear()
            self._cache[sh] = got
        i0, g0, i1, g1 = got
        return v[i0] * g0 + v[i1] * g1


class QpSolver:
    """OSQP on the layout's pattern: set up on the first solve, its values updated in place
    after; warm-started from the last good solution shifted in time.

    Attributes:
        solver: the ``osqp.OSQP`` object (None before the first solve; never rebuilt).
        warm: (primal, dual) of the last good solution, or None (no warm start).
        last_y: the dual of the last OSQP solution.
    """

    def __init__(self, layout: QpLayout, config: MpcConfig):
        self.layout = layout
        self.config = config
        self.solver: Any = None  # osqp.OSQP once set up (osqp has no type information)
        self._update_s = 0.0
        self._max_iter = 0  # the iteration cap OSQP has now
        self._raw = None
        self.forget()

    def forget(self) -> None:
        """Drop the warm start (a new run); the solver and its pattern stay."""
        #: the previous solution (primal, dual) to warm-start from, or None
        self.warm: tuple[np.ndarray, np.ndarray | None] | None = None
        self.last_y: np.ndarray | None = None
        #: (primal, dual, shift) of an unfinished solve (the iteration cap) that could not
        #: be used: the next warm start; ``shift``: its stage 0 in stages after the warm
        #: start's plan's stage 0
        self.iterate: tuple | None = None

    def solve(
        self,
        Pdata: np.ndarray,
        q: np.ndarray,
        Adata: np.ndarray,
        lo: np.ndarray,
        hi: np.ndarray,
        Xb: np.ndarray,
        Ub: np.ndarray,
        shift_stages: float | None,
    ) -> SolveOutcome:
        """Set up OSQP once (pattern), else update the values in place; warm start; solve.
        ``Xb``, ``Ub``: the nominal (the primal warm start's states and inputs);
        ``shift_stages``: stages elapsed since the warm start's first stage (None: none to
        shift)."""
        cfg, L = self.config, self.layout
        if self.solver is None:
            import osqp

            Pm = L.P.copy()
            Pm.data = Pdata
            Am = L.A.copy()
            Am.data = Adata
            self.solver = osqp.OSQP()
            settings = dict(
                verbose=False,
                warm_starting=True,
                polishing=False,
                eps_abs=cfg.eps_abs,
                eps_rel=cfg.eps_rel,
                max_iter=cfg.warm_iteration_cap,
                adaptive_rho=cfg.adaptive_rho,
                rho=cfg.rho,
                check_termination=cfg.check_termination,
                adaptive_rho_interval=cfg.adaptive_rho_interval,
                adaptive_rho_tolerance=cfg.adaptive_rho_tolerance,
                alpha=cfg.admm_alpha,
                scaling=cfg.osqp_scaling,
            )
            if cfg.time_limit_s > 0:
                settings["time_limit"] = cfg.time_limit_s
            self.solver.setup(Pm, q, Am, lo, hi, **settings)
            self._max_iter = cfg.warm_iteration_cap
            # OSQP 1.x's extension object: its update and solve called directly save the
            # Python wrapper's per-call bookkeeping (about 0.1 ms a step); None: the wrapper
            raw = getattr(self.solver, "_solver", None)
            self._raw = (
                raw
                if all(
                    hasattr(raw, a)
                    for a in ("update_data_vec", "update_data_mat", "solve", "info", "solution")
                )
                else None
            )
        else:
            t_up = time.perf_counter()
            raw = self._raw
            if raw is not None:  # the same calls as OSQP.update, without its bookkeeping
                np.maximum(lo, -_OSQP_INFTY, out=lo)
                np.minimum(hi, _OSQP_INFTY, out=hi)
                raw.update_data_vec(q=q, l=lo, u=hi)
                raw.update_data_mat(P_x=Pdata, P_i=None, A_x=Adata, A_i=None)
            else:
                self.solver.update(Px=Pdata, Ax=Adata, q=q, l=lo, u=hi)  # values in place
            self._update_s = time.perf_counter() - t_up  # includes OSQP's KKT refactorisation
        cap = cfg.warm_iteration_cap if shift_stages is not None else cfg.max_iter_cold
        if cap != self._max_iter:  # a cold start (no plan to shift) has its own cap
            self.solver.update_settings(max_iter=cap)
            self._max_iter = cap
        if self.warm is not None and self.config.warm_start_shifted:
            xw, yw = self.warm_start_vectors(Xb, Ub, shift_stages)
            if yw is None:
                self.solver.warm_start(x=xw)
            else:
                self.solver.warm_start(x=xw, y=yw)
        t0, c0 = time.perf_counter(), time.thread_time()
        raw = self._raw
        if raw is not None:  # OSQP.solve without copying its info into a namespace
            raw.solve()
            info, sol = raw.info, raw.solution
            x, y = sol.x, sol.y
        else:
            res = self.solver.solve(raise_error=False)
            info, x, y = res.info, res.x, res.y
        solve_s, solve_cpu_s = time.perf_counter() - t0, time.thread_time() - c0
        sv = int(info.status_val)
        out = SolveOutcome(
            None,
            str(info.status),
            "osqp",
            solve_time_s=solve_s,
            update_time_s=self._update_s,
            iterations=int(info.iter),
            solve_cpu_s=solve_cpu_s,
        )
        finite = x is not None and np.isfinite(x).all()
        if sv == _MAX_ITER and finite:
            # the iteration cap: the iterate is used when its residuals are within the
            # capped tolerances (each step's command is only its first stages, and
            # the next step starts from it); otherwise it is kept as the next warm start
            # only and the step falls back (the previous plan, shifted)
            if info.prim_res <= cfg.capped_prim_tol and info.dual_res <= cfg.capped_dual_tol:
                out.inaccurate, out.capped = True, True
                self.iterate = None
                self.last_y = np.array(y)
                out.solution = np.array(x)
            elif shift_stages is not None:
                # the next step starts from this iterate (shifted by the stages elapsed
                # since its first stage), so that a hard QP converges over a few steps
                self.iterate = (np.array(x), np.array(y), shift_stages)
            return out
        ok = sv == _SOLVED or (sv == _SOLVED_INACCURATE and cfg.accept_inaccurate)
        if not ok or not finite:
            return out
        out.inaccurate = sv != _SOLVED
        self.iterate = None
        self.last_y = np.array(y)
        out.solution = np.array(x)
        return out

    def warm_start_vectors(
        self, Xb: np.ndarray, Ub: np.ndarray, shift_stages: float | None
    ) -> tuple[np.ndarray, np.ndarray | None]:
        """Primal and dual warm start: the previous solution shifted in time by the
        stages elapsed (linear interpolation per stage block, last stage repeated). The
        dual is None when the previous solution has none. Every block moves by the same
        shift, so slacks and all row blocks are shifted at once (:class:`_Shift`). After an
        unfinished solve that could not be used (``iterate``), that iterate, primal and dual,
        shifted by the stages elapsed since it."""
        L = self.layout
        if self.iterate is not None and shift_stages is not None:
            x_it, y_it, sh_it = self.iterate
            return L.primal_shift(x_it, shift_stages - sh_it), L.dual_shift(
                y_it, shift_stages - sh_it
            )
        assert self.warm is not None  # called only with a previous solution
        x_prev, y_prev = self.warm
        sh = shift_stages
        z = np.empty(L.n)
        z[: L.nx_all] = Xb.ravel()
        z[L.nx_all : L.nx_all + L.nu_all] = Ub.ravel()
        if sh is None:  # cold guess: no previous plan to shift
            z[L.nx_all + L.nu_all :] = 0.0
            return z, None
        z[L.nx_all + L.nu_all :] = L.slack_shift(x_prev[L.nx_all + L.nu_all :], sh)
        if y_prev is None or len(y_prev) != L.m:
            return z, None
        return z, L.dual_shift(y_prev, sh)
