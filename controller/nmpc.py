"""Hybrid-mode MPC, reference path: the same problem as a CasADi nonlinear program.

Everything outside the optimisation is shared with the fast path
(:class:`controller.mpc.MpcController`): delay compensation, zone and pedal-mode
schedules, the speed band (floor, zone-transition rule), the dlqr terminal cost, limits,
failure handling. Only the solve differs: instead of a QP on the model linearised about
the previous plan, a multiple-shooting NLP on the nonlinear bicycle (eq. 1, integrated
with the same explicit midpoint rule the QP is discretised from) is solved by IPOPT
(CasADi ``Opti``), warm-started from the previous plan. The NLP is built once; each step
sets its parameters.

The input cost is the fast path's, term for term (the smoothness terms included, with
the weights of the fast path's ``QpCost``, controller/mpc/cost.py): per stage the
steering-wheel and pedal rates (the effort weights, velocity above steering, report VI; the
steering rate also weighted by the path-sharpness term at the stage's nominal speed), their
changes (second differences), the two inputs before the horizon as the fast path sees them
(``MpcController._prior_inputs``: the last command, and its planned rate), and the cost
of moving the first ``replan_window_s`` of inputs away from the previous plan. The
smoothness is thus a separate term from tracking in both, and both solve one problem.

It is used to check the fast path (tests: both agree on simple cases) and as a
reference in ``tools/bench_mpc.py``. Its model is models/plant.py's eq. 1, 7 and 8, the same
functions the plant and the fast path call, evaluated on CasADi symbols (``ops=casadi``).
"""

from __future__ import annotations

import time
from typing import TYPE_CHECKING

import numpy as np

from hmpc.models.params import Params
from hmpc.models.plant import HybridPlant, bicycle_rates, road_wheel_angle, zone_accel

from hmpc.controller.horizon import SolveOutcome, StageData
from hmpc.controller.limits import ActuatorLimits
from hmpc.controller.modes import ModeConfig
from hmpc.controller.mpc import MpcConfig, MpcController
from hmpc.controller.mpc.qp import NS, NU, NX

if TYPE_CHECKING:
    import casadi as ca


class NmpcController(MpcController):
    """CasADi/IPOPT nonlinear MPC with the step API of :class:`MpcController`.

    Args: as :class:`MpcController`; ``ipopt_max_iter`` caps IPOPT's iterations.
    """

    name = "nmpc"

    def __init__(
        self,
        params: Params,
        config: MpcConfig | None = None,
        limits: ActuatorLimits | None = None,
        mode_config: ModeConfig | None = None,
        ipopt_max_iter: int = 200,
    ):
        cfg = config or MpcConfig()
        if cfg.cold_start_iterations != 1:  # the NLP needs no SQP iterations
            from dataclasses import replace

            cfg = replace(cfg, cold_start_iterations=1)
        self.ipopt_max_iter = int(ipopt_max_iter)
        self._opti: ca.Opti | None = None
        super().__init__(params, cfg, limits, mode_config)
        # the NLP is written on eq. 1, 7, 8 alone: the report's model, without the physics of
        # ``extensions:`` the fast path adds (models.plant.plant_extensions), in the delay
        # prediction too, so that both see one model
        self.plant = HybridPlant(params)
        self.delay.lag_s = (0.0, 0.0)
        self._map_as_parameters = False  # eq. 7 in the NLP: constants, or parameters (use_model)

    def use_model(self, model) -> None:
        """:meth:`MpcController.use_model`; the NLP's zone models are per-step parameters
        already, eq. 7's offset and scale become two more (the NLP is built once more, the
        first time, with them as parameters), and the lags stay out as at the start."""
        super().use_model(model)
        self.delay.lag_s = (0.0, 0.0)
        if not self._map_as_parameters:
            self._map_as_parameters = True
            self._opti = None

    # ------------------------------------------------------------- the NLP
    def _build(self) -> None:
        import casadi as ca

        cfg, N, dt, pl = self.config, self.N, self.dt, self.plant
        lim = self.limits
        o = ca.Opti()
        X = o.variable(NX, N + 1)
        U = o.variable(NU, N)
        S = o.variable(NS, N)
        p = {
            "x0": o.parameter(NX),
            "ref": o.parameter(NX, N),
            "nvec": o.parameter(2, N),
            "PT": o.parameter(NX, NX),
            "rN": o.parameter(NX),
            "sw_ff": o.parameter(N),
            "z_off": o.parameter(N),
            "z_scale": o.parameter(N),
            "z_brake": o.parameter(N),
            "u_lo": o.parameter(NU, N),
            "u_hi": o.parameter(NU, N),
            "sr_lo": o.parameter(N),
            "sr_hi": o.parameter(N),
            "prior": o.parameter(NU, 2),
            "w_rate_s": o.parameter(N),
            "u_plan": o.parameter(NU, N),
            "has_plan": o.parameter(),
            "a_prev": o.parameter(),
            "v_lo": o.parameter(N),
            "v_hi": o.parameter(N),
            "w_lo": o.parameter(N),
            "w_hi": o.parameter(N),
        }
        off: float | ca.MX
        sc: float | ca.MX
        b, off, sc = pl.wheelbase_m, pl.offset_rad, pl.scale
        if self._map_as_parameters:
            p["sw_off"], p["sw_scale"] = o.parameter(), o.parameter()
            off, sc = p["sw_off"], p["sw_scale"]

        def f(x, u, k):  # the plant's eq. 1, 7, 8 on CasADi symbols
            xd, yd, psid = bicycle_rates(x[2], x[3], road_wheel_angle(u[0], off, sc), b, ops=ca)
            return ca.vertcat(
                xd,
                yd,
                psid,
                zone_accel(p["z_off"][k], p["z_scale"][k], p["z_brake"][k], u[1], u[2]),
            )

        J: ca.MX | int = 0
        wl, wh, wv = cfg.w_lateral * dt, cfg.w_heading * dt, cfg.w_speed * dt
        o.subject_to(X[:, 0] == p["x0"])
        for k in range(N):
            xk, uk = X[:, k], U[:, k]
            xm = xk + 0.5 * dt * f(xk, uk, k)
            o.subject_to(X[:, k + 1] == xk + dt * f(xm, uk, k))
            r = p["ref"][:, k]
            e_lat = p["nvec"][0, k] * (X[0, k + 1] - r[0]) + p["nvec"][1, k] * (X[1, k + 1] - r[1])
            J += 0.5 * (
                wl * e_lat**2 + wh * (X[2, k + 1] - r[2]) ** 2 + wv * (X[3, k + 1] - r[3]) ** 2
            )
            J += (
                cfg.w_limit_violation * dt * S[0, k]
                + p["w_lo"][k] * S[1, k]
                + p["w_hi"][k] * S[2, k]
                + 0.5 * cfg.w_slack_quadratic * dt * ca.sumsqr(S[:, k])
            )
            o.subject_to(o.bounded(p["u_lo"][:, k], uk, p["u_hi"][:, k]))
            # row 0's bounds already hold the last command (QpConstraints.input_bounds)
            o.subject_to(
                o.bounded(p["sr_lo"][k], uk[0] - U[0, k - 1] if k else uk[0], p["sr_hi"][k])
            )
            a_k = (X[3, k + 1] - X[3, k]) / dt
            o.subject_to(a_k + S[0, k] >= -lim.decel_max_mps2)
            o.subject_to(a_k - S[0, k] <= lim.accel_max_mps2)
            a_km1 = (X[3, k] - X[3, k - 1]) / dt if k else p["a_prev"]
            jd = lim.jerk_max_mps3 * dt
            o.subject_to(a_k - a_km1 + S[0, k] >= -jd)
            o.subject_to(a_k - a_km1 - S[0, k] <= jd)
            o.subject_to(X[3, k + 1] + S[1, k] >= p["v_lo"][k])
            o.subject_to(X[3, k + 1] - S[2, k] <= p["v_hi"][k])
            o.subject_to(S[:, k] >= 0)
        eN = X[:, N] - p["rN"]
        J += 0.5 * ca.mtimes([eN.T, p["PT"], eN])
        J += self._input_cost(U, p)
        o.minimize(J)
        o.solver(
            "ipopt",
            {"print_time": False, "error_on_fail": False, "expand": True},
            {
                "print_level": 0,
                "max_iter": self.ipopt_max_iter,
                "sb": "yes",
                "tol": 1e-6,
                "acceptable_tol": 1e-4,
            },
        )
        self._opti, self._X, self._U, self._S, self._p = o, X, U, S, p

    def _input_cost(self, U, p):
        """The fast path's input cost (``QpCost.input_values`` and the input part of its
        q) as a CasADi expression: rates and rate changes from the inputs before
        the horizon, levels, and the distance from the previous plan."""
        c = self.cost
        w_pr, w_src, w_prc = c.w_pr, c.w_src, c.w_prc
        J = 0
        for k in range(self.N):
            u, u1 = U[:, k], (U[:, k - 1] if k >= 1 else p["prior"][:, 1])
            u2 = U[:, k - 2] if k >= 2 else p["prior"][:, k]  # k=0: u_-2, k=1: u_-1
            d1, d2 = u - u1, u - 2 * u1 + u2
            J += 0.5 * (
                p["w_rate_s"][k] * d1[0] ** 2
                + w_pr * (d1[1] ** 2 + d1[2] ** 2)
                + w_src * d2[0] ** 2
                + w_prc * (d2[1] ** 2 + d2[2] ** 2)
                + c.w_sl * (u[0] - p["sw_ff"][k]) ** 2
                + c.w_pl * (u[1] ** 2 + u[2] ** 2)
            )
            w_re = c.w_replan[k]
            if np.any(w_re > 0):
                J += (
                    0.5
                    * p["has_plan"]
                    * sum(float(w_re[i]) * (u[i] - p["u_plan"][i, k]) ** 2 for i in range(NU))
                )
        return J

    def _solve(self, stage: StageData) -> SolveOutcome:
        """Set the NLP's parameters from ``stage``, warm-start from its nominal, solve."""
        N, L = self.N, self.layout
        if self._opti is None:
            self._build()
        o = self._opti
        assert o is not None  # built above
        self._set_parameters(stage)
        o.set_initial(self._X, stage.states.T)
        o.set_initial(self._U, stage.inputs.T)
        o.set_initial(self._S, np.zeros((NS, N)))
        t0 = time.perf_counter()
        try:
            sol = o.solve_limited()
        except RuntimeError:  # IPOPT gave up: a status for the caller, not an exception
            sol = None
        solve_s = time.perf_counter() - t0
        stats = o.stats()
        out = SolveOutcome(
            None,
            str(stats.get("return_status", "unknown")),
            "ipopt",
            solve_time_s=solve_s,
            iterations=int(stats.get("iter_count", 0)),
        )
        if sol is None or not stats.get("success", False):
            return out
        z = np.zeros(L.n)
        z[: L.nx_all] = np.asarray(sol.value(self._X)).T.ravel()
        z[L.nx_all : L.nx_all + L.nu_all] = np.asarray(sol.value(self._U)).T.ravel()
        z[L.nx_all + L.nu_all :] = np.asarray(sol.value(self._S)).T.ravel()
        if np.all(np.isfinite(z)):
            out.solution = z
        return out

    def _set_parameters(self, stage: StageData) -> None:
        """The NLP's per-step parameters: reference, terminal cost, zone models, bounds."""
        N, pl = self.N, self.plant
        o, p = self._opti, self._p
        assert o is not None  # _solve builds the NLP first
        path, band, zones = stage.path, stage.band, stage.zones
        xr, yr, th, psi_r, v_r = path.x_m, path.y_m, path.heading_rad, path.psi_rad, stage.v_ref_mps
        o.set_value(p["x0"], stage.x0)
        o.set_value(p["ref"], np.vstack([xr[1:], yr[1:], psi_r[1:], v_r[1:]]))
        o.set_value(p["nvec"], np.vstack([-np.sin(th[1:]), np.cos(th[1:])]))
        nx_, ny_ = -np.sin(th[-1]), np.cos(th[-1])
        T = np.array([[nx_, ny_, 0.0, 0.0], [0, 0, 1.0, 0], [0, 0, 0, 1.0]])
        P3 = self.cost.lqr_terminal(
            float(stage.states[-1, 3]), float(path.road_wheel_angle_rad[-1]), self.plant
        )
        o.set_value(p["PT"], T.T @ P3 @ T)
        o.set_value(p["rN"], np.array([xr[-1], yr[-1], psi_r[-1], v_r[-1]]))
        o.set_value(p["sw_ff"], path.steering_ff_rad[:N])
        o.set_value(p["z_off"], pl.z_offset[zones])
        o.set_value(p["z_scale"], pl.z_scale[zones])
        o.set_value(p["z_brake"], pl.z_brake[zones])
        if self._map_as_parameters:
            o.set_value(p["sw_off"], pl.offset_rad)
            o.set_value(p["sw_scale"], pl.scale)
        ulo, uhi, srlo, srhi = self.constraints.input_bounds(
            stage.modes, None, self.delay.fixed, self._last_cmd
        )
        big = 1e4  # IPOPT takes finite bounds: "free" rate rows get a huge band
        o.set_value(p["u_lo"], ulo.T)
        o.set_value(p["u_hi"], uhi.T)
        o.set_value(p["sr_lo"], np.maximum(srlo, -big))
        o.set_value(p["sr_hi"], np.minimum(srhi, big))
        # the fast path's input-cost data: the inputs before the horizon (zero before the
        # first command, as there), the steering rate weight at the nominal speeds, the plan
        prior = self._prior_inputs()
        o.set_value(p["prior"], np.zeros((NU, 2)) if prior is None else prior.T)
        v = np.maximum(stage.states[:N, 3], self.config.steer_sharpness_speed_floor_mps)
        o.set_value(p["w_rate_s"], self.cost.w_sr + self.cost.w_sharp / (v * v))
        o.set_value(p["u_plan"], stage.inputs.T)
        o.set_value(p["has_plan"], 0.0 if self._shift_stages is None else 1.0)
        o.set_value(p["a_prev"], stage.a_prev_mps2)
        o.set_value(p["v_lo"], band.v_lo_mps)
        o.set_value(p["v_hi"], np.minimum(band.v_hi_mps, 1e3))
        o.set_value(p["w_lo"], band.w_lo)
        o.set_value(p["w_hi"], band.w_hi)
