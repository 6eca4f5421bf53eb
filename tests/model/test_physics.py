"""The one source of truth for the plant's physics (models/plant.py): eq. 1's model and its
Jacobian against finite differences, scalar against batch, numpy against CasADi, and the
zone rule at its edges (boundaries, NaN, above the last zone, hysteresis).

Seeds are fixed (SEED, printed in the assertion messages)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from _data import REPORT_PARAMS
from hmpc.models.params import load_params
from hmpc.models.plant import (
    IV,
    HybridPlant,
    bicycle_jacobian,
    bicycle_rates,
    derivative_batch,
    jacobians_batch,
    road_wheel_angle,
    steering_wheel_angle_for,
    zone_accel,
)
from hmpc.models.zones import (
    zone_of_speed,
    zone_with_hysteresis,
    zones_of_speed,
    zones_with_hysteresis,
)

SEED = 20251123
V_MIN = [0.0, 2.0, 5.0]
V_MAX = [2.0, 5.0, 20.0]


@pytest.fixture(scope="module")
def plant():
    return HybridPlant(load_params(REPORT_PARAMS, require_model=True))


def _random_rows(n: int, seed: int = SEED):
    rng = np.random.default_rng(seed)
    X = np.column_stack(
        [rng.normal(0, 20, n), rng.normal(0, 20, n), rng.uniform(-4, 4, n), rng.uniform(0, 20, n)]
    )
    U = np.column_stack([rng.uniform(-7, 7, n), rng.uniform(0, 1, n), rng.uniform(0, 1, n)])
    return X, U


# -------------------------------------------------------------------------- eq. 1, 7, 8
def test_jacobian_matches_central_differences(plant):
    """Central differences with h = 1e-6 have truncation error ~h^2 * |f'''| < 1e-10 and
    round-off ~1e-16 * |f| / h < 1e-8 here (|f| <= 20 m/s): bound 1e-7."""
    X, U = _random_rows(40)
    zones = zones_of_speed(X[:, IV], plant.v_max, clamp=True)
    A, B = jacobians_batch(plant, X, U, zones)
    h = 1e-6
    for k in range(len(X)):
        for j in range(4):
            d = np.zeros(4)
            d[j] = h
            fd = (
                plant.derivative(X[k] + d, U[k], zones[k])
                - plant.derivative(X[k] - d, U[k], zones[k])
            ) / (2 * h)
            assert np.max(np.abs(A[k, :, j] - fd)) < 1e-7, (SEED, k, j)
        for j in range(3):
            d = np.zeros(3)
            d[j] = h
            fd = (
                plant.derivative(X[k], U[k] + d, zones[k])
                - plant.derivative(X[k], U[k] - d, zones[k])
            ) / (2 * h)
            assert np.max(np.abs(B[k, :, j] - fd)) < 1e-7, (SEED, k, j)


def test_scalar_and_batch_are_the_same_model(plant):
    """Scalars (python floats, ``ops=math``) and a numpy batch give the same numbers (numpy's
    vectorised sin/cos may differ from libm in the last bit: bound 4 ulp of 20)."""
    X, U = _random_rows(50)
    zones = zones_of_speed(X[:, IV], plant.v_max, clamp=True)
    F = derivative_batch(plant, X, U, zones)
    A, B = jacobians_batch(plant, X, U, zones)
    for k in range(len(X)):
        psi, v, sw, ap, bp = (
            float(X[k, 2]),
            float(X[k, 3]),
            float(U[k, 0]),
            float(U[k, 1]),
            float(U[k, 2]),
        )
        delta = road_wheel_angle(sw, plant.offset_rad, plant.scale)
        rates = bicycle_rates(psi, v, delta, plant.wheelbase_m, ops=math)
        z = int(zones[k])
        a = zone_accel(
            float(plant.z_offset[z]), float(plant.z_scale[z]), float(plant.z_brake[z]), ap, bp
        )
        assert np.allclose(F[k], [*rates, a], rtol=0, atol=1e-14), (SEED, k)
        assert np.allclose(plant.derivative(X[k], U[k], z), F[k], rtol=0, atol=1e-14)
        j = bicycle_jacobian(psi, v, delta, plant.wheelbase_m, plant.scale, ops=math)
        assert np.allclose(
            [
                A[k, 0, 2],
                A[k, 0, 3],
                A[k, 1, 2],
                A[k, 1, 3],
                A[k, 2, 3],
                B[k, 0, 0],
                B[k, 1, 0],
                B[k, 2, 0],
            ],
            list(j),
            rtol=0,
            atol=1e-14,
        )
        Ak, Bk = plant.jacobians(X[k], U[k], z)
        assert np.array_equal(Ak, A[k]) and np.array_equal(Bk, B[k])
        # eq. 7 inverted is eq. 7's inverse
        assert steering_wheel_angle_for(delta, plant.offset_rad, plant.scale) == pytest.approx(
            sw, abs=1e-12
        )


def test_numpy_and_casadi_evaluate_the_same_function(plant):
    ca = pytest.importorskip("casadi")
    psi, v, sw = ca.SX.sym("psi"), ca.SX.sym("v"), ca.SX.sym("sw")
    delta = road_wheel_angle(sw, plant.offset_rad, plant.scale)
    rates = bicycle_rates(psi, v, delta, plant.wheelbase_m, ops=ca)
    j = bicycle_jacobian(psi, v, delta, plant.wheelbase_m, plant.scale, ops=ca)
    f = ca.Function("f", [psi, v, sw], [ca.vertcat(*rates), ca.vertcat(*j)])
    # the symbolic Jacobian of the symbolic model equals the hand-written one too
    g = ca.Function("g", [psi, v, sw], [ca.jacobian(ca.vertcat(*rates), ca.vertcat(psi, v, sw))])
    X, U = _random_rows(30, SEED + 1)
    for k in range(len(X)):
        p, vv, s = float(X[k, 2]), float(X[k, 3]), float(U[k, 0])
        out_r, out_j = (np.asarray(o).ravel() for o in f(p, vv, s))
        d = road_wheel_angle(s, plant.offset_rad, plant.scale)
        assert np.allclose(out_r, bicycle_rates(p, vv, d, plant.wheelbase_m), rtol=0, atol=1e-13), (
            SEED + 1,
            k,
        )
        assert np.allclose(
            out_j,
            list(bicycle_jacobian(p, vv, d, plant.wheelbase_m, plant.scale)),
            rtol=0,
            atol=1e-13,
        )
        J = np.asarray(g(p, vv, s))
        jj = bicycle_jacobian(p, vv, d, plant.wheelbase_m, plant.scale)
        assert np.allclose(
            J,
            [
                [jj.dx_dpsi, jj.dx_dv, jj.dx_du],
                [jj.dy_dpsi, jj.dy_dv, jj.dy_du],
                [0.0, jj.dpsi_dv, jj.dpsi_du],
            ],
            rtol=0,
            atol=1e-13,
        )


def test_plant_step_is_eq1_over_the_distance_travelled(plant):
    """A step at constant speed turns by v dt sin(delta) / b and moves the front point by
    v dt along the midpoint heading + delta: :func:`bicycle_rates` integrated by the midpoint
    rule (exact to round-off), and within v |psi'| dt / 2 of the rates at the start."""
    s = np.array([3.0, -2.0, 0.4, 6.0])
    z = plant.select_zone(6.0, None)
    ap = -float(plant.z_offset[z]) / float(plant.z_scale[z])  # zero acceleration
    u = np.array([1.5, ap, 0.0])
    dt = 1e-3
    r = plant.step(s, u, dt, z)
    delta = road_wheel_angle(1.5, plant.offset_rad, plant.scale)
    rates = np.array(bicycle_rates(s[2], s[3], delta, plant.wheelbase_m))
    mid = np.array(bicycle_rates(s[2] + 0.5 * dt * rates[2], s[3], delta, plant.wheelbase_m))
    step_rates = (r.state[:3] - s[:3]) / dt
    assert np.allclose(step_rates, mid, rtol=0, atol=1e-9)
    assert np.all(np.abs(step_rates - rates) <= s[3] * abs(rates[2]) * dt / 2 + 1e-9)


# ------------------------------------------------------------------------- the zone rule
@pytest.mark.parametrize(
    "v, zone, clamped",
    [
        (0.0, 0, 0),
        (-1.0, 0, 0),
        (-math.inf, 0, 0),  # the first zone takes 0 and below
        (2.0, 0, 0),
        (math.nextafter(2.0, 3.0), 1, 1),  # exactly on a boundary: the lower zone
        (5.0, 1, 1),
        (5.0 + 1e-12, 2, 2),
        (20.0, 2, 2),
        (20.0 + 1e-9, -1, 2),
        (math.inf, -1, 2),  # above the last zone: none, or clamp
        (math.nan, -1, 2),  # NaN: no zone (the plant: the last)
    ],
)
def test_zone_rule_edges(v, zone, clamped):
    assert zone_of_speed(v, V_MAX) == zone
    assert zone_of_speed(v, V_MAX, clamp=True) == clamped
    assert zones_of_speed(np.array([v]), V_MAX).tolist() == [zone]
    assert zones_of_speed(np.array([v]), V_MAX, clamp=True).tolist() == [clamped]


def test_zone_rule_vectorised_equals_scalar():
    rng = np.random.default_rng(SEED)
    v = np.concatenate([rng.uniform(-1, 25, 500), V_MAX, V_MIN, [np.nan, np.inf]])
    for clamp in (False, True):
        assert zones_of_speed(v, V_MAX, clamp=clamp).tolist() == [
            zone_of_speed(float(x), V_MAX, clamp=clamp) for x in v
        ]


def test_hysteresis_edges():
    h = 0.25

    def hy(v, cur, clamp=False):
        return zone_with_hysteresis(v, cur, V_MIN, V_MAX, h, clamp=clamp)

    assert hy(2.25, 0) == 0 and hy(math.nextafter(2.25, 3.0), 0) == 1  # band edge inclusive
    assert hy(1.75, 1) == 1 and hy(math.nextafter(1.75, 0.0), 1) == 0
    assert hy(-5.0, 0) == 0  # the first zone has no lower edge
    assert hy(20.1, 2) == -1 and hy(20.1, 2, clamp=True) == 2  # no band above the last zone
    assert hy(1e6, 2, clamp=True) == 2
    assert hy(math.nan, 1) == -1 and hy(math.nan, 1, clamp=True) == 2  # NaN leaves the band
    assert hy(3.0, None) == 1 and hy(3.0, -1) == 1 and hy(3.0, 7) == 1  # no valid current
    # along a sequence: a speed hovering on a boundary keeps its zone; NaN resets
    v = np.array([1.9, 2.05, 1.98, 2.2, 2.3, 2.05, 1.9, 1.7, np.nan, 2.1])
    assert zones_with_hysteresis(v, V_MIN, V_MAX, h).tolist() == [0, 0, 0, 0, 1, 1, 1, 0, -1, 1]
    assert zones_with_hysteresis(v[:3], V_MIN, V_MAX, h, start=1).tolist() == [1, 1, 1]


def test_a_speed_sequence_takes_the_per_sample_rule_at_every_sample():
    """``zones_with_hysteresis`` (a search per zone held) against ``zone_with_hysteresis``
    applied sample by sample from the previous sample's zone: random zone tables and
    hysteresis, random walks and draws from the band edges, NaN, every kind of start."""
    rng = np.random.default_rng(SEED)
    for _ in range(2000):
        edges = np.sort(rng.uniform(0.5, 30.0, int(rng.integers(1, 5)))).tolist()
        vmin, vmax = [0.0] + edges[:-1], edges
        h = float(rng.choice([0.0, 0.1, 0.5, 2.0]))
        n = int(rng.integers(0, 60))
        kind = int(rng.integers(0, 3))
        if kind == 0:
            v = rng.uniform(-1.0, 35.0, n)
        elif kind == 1:
            v = np.cumsum(rng.normal(0.0, 1.0, n)) + rng.uniform(0.0, 30.0)
        else:  # exactly on the bands' edges
            v = rng.choice(
                np.array([*vmax, *(x + h for x in vmax), *(x - h for x in vmax), np.nan]), n
            )
        start = [None, -1, 0, len(vmax) - 1, int(rng.integers(0, len(vmax)))][rng.integers(0, 5)]
        clamp = bool(rng.integers(0, 2))
        cur, expect = start, []
        for x in v.tolist():
            cur = zone_with_hysteresis(x, cur, vmin, vmax, h, clamp=clamp)
            expect.append(cur)
        got = zones_with_hysteresis(v, vmin, vmax, h, start=start, clamp=clamp)
        assert got.tolist() == expect, (v, vmin, vmax, h, start, clamp)


def test_every_user_calls_the_one_zone_rule(plant):
    """Params.zone_for, the plant, identification's assign_zones and the MPC's schedule give
    the zone rule's answers (the same speeds, including the edges)."""
    from hmpc.controller.mpc import MpcController
    from hmpc.models.identify.longitudinal import assign_zones

    params = plant.params
    vmax = [z.v_max_mps for z in params.zones]
    vmin = [z.v_min_mps for z in params.zones]
    rng = np.random.default_rng(SEED)
    v = np.concatenate([rng.uniform(0, 25, 200), vmax, [np.nan]])
    ref = zones_of_speed(v, vmax)
    assert [params.zone_for(float(x)) for x in v] == ref.tolist()
    clamped = zones_of_speed(v, vmax, clamp=True).tolist()
    assert [plant.zone_by_speed(float(x)) for x in v] == clamped
    zones = tuple((z.name, z.v_min_mps, z.v_max_mps) for z in params.zones)
    assert assign_zones(v, zones).tolist() == ref.tolist()
    h = plant.hysteresis_mps
    assert assign_zones(v, zones, h).tolist() == zones_with_hysteresis(v, vmin, vmax, h).tolist()
    ctl = MpcController(params)
    vb = np.clip(np.cumsum(rng.normal(0, 0.4, ctl.N + 1)) + 3.0, 0.0, None)
    expect = [1] + zones_with_hysteresis(vb[1 : ctl.N], vmin, vmax, h, start=1, clamp=True).tolist()
    assert ctl.zone_rules.schedule(1, vb).tolist() == expect
    # and the plant's step uses it with hysteresis from the current zone
    for x, cur in ((2.1, 0), (1.9, 1), (30.0, 2), (3.0, None)):
        s = plant.step(np.array([0.0, 0.0, 0.0, x]), np.zeros(3), 1e-4, cur)
        assert s.zone == zone_with_hysteresis(x, cur, vmin, vmax, h, clamp=True)
