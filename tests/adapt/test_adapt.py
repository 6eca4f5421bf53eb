"""The online model estimator's parts (controller/adapt), each against a known truth: the
parameter filter (held directions, gate, widening, bounds, drift capped at the prior), the
sensor checks (spikes, a frozen wheel), the dead-time and lag fit, straight driving (the offset
learns, the scale holds), the learned file (round trip, another vehicle refused, nothing hmpc
would refuse is written) and the hand-over to the MPC and the state estimator."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from _data import REPORT_PARAMS
from hmpc.controller.adapt import AdaptConfig, LearnedModel, ModelAdapter
from hmpc.controller.adapt.learned import learned_params, restore, save_learned
from hmpc.controller.adapt.paramfilter import ParamFilter
from hmpc.controller.adapt.signals import PeriodSignals
from hmpc.controller.adapt.timing import ResponseFit
from hmpc.controller.estimator import IDOFF, Estimator
from hmpc.controller.mpc import MpcController
from hmpc.models.errors import InputError, ParamError
from hmpc.models.params import load_params


@pytest.fixture(scope="module")
def params():
    return load_params(REPORT_PARAMS)


def _filter(**kw):
    a = dict(
        theta0=[0.0, 1.0],
        sigma0=[1.0, 1.0],
        walk_per_rts=[0.0, 0.0],
        lo=[-10, 0.1],
        hi=[10, 10],
        gate_chi2=10.83,
        widen_after=20,
    )
    a.update(kw)
    return ParamFilter(**a)


def test_filter_learns_a_line_and_a_held_parameter_stays_put():
    rng = np.random.default_rng(1)
    f = _filter()
    for x in rng.uniform(-2, 2, 400):
        f.update([1.0, x], 0.3 + 1.5 * x + 0.01 * rng.standard_normal(), 1e-4, [True, True])
    assert f.theta[0] == pytest.approx(0.3, abs=3e-3) and f.theta[1] == pytest.approx(1.5, abs=3e-3)
    # the slope held at 1.0 with the regressor far from zero: the offset is the conditional
    # least-squares value y - 1.0 x (not a split of the error), the slope does not move and its
    # variance does not shrink
    g = _filter()
    for x in rng.uniform(-0.35, -0.30, 400):
        g.update([1.0, x], 0.3 + 1.5 * x + 0.001 * rng.standard_normal(), 1e-6, [True, False])
    assert g.theta[1] == 1.0 and g.P[1][1] == pytest.approx(1.0)
    assert g.theta[0] == pytest.approx(0.3 + 0.5 * -0.325, abs=0.01)
    # ... and a later update of the slope moves the offset with it (the kept correlation)
    for x in rng.uniform(-2, 2, 200):
        g.update([1.0, x], 0.3 + 1.5 * x, 1e-6, [True, True])
    assert g.theta == pytest.approx([0.3, 1.5], abs=2e-3)


def test_filter_gates_an_outlier_widens_on_a_real_change_and_clamps_at_its_bound():
    f = _filter()
    for x in np.linspace(-1, 1, 100):
        f.update([1.0, x], 2.0 * x, 1e-4, [True, True])
    before = list(f.theta)
    assert not f.update([1.0, 0.5], 50.0, 1e-4, [True, True])  # a spike: gated out
    assert f.theta == before and f.rejected == 1
    # the car changed for real: after ``widen_after`` rejections the filter re-learns
    for x in np.tile(np.linspace(-1, 1, 11), 6):
        f.update([1.0, x], 5.0 + 2.0 * x, 1e-4, [True, True])
    assert f.widened == 1 and f.theta[0] == pytest.approx(5.0, abs=0.05)
    h = _filter(lo=[-1.0, 0.5], hi=[1.0, 2.0])
    for x in np.linspace(-1, 1, 50):
        h.update([1.0, x], 9.0 * x, 1e-2, [True, True])
    assert h.theta[1] == 2.0 and h.at_bound[1]


def test_filter_drift_never_winds_up_beyond_the_prior():
    f = _filter(walk_per_rts=[0.1, 0.1])
    for x in np.linspace(-1, 1, 50):
        f.update([1.0, x], x, 1e-4, [True, True])
    assert f.P[1][1] < 1e-3
    f.drift(1e6)  # days without excitation
    assert f.P[0][0] == pytest.approx(1.0) and f.P[1][1] == pytest.approx(1.0)
    assert np.all(np.linalg.eigvalsh(np.array(f.P)) >= -1e-12)


def test_signals_drop_a_spike_follow_a_step_and_flag_a_frozen_wheel():
    s = PeriodSignals(AdaptConfig(), 1.6)
    for k in range(10):
        s.add_yaw(k * 0.01, 0.10)
    s.add_yaw(0.1, 1.10)  # one spike
    assert s.spikes["yaw_rate"] == 1 and s.sum_yaw / s.n_yaw == pytest.approx(0.1)
    for k in range(10):  # a real step
        s.add_yaw(0.2 + k * 0.01, 0.5)
    assert s._yaw_last == 0.5
    s.add_can(1.0, (5.0, 5.0, 5.0, 5.0))
    assert not s.suspect(1.0)
    s.add_can(1.1, (3.0, 5.4, 5.4, 5.4))  # front-left stuck at an old speed
    assert s.suspect(1.1) and s.suspect(2.0) and not s.suspect(2.2) and s.wheel_faults == 1


def test_response_fit_finds_a_known_dead_time_and_lag():
    cfg = AdaptConfig()
    T = 0.1
    fit = ResponseFit(cfg, T, (0.2, 0.2))
    rng = np.random.default_rng(3)
    cmds = np.repeat(rng.uniform(-1, 1, 60), 8)  # steps every 0.8 s
    # truth: 0.2 s dead time, 0.3 s lag, simulated finely (1 ms) and averaged per period
    d, tau, h = 0.2, 0.3, 0.001
    e, ys = 0.0, []
    for k in range(len(cmds)):
        acc = 0.0
        for j in range(100):
            t = k * T + j * h
            u = cmds[int(math.floor((t - d) / T))] if t >= d else cmds[0]
            e += (u - e) * (1 - math.exp(-h / tau))
            acc += e
        ys.append(acc / 100)
    for k in range(len(cmds)):
        fit.command(k * T, (cmds[k], cmds[k]))
        fit.advance()
        fit.weight[:] = 1.0
        fit.y[:] = (0.3 + 2.0 * ys[k], 0.0)  # a gain and an offset too
        fit.add((k + 1) * T)
    est = fit.estimate(0)
    assert est["valid"] and est["r2"] > 0.99
    assert est["delay_s"] == pytest.approx(0.2, abs=0.051)
    assert est["lag_s"] == pytest.approx(0.3, abs=0.051)
    assert est["delay_ci95_s"][0] <= est["delay_s"] <= est["delay_ci95_s"][1]
    assert fit.estimate(1) is None or not fit.estimate(1)["valid"]  # no response at all


def _straight(adapter, params, truth_off, truth_scale, seconds, rng):
    """Drive straight at 8 m/s with small corrections: the sensor sums the adapter reads."""
    b, v, t = params.vehicle.wheelbase_m, 8.0, 0.0
    sw0 = -truth_off / truth_scale
    for _ in range(int(seconds / 0.1)):
        t += 0.1
        sw = sw0 + 0.01 * rng.standard_normal()
        yaw = v * math.sin(truth_off + truth_scale * sw) / b
        for j in range(10):
            adapter.signals.add_imu(t - 0.1 + j * 0.01, yaw + 0.005 * rng.standard_normal(), 0.0)
        for j in range(8):
            adapter.signals.add_can(t - 0.1 + j * 0.012, (v, v, v, v), sw)
        adapter.learn(t, v, 0.0)
        adapter.commanded(t, sw, 0.1, 0.0)


def test_ten_minutes_straight_learn_the_offset_and_hold_the_scale(params):
    ad = ModelAdapter(params, 0.1)
    _straight(ad, params, 0.030, 0.094, 600.0, np.random.default_rng(0))
    rep = ad.report()
    assert rep["steering.scale"]["final"] == params.steering.scale  # held, exactly
    assert not rep["steering.scale"]["identified"]
    # the offset that drives straight with the held scale: 0.030 - (0.094 - 0.08) sw0
    sw0 = -0.030 / 0.094
    assert rep["steering.offset_rad"]["final"] == pytest.approx(-0.08 * sw0, abs=5e-4)
    assert ad.model().scale == params.steering.scale


def test_learned_file_round_trip_restore_and_refusals(tmp_path, params):
    ad = ModelAdapter(params, 0.1)
    _straight(ad, params, 0.030, 0.094, 30.0, np.random.default_rng(1))
    out = tmp_path / "car.learned.yaml"
    save_learned(learned_params(ad, run_s=30.0), out)
    lp = load_params(out, require_model=True)  # a file every hmpc tool loads
    assert lp.steering.offset_rad == pytest.approx(ad.model().offset_rad)
    assert lp.steering.offset_ci95_rad[0] < lp.steering.offset_rad < lp.steering.offset_ci95_rad[1]
    assert lp.provenance["started_from"] == str(params.path)
    ad2 = ModelAdapter(params, 0.1)
    restore(ad2, lp, str(out))
    assert ad2.steering.filter.theta[0] == pytest.approx(lp.steering.offset_rad)
    assert ad2.report()["steering.offset_rad"]["initial"] == pytest.approx(lp.steering.offset_rad)
    other = replace(lp, vehicle=replace(lp.vehicle, wheelbase_m=2.9))
    with pytest.raises(InputError, match="another vehicle"):
        restore(ModelAdapter(params, 0.1), other, "x.yaml")
    # a state hmpc would refuse is never written, and the old file stays
    bad = replace(lp, steering=replace(lp.steering, scale=-1.0))
    with pytest.raises(ParamError):
        save_learned(bad, out)
    assert load_params(out).steering.scale == lp.steering.scale
    assert [p.name for p in tmp_path.iterdir()] == ["car.learned.yaml"]


def test_model_hand_over_mpc_values_only_and_estimator_keeps_its_road_wheel_angle(params):
    ctl = MpcController(params)
    m = LearnedModel(
        0.03, 0.09, (0.3, -0.1, -0.25), (2.2, 2.1, 3.3), (4.4, 5.5, 6.6), 0.1, 0.2, 0.0, 0.0
    )
    ctl.use_model(m)
    assert (ctl.plant.offset_rad, ctl.plant.scale) == (0.03, 0.09)
    assert list(ctl.plant.z_scale) == [2.2, 2.1, 3.3] and ctl.plant._eq8[1] == (-0.1, 2.1, 5.5)
    assert ctl.params.zones[2].brake_scale_mps2 == 6.6
    assert ctl.delay.dead_time_steer_s == 0.1 and ctl.delay.dead_time_long_s == 0.2
    assert params.steering.scale == 0.08 and params.zones[1].scale_mps2 == 2.5  # untouched
    est = Estimator(params)
    est.reset(0.0, [0.0, 0.0, 0.0, 5.0])
    est.predict(0.0, [1.0, 0.0, 0.0])
    delta = est._off + est._scale * 1.0 + est._x[IDOFF]
    est.use_model(m)
    assert est._off + est._scale * 1.0 + est._x[IDOFF] == pytest.approx(delta)
    assert est._eq8[1] == (-0.1, 2.1, 5.5)
