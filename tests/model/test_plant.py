"""Zone switching and standstill of the hybrid plant (models/plant.py)."""

from __future__ import annotations

import copy

import numpy as np
import pytest

from hmpc.models.params import load_params
from hmpc.models.plant import IV, IX, DelayLine, HybridPlant

SEED = 20240604


@pytest.fixture(scope="module")
def params():
    return load_params("params/report_2008.yaml", require_model=True)


def test_hysteresis_keeps_zone_inside_band_and_leaves_outside(params):
    plant = HybridPlant(params, hysteresis_mps=0.25)
    assert plant.select_zone(2.1, 0) == 0  # idle kept up to 2.0 + 0.25
    assert plant.select_zone(2.26, 0) == 1  # then low
    assert plant.select_zone(1.9, 1) == 1  # low kept down to 2.0 - 0.25
    assert plant.select_zone(1.74, 1) == 0
    assert plant.select_zone(5.2, 1) == 1
    assert plant.select_zone(5.3, 1) == 2
    assert plant.select_zone(4.8, 2) == 2
    assert plant.select_zone(4.7, 2) == 1
    assert plant.select_zone(30.0, 2) == 2  # above the last zone: last zone
    assert plant.select_zone(3.0, None) == 1  # no current zone: by speed
    assert plant.zone_by_speed(2.0) == 0 and plant.zone_by_speed(2.0001) == 1


def test_plant_is_continuous_where_zone_models_agree(params):
    p = copy.deepcopy(params)
    low = p.zones[1]
    for z in p.zones:  # every zone gets the low zone's model
        z.offset_mps2, z.scale_mps2, z.brake_scale_mps2 = (
            low.offset_mps2,
            low.scale_mps2,
            low.brake_scale_mps2,
        )
    plant = HybridPlant(p)
    u = np.array([0.3, 0.4, 0.0])
    s = np.array([0.0, 0.0, 0.1, 1.5])
    zone = None
    speeds = []
    zones = []
    for _ in range(600):  # 1.5 -> ~15 m/s through both boundaries
        r = plant.step(s, u, 0.01, zone)
        s, zone = r.state, r.zone
        speeds.append(s[IV])
        zones.append(zone)
        assert r.accel_mps2 == pytest.approx(low.accel_mps2(0.4, 0.0), abs=1e-12)
    assert set(zones) == {0, 1, 2}  # it did cross both boundaries
    dv = np.diff(speeds)
    assert np.allclose(dv, dv[0], atol=1e-12)  # no jump anywhere: one smooth ramp

    # where the models differ, the acceleration jumps by exactly the difference at the switch
    plant2 = HybridPlant(params, hysteresis_mps=0.0)
    a_idle = plant2.step(np.array([0, 0, 0, 1.99]), u, 1e-4, 0).accel_mps2
    a_low = plant2.step(np.array([0, 0, 0, 2.01]), u, 1e-4, 0).accel_mps2
    assert a_low - a_idle == pytest.approx(
        params.zones[1].accel_mps2(0.4, 0) - params.zones[0].accel_mps2(0.4, 0)
    )


@pytest.mark.parametrize("boundary", [2.0, 5.0])
def test_no_transition_chatter_with_noise_on_a_boundary(params, boundary):
    rng = np.random.default_rng(SEED)
    print(f"seed {SEED}")
    v = boundary + rng.normal(0.0, 0.05, 2000)  # 40 s at 50 Hz of speed noise on the boundary

    def transitions(h):
        plant = HybridPlant(params, hysteresis_mps=h)
        zone, n = None, 0
        for vi in v:
            z = plant.select_zone(float(vi), zone)
            n += zone is not None and z != zone
            zone = z
        return n

    assert transitions(0.25) <= 1
    assert transitions(0.0) > 100  # the same noise without hysteresis chatters: the test can fail


def test_standstill_never_rolls_backwards_under_the_brake(params):
    plant = HybridPlant(params)
    s = np.array([0.0, 0.0, 0.3, 1.0])
    u = np.array([0.0, 0.0, 1.0])
    x_along = []
    for _ in range(300):
        r = plant.step(s, u, 0.02, None)
        s = r.state
        assert s[IV] >= 0.0
        x_along.append(s[IX] * np.cos(0.3) + s[1] * np.sin(0.3))
    assert s[IV] == 0.0
    assert np.all(np.diff(x_along) >= -1e-12)
    # at rest with the brake on, the car stays exactly where it is
    r = plant.step(s, u, 0.02, None)
    assert np.array_equal(r.state, s)
    assert r.accel_mps2 == 0.0
    # idle creep with the pedals released moves it forward (offset > 0 in the idle zone)
    r = plant.step(s, np.zeros(3), 0.1, None)
    assert r.state[IV] == pytest.approx(params.zones[0].offset_mps2 * 0.1)


def test_jacobians_match_finite_differences(params):
    plant = HybridPlant(params)
    rng = np.random.default_rng(SEED)
    for _ in range(20):
        s = np.array(
            [rng.normal(0, 10), rng.normal(0, 10), rng.uniform(-3, 3), rng.uniform(0.5, 15)]
        )
        u = np.array([rng.uniform(-6, 6), rng.uniform(0, 1), rng.uniform(0, 1)])
        zone = plant.zone_by_speed(s[IV])
        A, B = plant.jacobians(s, u, zone)
        eps = 1e-6
        for j in range(4):
            d = np.zeros(4)
            d[j] = eps
            fd = (plant.derivative(s + d, u, zone) - plant.derivative(s - d, u, zone)) / (2 * eps)
            assert np.allclose(A[:, j], fd, atol=1e-6)
        for j in range(3):
            d = np.zeros(3)
            d[j] = eps
            fd = (plant.derivative(s, u + d, zone) - plant.derivative(s, u - d, zone)) / (2 * eps)
            assert np.allclose(B[:, j], fd, atol=1e-6)


def test_delay_line_delays_by_whole_steps():
    d = DelayLine(0.3, 0.1, initial=0.0)
    out = [d.push(float(i)) for i in range(1, 7)]
    assert out == [0.0, 0.0, 0.0, 1.0, 2.0, 3.0]
    assert d.pending() == [4.0, 5.0, 6.0]
    assert DelayLine(0.0, 0.1).push(5.0) == 5.0
