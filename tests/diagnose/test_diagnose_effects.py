"""The extra concealed effects of the diagnosis benchmark (models.sim.effects_extra) do what
they say on the ground-truth simulator (noise-free, seeded); the longitudinal fit times its
inputs as the replay does (zero-order hold)."""

from __future__ import annotations

import numpy as np
import pytest

from hmpc.models.sim import effects_extra as fx2
from hmpc.models.sim.simulator import random_params, run_experiment


@pytest.fixture(scope="module")
def truth():
    return random_params(5)


def test_idle_creep_adds_its_term_only_with_the_throttle_released(truth):
    run = run_experiment("ramps", truth, seed=0, noise="none", effects=[fx2.IdleCreep(0.6, 2.0)])
    tr = run.truth
    v, th = tr["v_mps"], tr["accel_pedal_eff"]
    expect = np.where(th < 0.01, 0.6 * np.maximum(0.0, 1.0 - v / 2.0), 0.0)
    assert np.allclose(tr["accel_extra_mps2"], expect, atol=1e-12)
    assert (tr["accel_extra_mps2"] > 0.1).any()


def test_hilly_road_grade_follows_the_distance(truth):
    eff = fx2.HillyRoad(0.05, 150.0)
    run = run_experiment("ramp_sequence", truth, seed=0, noise="none", effects=[eff])
    tr = run.truth
    s = np.concatenate([[0.0], np.cumsum(tr["v_mps"][:-1] * tr.dt_s)])
    assert np.allclose(tr["accel_extra_mps2"], -9.80665 * np.sin(eff.grade_at(s)), atol=2e-3)
    with pytest.raises(ValueError):
        fx2.HillyRoad(0.5, 150.0)


def test_mass_change_scales_the_pedals_from_its_time_on(truth):
    run = run_experiment("ramps", truth, seed=0, noise="none", effects=[fx2.MassChange(30.0, 0.7)])
    tr = run.truth
    before, after = tr["t_s"] < 30.0 - 1e-9, tr["t_s"] >= 30.0 + 1e-9
    assert np.allclose(tr["accel_pedal_eff"][before], tr["accel_pedal"][before])
    assert np.allclose(tr["accel_pedal_eff"][after], 0.7 * tr["accel_pedal"][after])
    assert np.allclose(tr["brake_pedal_eff"][after], 0.7 * tr["brake_pedal"][after])


def _zoh_recording(dt: float = 0.02, dur_s: float = 300.0):
    """A car obeying one zone's law exactly, its pedal held between samples (zero-order hold,
    v[k+1] = v[k] + a(u[k]) dt, as a discrete plant and the diagnosis's replay integrate), the
    throttle a sum of slow sines so that its rate is correlated with the speed (the speed is
    the throttle's integral: a quarter period behind it)."""
    t = np.arange(0.0, dur_s, dt)
    offset, gain = -0.3, 2.6
    ap = (
        -offset / gain
        + 0.10 * np.sin(2 * np.pi * t / 20.0)
        + 0.05 * np.sin(2 * np.pi * t / 7.0 + 1.0)
    )
    a = offset + gain * ap
    v = 9.0 + np.concatenate([[0.0], np.cumsum(a[:-1]) * dt])
    return {"time": t, "speed": v, "accel_pedal": ap, "brake_pedal": np.zeros_like(t)}, gain


def test_fit_inputs_are_causal_like_the_replay():
    """The equation-error fit integrates an input from its own sample on (zero-order hold, as
    the replay does): on an exact zero-order-hold recording the fitted zone law is the truth and
    a speed-proportional term finds nothing. An input integrated one sample early (the running
    sum including u[k]) made the throttle's rate, correlated with the speed, a v-slope here of
    -0.0024 1/s (independent recordings: an apparent rolling resistance of -0.001 1/s)."""
    from hmpc.models.diagnose import longitudinal as lon

    ch, gain = _zoh_recording()
    d = lon.prepare(ch)
    assert d.vs.min() > 5.5 and d.vs.max() < 20.0  # one zone (high) throughout
    assert abs(d.input_shift_s) < 0.1 * d.dt  # recorded as it acts: no re-timing
    assert abs(lon.unconstrained_ext(d, "rolling_resistance")) < 5e-5
    m = lon.fit(d, lon.LonSpec(), d.ok)
    assert m.C[2, 1] == pytest.approx(gain, rel=1e-3)
    x = np.arange(6) * 0.5
    assert np.allclose(
        lon.causal_integral(x, 0.5), np.concatenate([[0.0], np.cumsum(x[:-1])]) * 0.5
    )
