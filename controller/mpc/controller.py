"""Hybrid-mode MPC, fast path: an OSQP linear time-varying QP (report section VI).

Prediction model: the hybrid plant (models/plant.py): kinematic bicycle (eq. 1), steering
map (eq. 7), one linear accelerator model per speed zone (eq. 8, with brake). Every step
:class:`MpcController` ties the package's parts together:

1. **Delay compensation** (controller/mpc/delay.py). The state is predicted forward through
   the commands still in flight (``steering.dead_time_s``, ``longitudinal.dead_time_s``,
   an ``actuator_lag``): the QP starts where the car will be when this step's command takes
   effect.
2. **Schedules.** Along the horizon, the zone of each stage follows the speed profile of
   the previous solution (with the plant's hysteresis, controller/mpc/zone_rules.py), and
   each stage gets ONE free pedal (controller/modes.py): within one QP throttle and brake
   are never both free.
3. **Re-linearisation** of eq. 1 about the previous solution (shifted in time),
   discretised (2nd order), the zone's eq. 8 per stage (controller/mpc/constraints.py). The
   QP's sparsity pattern is built ONCE (controller/mpc/qp.py); each step writes new values
   in place and warm-starts from the previous solution (primal and dual, shifted in time).
4. **Costs** (controller/mpc/cost.py): tracking, effort (velocity above steering, report
   VI), smoothness, the dlqr terminal cost, the soft limits' penalties, and the report's
   two ways to stay in the most accurate zone (VI): the minimum-speed floor and the
   zone-transition penalty (controller/mpc/zone_rules.py). Tuning: controller/mpc/config.py.
5. **Constraints** (controller/mpc/constraints.py): steering angle and rate; pedals in
   [0, 1], one free per stage; acceleration limits as bounds on the free pedal.
6. **Idle speed**: the pedal mode logic (hysteresis about the zone's coast acceleration,
   minimum dwell) and the standstill HOLD mode keep the brake in charge below the idle
   speed, so holding 1 m/s against idle creep does not chatter.
7. **Failures**: a step never raises and never returns None. On a solver failure or
   time-out the previous plan is shifted and followed; when it has run out, a controlled
   stop (brake ramp, steering held). An unexpected exception (a bug, not a solver failure)
   is an internal error: the plan is dropped, a controlled stop begins and the result
   carries the traceback. The status (controller/base.py ``Status``) says which, and
   ``reason`` why.
8. **Offset-free steering** (:meth:`MpcController.use_steering_correction`): without a
   learner, the estimator's correction to eq. 7's road-wheel angle, low-passed and taken in
   while the car steers straight, is added to the model's steering offset, so that a file
   with a wrong straight-ahead angle does not hold the car beside a straight path.

The step RETURNS a command; it never sends it. Every command goes through
``controller.limits.apply_limits`` before it is returned. The model's physics (eq. 1, 7, 8,
the zone rule) is models/plant.py's; this package only discretises it.
"""

from __future__ import annotations

import math
import time
from dataclasses import replace

import numpy as np

from hmpc.models.params import Params
from hmpc.models.plant import HybridPlant
from hmpc.models.reference import Reference

from hmpc.controller.base import ControlResult, Status, internal_error
from hmpc.controller.horizon import Plan, SolveOutcome, StageData, path_reference, speed_reference
from hmpc.controller.limits import ActuatorLimits, Command, apply_limits
from hmpc.controller.modes import (
    PEDAL_RELEASED,
    ModeConfig,
    PedalMode,
    PedalModeLogic,
    StandstillLogic,
    desired_accel,
)
from hmpc.controller.mpc.config import MpcConfig
from hmpc.controller.mpc.constraints import QpConstraints, linearise
from hmpc.controller.mpc.cost import QpCost
from hmpc.controller.mpc.delay import DelayCompensation
from hmpc.controller.mpc.qp import NU, NX, QpLayout, QpSolver
from hmpc.controller.mpc.zone_rules import ZoneRules

_THROTTLE, _BRAKE = int(PedalMode.THROTTLE), int(PedalMode.BRAKE)
#: [1] relative change of the steering scale after which the terminal cost's cache (dlqr per
#: speed and road-wheel angle, a function of the scale) is recomputed: below it the terminal
#: weight differs by less than the cache's own speed and angle rounding moves it
LQR_SCALE_TOL = 0.02
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


def plan_in_new_model(plan: Plan, plant: HybridPlant, model) -> np.ndarray:
    """The plan's inputs (N, 3) rewritten for new model values (``model``: a
    ``controller.adapt.LearnedModel``) so that they do what the plan meant under ``plant``'s
    current values: the same road-wheel angle (eq. 7's linear map) and, per stage, the same
    acceleration from the stage's free pedal in its zone (eq. 8). The plan is the previous
    solution the next QP is warm-started from and its first stages are held to (the replan
    term): in the old model's pedal and steering-wheel units it would hold the car to what the
    new model says is a different acceleration and road-wheel angle, and the learned
    correction would reach the commands only as fast as the replan term lets the plan move."""
    U = plan.inputs.copy()
    sc_new = float(model.scale)
    if abs(sc_new) > 1e-9:
        delta = plant.offset_rad + plant.scale * U[:, 0]
        U[:, 0] = (delta - float(model.offset_rad)) / sc_new
    z = np.asarray(plan.zones, dtype=np.int64)
    off, sc, br = plant.z_offset[z], plant.z_scale[z], plant.z_brake[z]
    off_n = np.asarray(model.zone_offset_mps2, dtype=float)[z]
    sc_n = np.maximum(np.asarray(model.zone_scale_mps2, dtype=float)[z], 1e-6)
    br_n = np.maximum(np.asarray(model.zone_brake_mps2, dtype=float)[z], 1e-6)
    acc = off + sc * U[:, 1] - br * U[:, 2]
    # the stage's free pedal (its pedal mode) carries the change, when pressed
    free_thr = np.asarray(plan.modes) == _THROTTLE
    thr, brk = free_thr & (U[:, 1] > 0.0), ~free_thr & (U[:, 2] > 0.0)
    U[thr, 1] = np.clip((acc[thr] - off_n[thr] + br_n[thr] * U[thr, 2]) / sc_n[thr], 0.0, 1.0)
    U[brk, 2] = np.clip((off_n[brk] + sc_n[brk] * U[brk, 1] - acc[brk]) / br_n[brk], 0.0, 1.0)
    return U


class MpcController:
    """The OSQP fast path. ``step`` returns a :class:`ControlResult`; see the module doc.

    Args:
        params: the model the controller believes (a complete parameter file).
        config: tuning (:class:`MpcConfig`).
        limits: actuator/comfort limits (default: from ``params``).
        mode_config: pedal/standstill mode logic tuning.

    Its parts: ``delay`` (:class:`DelayCompensation`: the commands issued, the inputs in
    flight), ``zone_rules`` (:class:`ZoneRules`), ``layout`` (:class:`QpLayout`), ``cost``
    (:class:`QpCost`), ``constraints`` (:class:`QpConstraints`) and ``qp``
    (:class:`QpSolver`: OSQP and its warm start).
    """

    name = "mpc"
    #: the last good solution (None after :meth:`reset`)
    _plan: Plan | None
    #: the time of the offset-free steering's last update (None after :meth:`reset`)
    _steer_corr_t: float | None

    def __init__(
        self,
        params: Params,
        config: MpcConfig | None = None,
        limits: ActuatorLimits | None = None,
        mode_config: ModeConfig | None = None,
    ):
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
        self.layout = QpLayout(self.N, self.dt)
        self.zone_rules = ZoneRules(params, self.config, self.mode_config, self.limits, self.plant)
        self.delay = DelayCompensation(params, self.plant, self.dt, self.N)
        self.cost = QpCost(self.config, self.limits, self.layout)
        self.cost.warm_terminal(self.plant, self.limits.speed_max_mps)
        self.constraints = QpConstraints(self.layout, self.limits, self.plant)
        self.qp = QpSolver(self.layout, self.config)
        self._pedal = PedalModeLogic(self.mode_config)
        self._standstill = StandstillLogic(self.mode_config)
        self._t_stages = self.dt * np.arange(self.N + 1)  # stage times from stage 0 [s]
        # eq. 7's offset of the model (the file's, or the learner's): the plant's offset is
        # this plus the offset-free steering's correction (use_steering_correction)
        self._offset_model = float(self.plant.offset_rad)
        self.reset()

    @property
    def floor_mps(self) -> float:
        """The minimum-speed floor [m/s] (:class:`ZoneRules`; 0: none)."""
        return self.zone_rules.floor_mps

    @property
    def lag_method(self) -> str:
        """How an ``actuator_lag`` is handled (:attr:`DelayCompensation.lag_method`)."""
        return self.delay.lag_method

    def use_lag_method(self, method: str) -> None:
        """Choose how an ``actuator_lag`` is handled (``lag_method``) before the first step."""
        self.delay.use_lag_method(method)

    def use_model(self, model) -> None:
        """Predict with new model values from now on (the online model estimator's
        ``controller.adapt.LearnedModel``: eq. 7's offset and scale, eq. 8 per zone, the dead
        times and lags). Values only: the QP's pattern and the warm start stay, and the plan
        stays with its inputs rewritten for the new values (:func:`plan_in_new_model`); the
        prediction model's coefficients are written in place, the pedal bounds that derive
        from them recomputed, the terminal cost's cache dropped when the steering scale moved
        (it is a function of the scale), and the zones the limits read replaced."""
        pl = self.plant
        if abs(model.scale - pl.scale) > LQR_SCALE_TOL * abs(pl.scale):
            self.cost._lqr_cache.clear()
        if self._plan is not None:
            self._plan = replace(self._plan, inputs=plan_in_new_model(self._plan, pl, model))
        self._offset_model = float(model.offset_rad)
        pl.offset_rad, pl.scale = self._offset_model + self._steer_corr, float(model.scale)
        pl.z_offset[:] = model.zone_offset_mps2
        pl.z_scale[:] = model.zone_scale_mps2
        pl.z_brake[:] = model.zone_brake_mps2
        pl._eq8[:] = zip(pl.z_offset.tolist(), pl.z_scale.tolist(), pl.z_brake.tolist())
        self.constraints.use_zone_models(pl)
        self.delay.use_timing(
            model.steer_delay_s, model.long_delay_s, model.steer_lag_s, model.long_lag_s
        )
        if not getattr(self, "_own_model", False):  # the caller's file is never written to
            p = self.params
            assert p.steering is not None
            self.params = replace(
                p, steering=replace(p.steering), zones=[replace(z) for z in p.zones]
            )
            self._own_model = True
        assert self.params.steering is not None
        self.params.steering.offset_rad = self._offset_model
        self.params.steering.scale = pl.scale
        for z, o, s, b in zip(
            self.params.zones, model.zone_offset_mps2, model.zone_scale_mps2, model.zone_brake_mps2
        ):
            z.offset_mps2, z.scale_mps2, z.brake_scale_mps2 = o, s, b

    def use_steering_correction(self, delta_rad: float, t_s: float) -> None:
        """Offset-free steering: the estimator's correction to eq. 7's road-wheel angle
        (``Estimator.steering_correction_rad``) at ``t_s`` [s], low-passed
        (``config.steer_correction_tau_s``), is added to the model's steering offset. Taken
        in only while the last command steers straight by the model (within
        ``config.steer_correction_gate_rad``), held otherwise, and not at all when the model
        has a steering extension; the loops call it every control step before :meth:`step`
        when no learner runs (a learner takes the offset itself)."""
        tau = self.config.steer_correction_tau_s
        ext = self.plant.ext
        if tau <= 0 or not math.isfinite(delta_rad) or (ext is not None and ext.steering):
            # a steering extension (rack nonlinearity, understeer) gives eq. 7 another shape,
            # which the estimator's eq. 7 lacks: its correction then holds that shape's
            # residual from the last curve, not an offset
            return
        t_prev, self._steer_corr_t = self._steer_corr_t, float(t_s)
        prev, pl = self._last_cmd, self.plant
        if t_prev is None or prev is None:
            return
        delta_cmd = self._offset_model + pl.scale * prev.steering_wheel_angle_rad
        if not abs(delta_cmd) < self.config.steer_correction_gate_rad:
            return
        gain = 1.0 - math.exp(-max(float(t_s) - t_prev, 0.0) / tau)
        self._steer_corr += gain * (float(delta_rad) - self._steer_corr)
        pl.offset_rad = self._offset_model + self._steer_corr

    # ----------------------------------------------------------------- state
    def reset(self) -> None:
        """Forget the plan, the history, the modes and the steering correction (a new
        run)."""
        self._steer_corr = 0.0  # the offset-free steering's correction [rad]
        self._steer_corr_t = None
        self.plant.offset_rad = self._offset_model
        self._plan = None  # the last good solution
        self._last_cmd: Command | None = None
        self._last_t: float | None = None
        self._zone: int | None = None
        self._s_prog: float | None = None
        self._pedal.reset()
        self._standstill.reset()
        self.delay.reset()  # the commands issued, the inputs in flight
        self.qp.forget()  # the warm start
        # stages elapsed since that solution's first stage (None: no plan to shift)
        self._shift_stages: float | None = None

    # ------------------------------------------------------------------ step
    def step(
        self,
        state,
        reference: Reference,
        t_s: float,
        *,
        stop: bool = False,
        obstacle_distance_m: float | None = None,
    ) -> ControlResult:
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
    def _finish(
        self,
        cmd: Command,
        t_s: float,
        zone: int,
        *,
        controlled_stop: bool = False,
        plan_inputs: np.ndarray | None = None,
    ) -> Command:
        """The command through ``apply_limits``, recorded; with ``plan_inputs`` (the QP's
        inputs, the lags' outputs) and an actuator lag, first its inverse
        (:meth:`DelayCompensation.command`)."""
        dt = self.dt if self._last_t is None else max(t_s - self._last_t, 1e-3)
        if plan_inputs is not None and self.delay.lag_act is not None:
            cmd = self.delay.command(cmd, plan_inputs, zone, self.plant)
        z = self.params.zones[zone]
        out = apply_limits(
            cmd, self._last_cmd, self.limits, dt, zone=z, controlled_stop=controlled_stop
        )
        self._last_cmd = out
        self._last_t = t_s
        self.delay.history.append((t_s, out))
        return out

    def _fallback(self, t_s: float, reason: str) -> ControlResult:
        """Shift the previous plan; when none remains, a controlled stop."""
        zone = self._zone if self._zone is not None else 0
        plan = self._plan
        if plan is not None:
            k = int(math.floor((t_s - plan.t0_s) / self.dt + 1e-9))
            k_s, k_l = self.delay.fixed.steer_stages, self.delay.fixed.pedal_stages
            if 0 <= k and k + max(k_s, k_l) < self.N - 1:
                U = plan.inputs
                sw, ap, bp = U[k + k_s, 0], U[k + k_l, 1], U[k + k_l, 2]
                cmd = self._finish(Command(float(sw), float(ap), float(bp)), t_s, zone)
                return ControlResult(
                    cmd,
                    Status.SHIFTED_PLAN,
                    reason,
                    plan=plan.states,
                    plan_inputs=U,
                    zone_plan=plan.zones,
                    mode_plan=plan.modes,
                    zone=zone,
                    pedal_mode=int(plan.modes[k]),
                )
            self._plan = None
        return self._controlled_stop(t_s, reason, zone)

    def _stop_after_error(self, t_s) -> ControlResult:
        """The command after an unexpected exception: the plan and warm start are dropped
        (what raised may have left them half-written) and a controlled stop begins. Should
        that raise too, the last resort: throttle released, brake pressed at its rate limit,
        steering held (``apply_limits`` on a non-finite command)."""
        self._plan = None
        self.qp.forget()
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
        target = min(
            1.0,
            max(z.offset_mps2 + self.config.stop_brake_decel_mps2, 0.0)
            / max(z.brake_scale_mps2, 1e-6),
        )
        ramp = self.limits.jerk_max_mps3 / max(z.brake_scale_mps2, 1e-6) * dt
        bp0 = prev.brake_pedal if prev is not None else 0.0
        bp = min(target, bp0 + ramp) if bp0 < target else bp0
        sw = prev.steering_wheel_angle_rad if prev is not None else 0.0
        cmd = self._finish(Command(sw, 0.0, bp), t_s, zone, controlled_stop=True)
        return ControlResult(
            cmd, Status.CONTROLLED_STOP, reason, zone=zone, pedal_mode=int(PedalMode.BRAKE)
        )

    def _step(
        self, x_meas: np.ndarray, ref: Reference, t: float, stop: bool, obstacle_m: float | None
    ) -> ControlResult:
        """One step in named stages: delay compensation, standstill hold, path progress,
        nominal trajectory, then the SQP iterations (one when warm) of
        :meth:`_stage_data` + :meth:`_solve`."""
        cfg, L, N, pl = self.config, self.layout, self.N, self.plant
        x0, d = self.delay.predict(x_meas, t, self._zone, self._last_cmd, self.plant)
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
        total_solve, total_update, total_it, total_cpu = 0.0, 0.0, 0, 0.0
        first = None
        for it in range(iters):
            stage, first = self._stage_data(
                x0,
                Xb,
                Ub,
                a_prev,
                ref,
                tk,
                s0,
                zone0,
                v_mode,
                t,
                cold=cold,
                seed_guess=cold and it == 0,
                first=first,
                stop=stop,
                obstacle_m=obstacle_m,
                override=override,
            )
            out = self._solve(stage)
            total_solve += out.solve_time_s
            total_update += out.update_time_s
            total_it += out.iterations
            total_cpu += out.solve_cpu_s
            if out.solution is None:
                break
            sol = out.solution
            Xb = sol[: L.nx_all].reshape(N + 1, NX).copy()
            Ub = sol[L.nx_all : L.nx_all + L.nu_all].reshape(N, NU).copy()

        if out.solution is None:
            res = self._fallback(t, out.reason)
            res.solve_time_s, res.iterations = total_solve, total_it
            return res
        self.qp.warm = (out.solution, self.qp.last_y)
        # each channel's command is the QP input at the stage where it will act; the QP's
        # bounds make the non-free pedal exactly 0 (clean solver round-off)
        k_s, k_l = self.delay.fixed.steer_stages, self.delay.fixed.pedal_stages
        modes, zones = stage.modes, stage.zones
        mode_l = int(modes[k_l])  # plain ints: comparing NumPy values with an IntEnum is slow
        ap = float(Ub[k_l, 1]) if mode_l == _THROTTLE else 0.0
        bp = float(Ub[k_l, 2]) if mode_l == _BRAKE else 0.0
        cmd = self._finish(Command(float(Ub[k_s, 0]), ap, bp), t, zone0, plan_inputs=Ub)
        self._plan = Plan(float(tk[0]), Xb, Ub, zones, modes)
        status = Status.SOLVED_INACCURATE if out.inaccurate else Status.SOLVED
        return ControlResult(
            cmd,
            status,
            solve_time_s=total_solve,
            plan=Xb,
            plan_inputs=Ub,
            zone_plan=zones,
            mode_plan=modes,
            zone=zone0,
            pedal_mode=mode_l,
            iterations=total_it,
            info={
                "v_ref_mps": stage.v_ref_mps,
                "s0_m": s0,
                "update_time_s": total_update,
                "capped": out.capped,
                "solve_cpu_s": total_cpu,
            },
        )

    def _standstill_hold(
        self,
        x_meas: np.ndarray,
        ref: Reference,
        t: float,
        d: float,
        stop: bool,
        obstacle_m: float | None,
        zone0: int,
    ) -> ControlResult | None:
        """Standstill HOLD (mode logic; no QP needed while the car is held): the result of
        this step if the car is held, else None."""
        cfg = self.config
        look = ref.speed_at(_linspace6(t, t + d + self.mode_config.hold_lookahead_s))
        stop_now = stop or (obstacle_m is not None and obstacle_m <= cfg.obstacle_margin_m)
        if not self._standstill.update(float(x_meas[3]), float(look.max()), stop_now):
            return None
        self._pedal.hold(t)
        self._plan = None
        self.qp.forget()
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
            self._s_prog = ref.project(float(x_meas[0]), float(x_meas[1]), self._s_prog, 5.0)[0]
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

    def _nominal(
        self, x0: np.ndarray, ref: Reference, tk: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, float]:
        """Nominal trajectory (states, inputs) and the acceleration before stage 0: the
        previous plan shifted in time to the stage times ``tk``, or without one a cold
        guess (a speed ramp towards the reference; ``horizon.path_reference`` puts it on
        the path). Sets the warm start's shift."""
        N, dt, L = self.N, self.dt, self.layout
        plan = self._plan
        if plan is not None:
            # now's stage times are the plan's moved by ``sh`` stages: each state and input
            # interpolated linearly between the plan's stages, its first and last held beyond
            Xp, Up = plan.states, plan.inputs
            sh = (float(tk[0]) - plan.t0_s) / dt
            z = L.nominal_shift(np.concatenate((Xp.ravel(), Up.ravel())), sh)
            Xb = z[: L.nx_all].reshape(N + 1, NX)
            Ub = z[L.nx_all :].reshape(N, NU)
            tp = plan.t0_s + self._t_stages[:N]
            a_prev = float(np.interp(tk[0], tp, np.diff(Xp[:, 3]) / dt))
            self._shift_stages = sh
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

    def _stage_data(
        self,
        x0,
        Xb,
        Ub,
        a_prev,
        ref,
        tk,
        s0,
        zone0,
        v_mode,
        t,
        *,
        cold,
        seed_guess,
        first,
        stop,
        obstacle_m,
        override,
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
        cfg = self.config
        path = path_reference(
            ref, s_k, Xb, Ub, x0, seed_guess, self.plant, self.limits.steering_wheel_angle_max_rad
        )
        v_r = speed_reference(
            ref,
            tk,
            float(x0[3]),
            stop,
            obstacle_m,
            s_k - s0,
            cfg.stop_decel_mps2,
            cfg.obstacle_margin_m,
        )
        zones = self.zone_rules.schedule(zone0, vb)
        modes, first = self._pedal_modes(v_r, vb, v_mode, zones, Ub, t, cold, first)
        band = self.zone_rules.speed_band(zone0, v_r, override)
        return StageData(x0, Xb, Ub, zones, modes, path, v_r, band, a_prev), first

    def _pedal_modes(
        self,
        v_r: np.ndarray,
        vb: np.ndarray,
        v_mode: float,
        zones: np.ndarray,
        Ub: np.ndarray,
        t: float,
        cold: bool,
        first: PedalMode | None,
    ) -> tuple[np.ndarray, PedalMode]:
        """Pedal mode per stage, one free pedal each (controller/modes.py); the stages
        whose pedals are in flight keep theirs. Returns (modes, mode of the first free
        stage), that mode decided here when ``first`` is None."""
        N, dt = self.N, self.dt
        fixed = self.delay.fixed
        k_l = fixed.pedal_stages
        vb_mode = vb.copy()
        vb_mode[0] = v_mode  # the switching signal is filtered; the QP is not
        a_des = desired_accel(v_r, vb_mode, dt, self.mode_config.error_time_constant_s)
        coast = self.plant.z_offset[zones]
        if first is None:
            exhausted = True
            cur = self._pedal.mode
            if not cold and cur in (PedalMode.THROTTLE, PedalMode.BRAKE):
                k_ex = max(int(round(self.mode_config.exhausted_lookahead_s / dt)), 1)
                exhausted = bool((Ub[k_l : k_l + k_ex, 1 + int(cur)] <= PEDAL_RELEASED).all())
            first = self._pedal.first(float(a_des[k_l]), float(coast[k_l]), t, exhausted)
        modes = np.empty(N, dtype=np.int8)
        modes[k_l:] = self._pedal.schedule(
            first,
            a_des[k_l:],
            coast[k_l:],
            dt,
            self._pedal.since_switch_s(t),
            None if cold else Ub[k_l:, 1:],
        )
        if k_l:  # pedals in flight: their own modes
            modes[:k_l] = np.where(fixed.pedals[:, 0] > 0, PedalMode.THROTTLE, PedalMode.BRAKE)
        return modes, first

    def _solve(self, stage: StageData) -> SolveOutcome:
        """One QP about the nominal of ``stage``: linearise and discretise, write the new
        values into the fixed pattern, solve (warm-started)."""
        Ad, Bd, ck = linearise(self.plant, stage.states, stage.inputs, stage.zones, self.dt)
        Pdata, q = self.cost.values(
            stage, self.plant, self._shift_stages is not None, self._prior_inputs()
        )
        Adata = self.constraints.dynamics_values(Ad, Bd)
        lo, hi = self.constraints.row_bounds(stage, ck, self.delay.fixed, self._last_cmd)
        return self.qp.solve(
            Pdata, q, Adata, lo, hi, stage.states, stage.inputs, self._shift_stages
        )

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
            tp = plan.t0_s + self._t_stages[: self.N]
            k = min(max(int(np.searchsorted(tp, self._last_t + self.dt)), 1), self.N - 1)
            out[0] = out[1] - (plan.inputs[k] - plan.inputs[k - 1])
        return out
