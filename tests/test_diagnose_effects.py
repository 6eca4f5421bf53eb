"""The extra concealed effects of the diagnosis benchmark (models.sim.effects_extra) do what
they say on the ground-truth simulator (noise-free, seeded)."""
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
