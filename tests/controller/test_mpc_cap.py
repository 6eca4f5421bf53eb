"""The MPC's bounded solve and its model hand-over: OSQP's iteration cap (a capped iterate used
when close, else the previous plan shifted and the next solve continuing from the iterate),
and the plan rewritten for new model values so that it means the same road-wheel angle and
accelerations."""

from __future__ import annotations

from dataclasses import replace
from types import SimpleNamespace

import numpy as np
import pytest

from _data import REPORT_PARAMS
from hmpc.controller.adapt import LearnedModel
from hmpc.controller.mpc import MpcConfig, MpcController
from hmpc.controller.mpc.controller import plan_in_new_model
from hmpc.controller.mpc.cost import replan_fade
from hmpc.models.params import load_params
from hmpc.models.plant import HybridPlant
from test_mpc import drive, drive_from, straight


@pytest.fixture(scope="module")
def params():
    return load_params(REPORT_PARAMS, require_model=True)


def test_a_capped_solve_is_used_when_close_and_otherwise_shifts_the_plan_then_recovers(params):
    ref = straight(5.0, seconds=40.0, v_end=7.0)
    ctl = MpcController(params)
    out = drive(ctl, ref, params, 3.0)
    assert out[-1][2].status == "solved"
    # five iterations and no capped iterate close enough: every warm solve falls back at
    # first, and each continues from the last iterate
    ctl.qp.config = replace(ctl.config, max_iter=5, capped_prim_tol=0.0, capped_dual_tol=0.0)
    later = drive_from(ctl, ref, params, out[-1][1], t0=3.1, seconds=0.5)
    assert later[0][2].status == "shifted_plan" and "maximum iterations" in later[0][2].reason
    assert ctl.qp.iterate is not None  # the next solve starts there
    # the cap with the shipped tolerances: capped iterates are used, marked as such
    ctl.qp.config = replace(ctl.config, max_iter=5)
    more = drive_from(ctl, ref, params, later[-1][1], t0=3.6, seconds=2.0)
    capped = [r for _, _, r in more if r.info and r.info.get("capped")]
    assert capped and all(r.status == "solved_inaccurate" and r.ok for r in capped)
    assert all(r.ok for _, _, r in more)
    assert abs(more[-1][1][3] - float(ref.speed_at(5.6))) < 0.5  # still tracking


def test_a_cold_start_keeps_its_own_cap(params):
    ctl = MpcController(params, MpcConfig(max_iter=1))
    r = ctl.step(straight(5.0).initial_state(params), straight(5.0), 0.0)
    assert r.status == "solved" and r.iterations > 3  # the cold start was not capped


def test_the_warm_cap_follows_the_stage_count_unless_set(params):
    """0 (the default): 50 iterations up to 60 stages, 40 beyond (an iteration costs in
    proportion to the stages); a set ``max_iter`` wins; OSQP is given the cap."""
    assert MpcConfig().warm_iteration_cap == 50  # 0.2 s stages, 50
    assert MpcConfig(horizon_s=12.0).warm_iteration_cap == 50  # 60 stages
    assert MpcConfig(horizon_s=12.2).warm_iteration_cap == 40  # 61
    assert MpcConfig(dt_s=0.1).warm_iteration_cap == 40  # 100
    assert MpcConfig(dt_s=0.1, max_iter=70).warm_iteration_cap == 70
    with pytest.raises(ValueError, match="max_iter"):
        MpcConfig(max_iter=-1)
    ctl = MpcController(params, MpcConfig(dt_s=0.1))
    ref = straight(5.0, seconds=20.0, v_end=7.0)
    out = drive(ctl, ref, params, 1.0)
    assert out[-1][2].ok and ctl.qp.solver.settings.max_iter == 40


def test_a_straight_roads_terminal_costs_are_solved_before_the_first_step(params, monkeypatch):
    """Each terminal cost is a DARE (0.4-1 ms); a straight road's, for every cached speed up
    to the speed limit, are solved when the controller is built, so that a drive that
    speeds up on a straight road solves none in its control steps."""
    import hmpc.controller.mpc.cost as cost_mod

    ctl = MpcController(params)
    calls = []
    real = cost_mod.solve_discrete_are
    monkeypatch.setattr(cost_mod, "solve_discrete_are", lambda *a: calls.append(a) or real(*a))
    out = drive(ctl, straight(3.0, seconds=30.0, v_end=15.0), params, 6.0)
    assert out[-1][1][3] > 5.0 and all(r.ok for _, _, r in out)  # it sped up
    assert not calls
    # a curve's are solved on first use
    ctl.cost.lqr_terminal(5.0, 0.1, ctl.plant)
    assert len(calls) == 1


def test_the_plan_rewritten_for_new_values_means_the_same_angle_and_accelerations(params):
    ref = straight(3.0, seconds=30.0, v_end=7.0)
    ctl = MpcController(params)
    drive(ctl, ref, params, 4.0)
    plan = ctl._plan
    pl = HybridPlant(params)
    z = plan.zones
    model = LearnedModel(
        offset_rad=0.005,
        scale=0.095,
        zone_offset_mps2=tuple(o + 0.05 for o in pl.z_offset),
        zone_scale_mps2=tuple(0.8 * s for s in pl.z_scale),
        zone_brake_mps2=tuple(1.2 * b for b in pl.z_brake),
        steer_delay_s=0.0,
        long_delay_s=0.0,
        steer_lag_s=0.0,
        long_lag_s=0.0,
    )
    U0, U1 = plan.inputs, plan_in_new_model(plan, pl, model)
    np.testing.assert_allclose(
        0.005 + 0.095 * U1[:, 0], pl.offset_rad + pl.scale * U0[:, 0], atol=1e-12
    )
    acc0 = pl.z_offset[z] + pl.z_scale[z] * U0[:, 1] - pl.z_brake[z] * U0[:, 2]
    acc1 = (
        np.array(model.zone_offset_mps2)[z]
        + np.array(model.zone_scale_mps2)[z] * U1[:, 1]
        - np.array(model.zone_brake_mps2)[z] * U1[:, 2]
    )
    free = np.where(plan.modes == 0, U1[:, 1], U1[:, 2])  # the stage's free pedal
    inside = (free > 0) & (free < 1)  # pressed, not clipped
    assert inside.sum() > 10
    np.testing.assert_allclose(acc1[inside], acc0[inside], atol=1e-9)
    assert ((U1[:, 1:] > 0) == (U0[:, 1:] > 0)).all()  # the same pedals pressed
    # the controller does it on a hand-over, and the next step solves from there
    want = plan_in_new_model(plan, ctl.plant, model)
    ctl.use_model(model)
    np.testing.assert_array_equal(ctl._plan.inputs, want)
    np.testing.assert_allclose(want, U1, atol=1e-6)


def test_the_replan_fade_has_no_step_and_the_window_s_sum():
    w = replan_fade(1.0, 0.1, 100)
    assert w[0] == 1.0 and w[10] == pytest.approx(0.5) and (w[20:] == 0).all()
    assert np.all(np.diff(w) <= 1e-12) and np.max(np.abs(np.diff(w))) < 0.1
    assert w.sum() * 0.1 == pytest.approx(1.0, abs=0.06)


def test_offset_free_steering_follows_the_estimators_correction_only_when_straight(params):
    """``use_steering_correction``: the estimator's correction reaches the model's steering
    offset through a first-order lag of ``steer_correction_tau_s`` while the last command
    steers straight; it is held while the command turns, off with tau 0, and a reset or a
    learned model keeps the model's own offset apart from it."""
    ref = straight(3.0, seconds=30.0, v_end=3.0)
    ctl = MpcController(params)
    off0 = ctl.plant.offset_rad
    out = drive(ctl, ref, params, 1.0)
    t = out[-1][0]
    assert abs(ctl._offset_model + ctl.plant.scale * ctl._last_cmd.steering_wheel_angle_rad) < 0.02
    ctl.use_steering_correction(0.01, t)  # the first call after a reset sets the clock only
    ctl.use_steering_correction(0.01, t + 3.0)  # one time constant later
    assert ctl.plant.offset_rad - off0 == pytest.approx(0.01 * (1 - np.exp(-1.0)), rel=1e-12)
    held = ctl.plant.offset_rad
    ctl._last_cmd = replace(ctl._last_cmd, steering_wheel_angle_rad=0.5)  # turning
    ctl.use_steering_correction(0.05, t + 6.0)
    assert ctl.plant.offset_rad == held
    ctl.use_steering_correction(float("nan"), t + 9.0)
    assert ctl.plant.offset_rad == held
    # a learned model moves the model's offset; the correction stays on top of it
    corr = held - off0
    pl = ctl.plant
    ctl.use_model(
        LearnedModel(
            offset_rad=off0 + 0.002,
            scale=pl.scale,
            zone_offset_mps2=tuple(pl.z_offset),
            zone_scale_mps2=tuple(pl.z_scale),
            zone_brake_mps2=tuple(pl.z_brake),
            steer_delay_s=0.0,
            long_delay_s=0.0,
            steer_lag_s=0.0,
            long_lag_s=0.0,
        )
    )
    assert ctl.plant.offset_rad == pytest.approx(off0 + 0.002 + corr, abs=1e-15)
    assert ctl.params.steering.offset_rad == off0 + 0.002
    # a steering extension (here: a stand-in saying the model has one): nothing is taken
    ext, ctl.plant.ext = ctl.plant.ext, SimpleNamespace(steering=True)
    ctl._last_cmd = replace(ctl._last_cmd, steering_wheel_angle_rad=0.0)
    before = ctl.plant.offset_rad
    ctl.use_steering_correction(0.05, t + 12.0)
    ctl.use_steering_correction(0.05, t + 15.0)
    assert ctl.plant.offset_rad == before
    ctl.plant.ext = ext
    ctl.reset()
    assert ctl._steer_corr == 0.0 and ctl.plant.offset_rad == ctl._offset_model
    off = MpcController(params, MpcConfig(steer_correction_tau_s=0.0))
    drive(off, ref, params, 1.0)
    off.use_steering_correction(0.01, 1.0)
    off.use_steering_correction(0.01, 10.0)
    assert off.plant.offset_rad == off0
