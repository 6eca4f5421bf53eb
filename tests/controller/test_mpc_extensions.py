"""The MPC predicts with the physics ``hmpc diagnose`` adds (``extensions:``).

``HybridPlant(params, extensions=True)`` adds drag, rolling resistance, idle creep and the
steering map's shapes (models.plant.plant_extensions) on the coefficients each was fitted
with; the MPC builds its prediction model that way and simulates an actuator lag from its own
commands. Checked here: the Jacobians against finite differences, the plant's step against
its derivative, that nothing changes without extensions and that truth plants never add them
(opt-in), the QP's A_d pattern, the exact lag, and on short seeded closed loops that the MPC
given an effect tracks a truth plant with that effect better than the MPC without it.
"""

from __future__ import annotations

import copy
import math

import numpy as np
import pytest

from _data import REPORT_PARAMS
from hmpc.controller.closed_loop import run_closed_loop
from hmpc.controller.mpc import MpcController
from hmpc.controller.mpc.constraints import linearise
from hmpc.controller.mpc.delay import _lag_through
from hmpc.controller.mpc.qp import APAT
from hmpc.models.params import load_params, parse_params
from hmpc.models.plant import (
    IAP,
    IBP,
    ISW,
    IV,
    HybridPlant,
    derivative_batch,
    first_order_lag,
    jacobians_batch,
    plant_extensions,
)
from hmpc.models.sim import effects as fx
from hmpc.models.sim import effects_extra as fx2
from hmpc.models.reference import Reference
from hmpc.models.sim.scenarios import make_scenario

SEED = 20261123


def report():
    return load_params(REPORT_PARAMS, require_model=True)


def with_ext(p, ext: dict):
    q = copy.deepcopy(p)
    q.extensions = ext
    return q


ALL_PHYSICS = {
    "aero_drag": {"longitudinal": {"coeff_per_m": 2e-3}},
    "rolling_resistance": {"longitudinal": {"coeff_per_s": 8e-3}},
    "idle_creep": {"longitudinal": {"accel_mps2": 0.6, "creep_speed_mps": 2.0}},
    "steering_nonlinearity": {"steering": {"cubic_per_rad2": 0.004}},
    "understeer": {"steering": {"gradient_rad_per_mps2": 0.004}},
}


def random_rows(n: int, rng) -> tuple[np.ndarray, np.ndarray]:
    X = np.column_stack(
        [
            rng.uniform(-50, 50, n),
            rng.uniform(-50, 50, n),
            rng.uniform(-math.pi, math.pi, n),
            rng.uniform(0.2, 15.0, n),
        ]
    )
    U = np.column_stack([rng.uniform(-6, 6, n), rng.uniform(0, 0.6, n), rng.uniform(0, 0.6, n)])
    # half the rows with the throttle released (the creep acts), away from its 0.01 switch
    U[: n // 2, IAP] = 0.0
    return X, U


@pytest.mark.parametrize(
    "ids",
    [
        tuple(ALL_PHYSICS),
        ("aero_drag",),
        ("idle_creep",),
        ("steering_nonlinearity",),
        ("understeer",),
    ],
)
def test_jacobians_match_finite_differences(ids):
    plant = HybridPlant(with_ext(report(), {k: ALL_PHYSICS[k] for k in ids}), extensions=True)
    # the plant carries exactly the physics asked for (each id's coefficient, nothing else)
    fields = {
        "aero_drag": "drag_per_m",
        "rolling_resistance": "rolling_per_s",
        "idle_creep": "creep_accel_mps2",
        "steering_nonlinearity": "cubic_per_rad2",
        "understeer": "understeer_rad_per_mps2",
    }
    assert {k for k, f in fields.items() if getattr(plant.ext, f)} == set(ids)
    rng = np.random.default_rng(SEED)
    X, U = random_rows(40, rng)
    X[:, IV] = np.where(np.abs(X[:, IV] - 2.0) < 0.05, 2.2, X[:, IV])  # off the creep's kink
    zones = plant.zone_schedule(X[:, IV], None)
    A, B = jacobians_batch(plant, X, U, zones)
    h = 1e-6
    for j in range(4):
        dX = np.zeros_like(X)
        dX[:, j] = h
        fd = (
            derivative_batch(plant, X + dX, U, zones) - derivative_batch(plant, X - dX, U, zones)
        ) / (2 * h)
        np.testing.assert_allclose(A[:, :, j], fd, rtol=1e-5, atol=1e-6, err_msg=f"state {j}")
    for j in (ISW, IBP):  # the accelerator pedal's creep switch has no derivative
        dU = np.zeros_like(U)
        dU[:, j] = h
        fd = (
            derivative_batch(plant, X, U + dU, zones) - derivative_batch(plant, X, U - dU, zones)
        ) / (2 * h)
        np.testing.assert_allclose(B[:, :, j], fd, rtol=1e-5, atol=1e-6, err_msg=f"input {j}")


def test_extensions_change_the_derivative_as_the_catalogue_says():
    p = report()
    base = HybridPlant(p)
    ext = HybridPlant(with_ext(p, ALL_PHYSICS), extensions=True)
    X = np.array([[0.0, 0.0, 0.3, 8.0], [0.0, 0.0, 0.3, 1.0]])
    U = np.array([[2.0, 0.2, 0.0], [2.0, 0.0, 0.1]])
    z = np.array([2, 0])
    f0, f1 = derivative_batch(base, X, U, z), derivative_batch(ext, X, U, z)
    v = X[:, IV]
    creep = np.array([0.0, 0.6 * (1 - 1.0 / 2.0)])
    np.testing.assert_allclose(f1[:, IV] - f0[:, IV], -2e-3 * v * v - 8e-3 * v + creep)
    sw = 2.0
    d7 = p.steering.offset_rad + p.steering.scale * (sw + 0.004 * sw**3)
    b = p.vehicle.wheelbase_m
    delta = d7 * b / (b + 0.004 * v * v)
    np.testing.assert_allclose(f1[:, 2], v * np.sin(delta) / b)


def test_plant_step_follows_its_derivative():
    plant = HybridPlant(with_ext(report(), ALL_PHYSICS), extensions=True)
    s, u = np.array([1.0, 2.0, 0.4, 9.0]), np.array([1.5, 0.3, 0.0])
    zone = plant.zone_by_speed(9.0)
    dt = 1e-3
    r = plant.step(s, u, dt, zone)
    np.testing.assert_allclose((r.state - s) / dt, plant.derivative(s, u, zone), rtol=2e-3)


def test_without_extensions_the_plant_is_the_reports_and_truth_plants_never_add_them():
    p = report()
    q = with_ext(p, ALL_PHYSICS)
    assert HybridPlant(p, extensions=True).ext is None
    assert HybridPlant(q).ext is None  # opt-in: the closed loop's and the node's truth plants
    rng = np.random.default_rng(SEED)
    X, U = random_rows(20, rng)
    zones = np.zeros(20, dtype=np.int64)
    a, b = HybridPlant(p), HybridPlant(q)
    assert np.array_equal(derivative_batch(a, X, U, zones), derivative_batch(b, X, U, zones))
    assert MpcController(p).plant.ext is None
    assert MpcController(q).plant.ext == HybridPlant(q, extensions=True).ext
    assert MpcController(q).plant.ext.longitudinal and MpcController(q).plant.ext.steering


def test_base_coefficients_are_used_and_a_command_fit_adds_no_longitudinal_term():
    p = report()
    zs = [
        {
            "name": z.name,
            "offset_mps2": z.offset_mps2 - 0.1,
            "scale_mps2": z.scale_mps2 + 0.2,
            "brake_scale_mps2": -z.brake_scale_mps2,
        }
        for z in p.zones
    ]
    q = with_ext(
        p,
        {
            "aero_drag": {"longitudinal": {"coeff_per_m": 1e-3, "base": {"zones": zs}}},
            "understeer": {
                "steering": {
                    "gradient_rad_per_mps2": 0.003,
                    "base": {"offset_rad": 0.01, "scale": 0.07},
                }
            },
        },
    )
    pl = HybridPlant(q, extensions=True)
    np.testing.assert_allclose(pl.z_offset, [z["offset_mps2"] for z in zs])
    np.testing.assert_allclose(pl.z_scale, [z["scale_mps2"] for z in zs])
    # a brake that accelerates is no physics: the file's brake scale
    np.testing.assert_allclose(pl.z_brake, [z.brake_scale_mps2 for z in p.zones])
    assert (pl.offset_rad, pl.scale) == (0.01, 0.07)
    cmd = [{"name": z.name, "offset_mps2": 0.0, "accel_cmd_gain": 1.0} for z in p.zones]
    r = with_ext(
        p,
        {
            "aero_drag": {"longitudinal": {"coeff_per_m": 1e-3, "base": {"zones": cmd}}},
            "actuator_lag": {"longitudinal": {"tau_s": 0.25}},
        },
    )
    ext, _, zones = plant_extensions(r)
    assert ext.drag_per_m == 0.0 and zones is None and ext.lag_long_s == 0.25


def test_a_parameter_file_with_extensions_round_trips_into_the_plant():
    d = report().to_dict()
    d["extensions"] = {
        "idle_creep": {"longitudinal": {"accel_mps2": 0.5, "creep_speed_mps": 2.5}},
        "actuator_lag": {"steering": {"tau_s": 0.3}},
    }
    ext, _, _ = plant_extensions(parse_params(d, require_model=True))
    assert (ext.creep_accel_mps2, ext.creep_speed_mps, ext.lag_steer_s) == (0.5, 2.5, 0.3)


def test_the_qp_pattern_holds_every_entry_the_extensions_make():
    q = with_ext(report(), ALL_PHYSICS)
    c = MpcController(q)
    rng = np.random.default_rng(SEED)
    X, U = random_rows(c.N, rng)
    X = np.vstack([X, X[-1]])
    Ad, _, _ = linearise(c.plant, X, U, np.zeros(c.N, dtype=np.int64), c.dt)
    nz = {(i, j) for i in range(4) for j in range(4) if np.any(Ad[:, i, j] != 0)}
    assert (IV, IV) in nz  # the resistances' speed dependence reaches the QP
    assert nz <= set(APAT), nz - set(APAT)


def test_the_lag_is_exact_through_piecewise_constant_commands():
    times, values = [0.0, 0.13, 0.4], [1.0, -2.0, 0.5]
    tau, h = 0.3, 1e-4
    e, t = 1.0, 0.0
    while t < 0.7 - 1e-12:
        e = first_order_lag(e, values[int(np.searchsorted(times, t + 1e-12, "right")) - 1], h, tau)
        t += h
    assert _lag_through(1.0, 0.0, 0.7, times, values, tau) == pytest.approx(e, abs=1e-3)
    assert _lag_through(0.2, 0.5, 0.5, times, values, tau) == 0.2


# ------------------------------------------------------------------- closed loops
def truncated(ref: Reference, t_end_s: float) -> Reference:
    n = int(np.searchsorted(ref.time_s, ref.time_s[0] + t_end_s)) + 1
    return Reference(
        ref.time_s[:n],
        ref.x_m[:n],
        ref.y_m[:n],
        ref.heading_rad[:n],
        ref.speed_mps[:n],
        name=f"{ref.name}[:{t_end_s:g}s]",
    )


def track(model, truth, effects, ref, seed: int = 1) -> dict:
    res = run_closed_loop(
        MpcController(model),
        ref,
        model,
        plant_params=truth,
        control_period_s=0.1,
        seed=seed,
        effects=effects,
    )
    assert res.metrics["failures"] == 0
    return res.metrics


CLOSED_LOOPS = {  # effect in the truth, the same physics as the model's extension, scenario
    "steering_lag": (
        lambda: [fx.SteeringLag(0.3)],
        {"actuator_lag": {"steering": {"tau_s": 0.3}}},
        "figure8",
        40.0,
        "lateral_error_rms_m",
    ),
    "rack_cubic": (
        lambda: [fx.SteeringCubic(0.004)],
        {"steering_nonlinearity": {"steering": {"cubic_per_rad2": 0.004}}},
        "figure8",
        40.0,
        "lateral_error_rms_m",
    ),
    "aero_drag": (
        lambda: [fx.AeroDrag(4e-3)],
        {"aero_drag": {"longitudinal": {"coeff_per_m": 4e-3}}},
        "ramps",
        40.0,
        "speed_error_rms_mps",
    ),
    "idle_creep": (
        lambda: [fx2.IdleCreep(0.6, 2.0)],
        {"idle_creep": {"longitudinal": {"accel_mps2": 0.6, "creep_speed_mps": 2.0}}},
        "idle_hold",
        40.0,
        "speed_error_rms_mps",
    ),
}


@pytest.mark.parametrize("case", sorted(CLOSED_LOOPS))
def test_the_mpc_with_the_extension_tracks_a_truth_with_that_effect_better(case):
    make_effects, ext, scenario, t_end, key = CLOSED_LOOPS[case]
    truth = report()
    ref = truncated(make_scenario(scenario, truth), t_end)
    without = track(truth, truth, make_effects(), ref)
    given = track(with_ext(truth, ext), truth, make_effects(), ref)
    print(case, key, "without", without[key], "with", given[key])
    assert given[key] < 0.9 * without[key]
    other = "speed_error_rms_mps" if key == "lateral_error_rms_m" else "lateral_error_rms_m"
    assert given[other] <= 1.15 * without[other] + 0.01
