"""Clock alignment (known offsets injected and recovered) and resampling onto the grid."""

import numpy as np
import pytest

from hmpc.models.logs.align import estimate_offset
from hmpc.models.logs.canlog import read_log
from hmpc.models.logs.dbc import load_dbc
from hmpc.models.logs.decode import decode_frames
from hmpc.models.errors import Problems
from hmpc.models.logs.nav import read_imu_raw, read_nav
from hmpc.models.logs.resample import find_gaps, gap_threshold_s, make_grid, resample
from _data import bundled

SEED = 20240611


# ----------------------------------------------------------------------------- simulated pair
@pytest.mark.parametrize("true_offset_s", [0.0, 0.237, -1.613, 3.05])
def test_simulated_offset_recovered_to_a_fraction_of_a_sample(true_offset_s):
    """A smooth speed profile seen by two loggers at different rates and clocks."""
    rng = np.random.default_rng(SEED)
    print(f"seed {SEED}")
    knots = np.cumsum(rng.normal(0, 1.0, 40)) + 15.0

    def speed(t):  # m/s, smooth (cubic-free: linear between 1.5 s knots, then smoothed)
        return np.interp(t, np.arange(40) * 1.5, knots) + 0.3 * np.sin(1.7 * t)

    t_can = np.sort(rng.uniform(0, 58, 4800))  # ~83 Hz with jitter
    t_nav = np.arange(0, 58, 0.05)
    v_can = np.round(speed(t_can) / (0.01 / 3.6)) * (0.01 / 3.6)  # 0.01 km/h quantisation
    v_nav = speed(t_nav) + rng.normal(0, 0.02, len(t_nav))
    # the nav logger's clock reads (true time - offset): adding the offset maps it back
    est = estimate_offset(t_can, v_can, t_nav - true_offset_s, v_nav, what="speed")
    assert est.ok, est.note
    assert est.offset_s == pytest.approx(true_offset_s, abs=0.004)  # 1/5 of a 50 Hz grid step
    assert est.peak > 0.99


def test_no_overlap_or_no_variation_is_reported_not_ok():
    t = np.linspace(0, 10, 500)
    est = estimate_offset(t, np.sin(t), t + 100, np.sin(t))
    assert not est.ok and est.offset_s == 0.0
    est = estimate_offset(t, np.ones_like(t), t, np.ones_like(t))
    assert not est.ok
    with pytest.raises(ValueError):
        estimate_offset(t, t, t, t, rate_hz=0)


def test_offset_beyond_window_is_flagged():
    t = np.linspace(0, 60, 3000)
    v = np.sin(0.3 * t) + 0.5 * np.sin(1.1 * t)
    est = estimate_offset(t, v, t - 8.0, v, max_lag_s=2.0)
    assert not est.ok and "edge" in est.note


# ----------------------------------------------------------------------------- real pair
@pytest.fixture(scope="module")
def comma_pair(comma_log, comma_dbc):
    p = Problems()
    frames = read_log(comma_log, p)
    dec = decode_frames(
        frames, load_dbc(comma_dbc), p, names=["WHEEL_SPEEDS", "KINEMATICS"], buses=[0]
    )
    w = dec["WHEEL_SPEEDS"]
    v_can = (
        sum(
            w.signals[s]
            for s in ("WHEEL_SPEED_FL", "WHEEL_SPEED_FR", "WHEEL_SPEED_RL", "WHEEL_SPEED_RR")
        )
        / 4
        / 3.6
    )
    nav = read_nav(bundled("rav4-comma2k19/nav.csv.gz"), p)
    imu = read_imu_raw(bundled("rav4-comma2k19/imu.csv.gz"), p)
    return w.t_s, v_can, nav, imu


def test_real_can_vs_gnss_offset_is_small(comma_pair):
    t_can, v_can, nav, _ = comma_pair
    est = estimate_offset(t_can, v_can, *nav["gps_speed"], what="speed")
    assert est.ok and est.peak > 0.99
    assert abs(est.offset_s) < 0.1  # the comma logger stamps both with the same clock


@pytest.mark.parametrize("injected_s", [0.37, -1.234, 2.5])
def test_real_injected_offset_recovered(comma_pair, injected_s):
    t_can, v_can, nav, _ = comma_pair
    tg, vg = nav["gps_speed"]
    base = estimate_offset(t_can, v_can, tg, vg, what="speed").offset_s
    est = estimate_offset(t_can, v_can, tg - injected_s, vg, what="speed")
    assert est.ok
    assert est.offset_s - base == pytest.approx(injected_s, abs=0.01)


@pytest.mark.parametrize("injected_s", [0.0, 0.21, -0.8])
def test_imu_aligned_to_nav_by_yaw_rate(comma_pair, injected_s):
    """Same device: the IMU's yaw rate lines up with the INS heading rate at the injected offset."""
    _, _, nav, imu = comma_pair
    th, h = nav["heading"]
    est = estimate_offset(
        th,
        np.gradient(np.unwrap(h), th),
        imu.t_s - injected_s,
        imu.yaw_rate_device(),
        what="yaw rate",
    )
    assert est.ok and est.peak > 0.9
    assert est.offset_s == pytest.approx(injected_s, abs=0.02)


# ----------------------------------------------------------------------------- resampling
def test_grid():
    g = make_grid(10.0, 11.0, 50.0)
    assert len(g) == 51 and g[0] == 10.0 and g[-1] == pytest.approx(11.0)
    with pytest.raises(ValueError):
        make_grid(0, 1, -5)


def test_linear_resampling_is_exact_on_a_line_and_nan_outside():
    t = np.array([0.0, 0.1, 0.2, 0.35])
    v = 2.0 * t + 1.0
    g = np.arange(-0.1, 0.5, 0.02)
    out, gaps = resample(t, v, g, "linear")
    inside = (g >= 0) & (g <= 0.35)
    np.testing.assert_allclose(out[inside], 2.0 * g[inside] + 1.0)
    assert np.isnan(out[~inside]).all() and gaps == []


def test_gaps_are_nan_not_interpolated():
    t = np.concatenate([np.arange(0, 1, 0.01), np.arange(2.0, 3.0, 0.01)])
    v = np.sin(t)
    g = make_grid(0.0, 2.99, 50.0)
    out, gaps = resample(t, v, g, "linear")
    assert len(gaps) == 1
    assert gaps[0].start_s == pytest.approx(0.99) and gaps[0].end_s == pytest.approx(2.0)
    in_gap = (g > 0.99) & (g < 2.0)
    assert np.isnan(out[in_gap]).all()
    assert np.isfinite(out[~in_gap]).all()
    # default threshold: max(0.5 s, 5 median periods)
    assert gap_threshold_s(t) == 0.5
    assert gap_threshold_s(np.arange(0, 10, 1.0)) == 5.0
    assert find_gaps(np.arange(0, 10, 1.0), 5.0) == []
    # an explicit threshold wins
    _, gaps = resample(t, v, g, "linear", gap_s=2.0)
    assert gaps == []


def test_hold_and_string_hold_previous_sample():
    t = np.array([0.0, 0.5, 1.0])
    out, _ = resample(
        t, np.array([0.0, 1.0, 0.0]), np.array([0.0, 0.2, 0.5, 0.7, 1.0, 1.2]), "hold"
    )
    np.testing.assert_array_equal(out[:5], [0.0, 0.0, 1.0, 1.0, 0.0])
    assert np.isnan(out[5])
    gear, _ = resample(
        t, np.array(["P", "R", "D"], dtype=object), np.array([-0.1, 0.1, 0.6, 1.0]), "string"
    )
    assert list(gear) == ["", "P", "R", "D"]


def test_angle_resampling_unwraps_across_pi():
    t = np.array([0.0, 1.0])
    v = np.array([np.pi - 0.1, -np.pi + 0.1])  # +0.2 rad through +-pi
    out, _ = resample(t, v, np.array([0.0, 0.25, 0.5, 0.75, 1.0]), "angle")
    want = np.angle(np.exp(1j * (np.pi - 0.1 + 0.2 * np.array([0, 0.25, 0.5, 0.75, 1.0]))))
    np.testing.assert_allclose(np.angle(np.exp(1j * (out - want))), 0, atol=1e-12)
    assert np.all(np.abs(out) <= np.pi)


def test_nonfinite_raw_samples_are_dropped():
    t = np.array([0.0, 0.1, 0.2, 0.3])
    v = np.array([0.0, np.nan, 2.0, 3.0])
    out, _ = resample(t, v, np.array([0.1, 0.25]), "linear")
    np.testing.assert_allclose(out, [1.0, 2.5])
