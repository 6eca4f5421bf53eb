"""The estimator's fast paths (controller.estimator) against the plain forms they replace.

The prediction writes eq. 1/7/8 out on Python floats and eq. 1's Jacobian straight into ``F``;
the updates use BLAS/LAPACK in place. Each is checked here against ``models.plant`` (the one
place the physics lives) or the textbook Kalman form, on seeded random states (seeds fixed).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from _data import REPORT_PARAMS
from hmpc.controller.estimator import NXE, Estimator, EstimatorConfig
from hmpc.controller.estimator.ekf import _zone_bands
from hmpc.models.params import load_params
from hmpc.models.plant import HybridPlant
from hmpc.models.zones import zone_with_hysteresis

P = load_params(REPORT_PARAMS)


def _random_filter(rng, est: Estimator) -> None:
    """A random but valid state and covariance (speeds across every zone and standstill)."""
    v = float(rng.choice([0.0, rng.uniform(0.0, 0.3), rng.uniform(0.0, 25.0)]))
    x = [
        rng.normal(0, 50),
        rng.normal(0, 50),
        rng.uniform(-math.pi, math.pi),
        v,
        rng.normal(0, 0.01),
        rng.normal(0, 0.002),
        1.0 + rng.normal(0, 0.02),
    ]
    est.reset(0.0, x)
    A = rng.normal(size=(NXE, NXE)) * 0.05
    M = A @ A.T + np.diag(est._init_var)
    est._P[:] = 0.5 * (M + M.T)  # exactly symmetric
    est._u[:] = [rng.normal(0, 1.0), rng.uniform(0, 1), rng.uniform(0, 1) * (rng.random() < 0.5)]


@pytest.mark.parametrize("seed", range(5))
def test_prediction_mean_is_the_plant_step_to_the_bit(seed):
    """The inlined mean equals ``HybridPlant.step`` bit for bit (zone with hysteresis, IMU
    acceleration, standstill clamp), so the plant stays the one source of eq. 1/7/8."""
    rng = np.random.default_rng(seed)
    est, plant = Estimator(P), HybridPlant(P)
    clamps = 0
    for _ in range(300):
        _random_filter(rng, est)
        est._zone = None if rng.random() < 0.2 else int(rng.integers(plant.n_zones))
        est._a_imu = float(rng.normal(0, 3))
        imu = bool(rng.random() < 0.5)
        sw, dt = float(rng.normal(0, 1.0)), float(rng.uniform(1e-4, 0.05))
        x0, zone0 = est._x.copy(), est._zone
        u = np.array([sw + x0[4] / plant.scale, est._u[1], est._u[2]])
        zone = plant.select_zone(float(x0[3]), zone0)
        extra = est._a_imu - plant.accel(zone, u[1], u[2]) if imu else 0.0
        ref = plant.step(x0[:4], u, dt, zone, extra)
        est._propagate(dt, sw, imu)
        assert np.array_equal(est._x[:4], ref.state), (seed, x0, sw, dt, imu)
        assert est._zone == ref.zone
        assert np.array_equal(est._x[4:], x0[4:])
        clamps += ref.state[3] == 0.0 and x0[3] > 0.0
    assert clamps > 0  # the standstill clamp was exercised


@pytest.mark.parametrize("seed", range(3))
def test_prediction_covariance_is_F_P_F_plus_Q(seed):
    """``P`` after a sub-step equals ``F P F' + Q dt`` with ``F = I + A dt`` from the plant's
    own Jacobians (``HybridPlant.jacobians``; the delta_offset column is the steering-wheel
    column divided by eq. 7's scale; with the IMU the speed walk is the IMU's)."""
    rng = np.random.default_rng(100 + seed)
    est, plant = Estimator(P), HybridPlant(P)
    cfg = est.cfg
    for _ in range(100):
        _random_filter(rng, est)
        imu = bool(rng.random() < 0.5)
        sw, dt = float(rng.normal(0, 1.0)), float(rng.uniform(1e-4, 0.05))
        x0, P0 = est._x.copy(), est._P.copy()
        u = np.array([sw + x0[4] / plant.scale, est._u[1], est._u[2]])
        zone = plant.select_zone(float(x0[3]), est._zone)
        A, B = plant.jacobians(x0[:4], u, zone)
        F = np.eye(NXE)
        F[:4, :4] += A * dt  # eq. 8's speed row has no state in it (zone aside)
        F[:3, 4] = B[:3, 0] * dt / plant.scale
        q = (
            np.array(
                [
                    cfg.position_walk_m_rts,
                    cfg.position_walk_m_rts,
                    cfg.heading_walk_rad_rts,
                    cfg.speed_walk_imu_mps_rts if imu else cfg.speed_walk_mps_rts,
                    cfg.delta_offset_walk_rad_rts,
                    cfg.gyro_bias_walk_radps_rts,
                    cfg.wheel_scale_walk_rts,
                ]
            )
            ** 2
        )
        expect = F @ P0 @ F.T + np.diag(q * dt)
        est._propagate(dt, sw, imu)
        np.testing.assert_allclose(est._P, expect, rtol=1e-12, atol=1e-18)


def test_zone_band_cache_agrees_with_the_plant_rule():
    """The kept-zone bands the prediction tests first give the zone that
    ``zone_with_hysteresis`` gives, at and around every edge, for every current zone."""
    plant = HybridPlant(P)
    vmin, vmax, h = plant._v_min_list, plant._v_max_list, plant.hysteresis_mps
    bands = _zone_bands(vmin, vmax, h)
    edges = sorted(
        {e + d for e in vmin + vmax for e in (e, e - h, e + h) for d in (-1e-9, 0.0, 1e-9)}
    )
    speeds = edges + list(np.linspace(-1.0, 40.0, 400)) + [math.nan, math.inf]
    for cur in [None] + list(range(len(vmax))):
        for v in speeds:
            fast = (
                cur
                if cur is not None and bands[cur][0] <= v <= bands[cur][1]
                else zone_with_hysteresis(v, cur, vmin, vmax, h, clamp=True)
            )
            assert fast == zone_with_hysteresis(v, cur, vmin, vmax, h, clamp=True), (cur, v)


@pytest.mark.parametrize("seed", range(3))
def test_updates_equal_the_textbook_kalman_update(seed):
    """The in-place one-value update (BLAS) and the Cholesky-solved GNSS update equal
    ``K = P H' S^-1``, ``x + K y``, ``P - K S K'`` computed plainly; the gate alike."""
    rng = np.random.default_rng(200 + seed)
    est = Estimator(P, EstimatorConfig(gnss_offset_m=(1.2, -0.3)))
    for trial in range(60):
        _random_filter(rng, est)
        x0, P0 = est._x.copy(), est._P.copy()
        if trial % 2:
            h = est._h_wyaw
            h[:] = 0.0
            h[[3, 4, 6]] = rng.normal(size=3)
            H, y, R = h[None, :].copy(), np.array([rng.normal(0, 0.05)]), np.array([[0.02**2]])
            ok = est._update1(h, float(y[0]), float(R[0, 0]), "wheel_yaw_rate")
            gate = est._gate[1]
        else:
            gx, gy = x0[0] + rng.normal(0, 0.3), x0[1] + rng.normal(0, 0.3)
            gh, gv = x0[2] + rng.normal(0, 0.03), x0[3] + rng.normal(0, 0.2)
            ok = est._gnss_update(gx, gy, gh, gv)
            H, y, R = est._H[4].copy(), est._y[4].copy(), np.diag(est._R[4])
            gate = est._gate[4]
        S = H @ P0 @ H.T + R
        K = P0 @ H.T @ np.linalg.inv(S)
        d2 = float(y @ np.linalg.solve(S, y))
        assert ok == (d2 <= gate), (seed, trial, d2)
        if ok:
            np.testing.assert_allclose(est._x, x0 + K @ y, rtol=1e-10, atol=1e-12)
            np.testing.assert_allclose(est._P, P0 - K @ S @ K.T, rtol=1e-9, atol=1e-14)
            # symmetric to rounding (the GNSS update symmetrises exactly, the BLAS rank-one
            # update to a few ulps)
            np.testing.assert_allclose(est._P, est._P.T, rtol=0, atol=1e-15)
        else:
            assert np.array_equal(est._x, x0) and np.array_equal(est._P, P0)


def test_plant_step_fallback_gives_the_same_prediction():
    """The path for a plant with opt-in extensions (``HybridPlant.step`` itself for the mean)
    gives, on the report's plant, the same state and covariance as the written-out one."""
    rng = np.random.default_rng(7)
    fast, slow = Estimator(P), Estimator(P)
    slow._plant_step = True
    for _ in range(50):
        _random_filter(rng, fast)
        slow.reset(0.0, fast._x)
        slow._P[:], slow._u[:], slow._zone = fast._P, fast._u, fast._zone
        sw, dt = float(rng.normal(0, 1.0)), float(rng.uniform(1e-4, 0.05))
        imu = bool(rng.random() < 0.5)
        fast._a_imu = slow._a_imu = float(rng.normal(0, 2))
        fast._propagate(dt, sw, imu)
        slow._propagate(dt, sw, imu)
        assert np.array_equal(fast._x, slow._x) and np.array_equal(fast._P, slow._P)
        assert fast._zone == slow._zone
