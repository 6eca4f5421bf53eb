"""The MPC step's vectorised helpers (controller/mpc/, controller/modes.py) against the
straightforward code they stand for: same values, to the bit.

They run every control step, so they are written for speed; each test below holds the plain version
(a loop, a per-block interpolation, NumPy's own routine) and checks the fast one against it
on seeded random data that reaches every branch.
"""

from __future__ import annotations

import numpy as np
import pytest

from _data import REPORT_PARAMS
from hmpc.controller.modes import ModeConfig, PedalMode, PedalModeLogic, next_mode
from hmpc.controller.mpc import MpcConfig, MpcController
from hmpc.controller.mpc.controller import _linspace6
from hmpc.controller.mpc.qp import QpLayout
from hmpc.models.params import load_params

SEED = 5


@pytest.fixture(scope="module")
def params():
    return load_params(REPORT_PARAMS, require_model=True)


def _shifted_blockwise(v, sh, blocks):
    """The warm start's shift as it was written first: one block at a time."""
    out = np.empty(len(v))
    for sl, width in blocks:
        block = v[sl].reshape(-1, width)
        n = len(block)
        pos = np.clip(np.arange(n) + sh, 0, n - 1)
        k0 = np.floor(pos).astype(np.int64)
        k1 = np.minimum(k0 + 1, n - 1)
        f = (pos - k0)[:, None]
        out[sl] = (block[k0] * (1 - f) + block[k1] * f).ravel()
    return out


@pytest.mark.parametrize("n_stages", [5, 50])
def test_warm_start_shift_is_the_blockwise_interpolation(n_stages):
    lay = QpLayout(n_stages, 0.2)
    rng = np.random.default_rng(SEED)
    y = rng.normal(size=lay.m)
    s = rng.normal(size=3 * n_stages)
    for sh in [0.0, 0.5, 0.4999999999999982, 1.0, 2.75, -0.3, n_stages + 3.0] + list(
        rng.uniform(0, 3, 20)
    ):
        for _ in range(2):  # the second call takes the cached interpolation
            assert np.array_equal(lay.dual_shift(y, sh), _shifted_blockwise(y, sh, lay.row_blocks))
            assert np.array_equal(
                lay.slack_shift(s, sh), _shifted_blockwise(s, sh, [(slice(0, len(s)), 3)])
            )


def test_linspace6_is_numpys():
    rng = np.random.default_rng(SEED)
    cases = [(5.0, 5.0), (0.0, 1e-320), (-3.0, 2.0)] + [
        (a, a + d) for a, d in zip(rng.uniform(0, 5000, 500), rng.uniform(0, 3, 500))
    ]
    for a, b in cases:
        assert np.array_equal(_linspace6(a, b), np.linspace(a, b, 6)), (a, b)


def _schedule_loop(logic, first, a, coast, dt, since, pedals):
    """PedalModeLogic.schedule as a plain loop over next_mode (its definition)."""
    c = logic.config
    out = np.empty(len(a), dtype=np.int8)
    mode, age = first, since
    out[0] = mode
    for k in range(1, len(a)):
        age += dt
        new = next_mode(mode, a[k], coast[k], c.accel_hysteresis_mps2)
        urgent = new == PedalMode.BRAKE and a[k] < coast[k] - c.urgent_mps2
        free = True
        if pedals is not None and new != mode:
            free = pedals[k, 0 if mode == PedalMode.THROTTLE else 1] <= 0.005
        if new != mode and ((age >= c.min_dwell_s and free) or urgent):
            mode, age = new, 0.0
        out[k] = mode
    return out


def test_pedal_schedule_is_the_plain_loop():
    rng = np.random.default_rng(SEED)
    logic = PedalModeLogic(ModeConfig())
    switched = fast = 0
    for trial in range(400):
        n = int(rng.integers(2, 60))
        scale = [0.05, 0.3, 1.5][trial % 3]  # quiet (no switch: the fast path) to busy
        a = rng.normal(0, scale, n)
        coast = (
            rng.choice([0.0, 0.3, -0.2], n)
            if trial % 5 == 0
            else np.full(n, rng.choice([0.0, 0.3, -0.2]))
        )
        pedals = None if trial % 4 == 0 else rng.choice([0.0, 0.003, 0.2], (n, 2))
        first = [PedalMode.THROTTLE, PedalMode.BRAKE, PedalMode.HOLD][trial % 3]
        since = float(rng.uniform(0, 2))
        got = logic.schedule(first, a, coast, 0.2, since, pedals)
        want = _schedule_loop(logic, first, a, coast, 0.2, since, pedals)
        assert got.dtype == np.int8 and np.array_equal(got, want), trial
        switched += bool(np.any(want != want[0]))
        h = logic.config.accel_hysteresis_mps2
        fast += bool(
            (first == PedalMode.BRAKE and not np.any(a[1:] > coast[1:] + h))
            or (first == PedalMode.THROTTLE and not np.any(a[1:] < coast[1:] - h))
        )
    assert fast > 40 and switched > 100  # both the fast path and the loop were exercised


def test_pedal_bounds_table_is_the_per_stage_formula(params):
    """QpConstraints.input_bounds with zones: the acceleration limits as bounds on the free
    pedal."""
    ctl = MpcController(params, MpcConfig())
    pl, lim, N = ctl.plant, ctl.limits, ctl.N
    rng = np.random.default_rng(SEED)
    modes = rng.choice([PedalMode.THROTTLE, PedalMode.BRAKE], N).astype(np.int8)
    zones = rng.integers(0, pl.n_zones, N)
    ulo, uhi, _srlo, _srhi = ctl.constraints.input_bounds(
        modes, zones, ctl.delay.fixed, ctl._last_cmd
    )
    thr = modes == PedalMode.THROTTLE
    off = pl.z_offset[zones]
    sc, br = np.maximum(pl.z_scale[zones], 1e-6), np.maximum(pl.z_brake[zones], 1e-6)
    ap_lo, ap_hi = (-lim.decel_max_mps2 - off) / sc, (lim.accel_max_mps2 - off) / sc
    bp_lo, bp_hi = (off - lim.accel_max_mps2) / br, (off + lim.decel_max_mps2) / br
    p_hi = np.clip(np.where(thr, ap_hi, bp_hi), 0.0, 1.0)
    p_lo = np.minimum(np.clip(np.where(thr, ap_lo, bp_lo), 0.0, 1.0), p_hi)
    assert np.array_equal(ulo[:, 1], np.where(thr, p_lo, 0.0))
    assert np.array_equal(uhi[:, 1], np.where(thr, p_hi, 0.0))
    assert np.array_equal(ulo[:, 2], np.where(thr, 0.0, p_lo))
    assert np.array_equal(uhi[:, 2], np.where(thr, 0.0, p_hi))
    assert np.all(ulo[:, 0] == -lim.steering_wheel_angle_max_rad)


def test_zone_schedule_is_the_plants_loop(params):
    """ZoneRules.schedule: zone0 throughout when the nominal stays in its hysteresis band (checked
    at once), else the plant's stage-by-stage rule; both as the plant's loop gives them."""
    ctl = MpcController(params, MpcConfig())
    pl, N = ctl.plant, ctl.N
    rng = np.random.default_rng(SEED)
    inside = 0
    for trial in range(300):
        zone0 = int(rng.integers(0, pl.n_zones))
        centre = 0.5 * (pl.v_min[zone0] + min(pl.v_max[zone0], pl.v_min[zone0] + 6.0))
        vb = centre + rng.normal(0, [0.05, 0.5, 3.0][trial % 3], N + 1)
        want = np.concatenate([[zone0], pl.zone_schedule(vb[1:N], zone0)])
        got = ctl.zone_rules.schedule(zone0, vb)
        assert got.dtype == want.dtype and np.array_equal(got, want), trial
        inside += bool(np.all(want == zone0))
    assert 30 < inside < 270  # both ways were taken
