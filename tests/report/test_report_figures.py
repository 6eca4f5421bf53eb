"""The identification figures (models/report/identification.py) show what the fit used: the
angle panels of Fig. 2 are scaled to the trusted samples (the standstill spikes of the measured
angle neither set the limits nor are drawn), a zone figure's time axis holds only that zone's
samples (and says so when it has none), the replay figure plots the position error against
time, and no legend sits over the data."""

from __future__ import annotations

import copy

import numpy as np
import pytest

from hmpc.models.identify.pipeline import concat_recordings, identify
from hmpc.models.identify.steering import SteeringIdConfig
from hmpc.models.params import load_params
from hmpc.models.report.identification import replay_figure, steering_figure, zone_axis, zone_figure
from hmpc.models.sim.simulator import simulate_experiment
from _data import REPORT_PARAMS

SEED = 3


@pytest.fixture(scope="module")
def result():
    truth = load_params(REPORT_PARAMS)
    rec = concat_recordings(
        [simulate_experiment(n, truth, seed=SEED) for n in ("arcs", "ramp_sequence")]
    )
    return identify(rec, truth.vehicle)


def _legends_clear_of_axes(fig) -> None:
    fig.tight_layout()
    r = fig.canvas.get_renderer()
    for ax in fig.axes:
        leg = ax.get_legend()
        if leg is None:
            continue
        lb = leg.get_window_extent(r)
        for other in fig.axes:  # twin axes share the box: every axes counts
            ab = other.get_window_extent(r)
            w = min(lb.x1, ab.x1) - max(lb.x0, ab.x0)
            h = min(lb.y1, ab.y1) - max(lb.y0, ab.y0)
            assert w <= 1 or h <= 1, f"legend of {ax.get_ylabel()!r} over the data"


def test_fig2_angle_panels_are_scaled_to_the_trusted_samples(result):
    s = result.steering.series
    trust = np.asarray(s["trustworthy"], bool)
    fl, fr = np.asarray(s["wheel_speed_fl"], float), np.asarray(s["wheel_speed_fr"], float)
    slow = 0.5 * (fl + fr) < SteeringIdConfig().v_min_mps
    fig = steering_figure(result)
    ax = fig.axes
    for a, key in zip(ax[3:5], ("delta_wheels_rad", "delta_yaw_rad")):
        m = np.degrees(np.asarray(s[key], float))
        vals = np.concatenate([m[trust], np.degrees(s["delta_model_rad"])[trust]])
        lo, hi = np.nanmin(vals), np.nanmax(vals)
        pad = 0.25 * (hi - lo)
        # the simulated arcs start and end at standstill: the measured angle spikes there,
        # beyond the limits asserted below (autoscaled limits would include the spikes)
        assert np.nanmax(np.abs(m[slow])) > max(hi, -lo) + pad
        y0, y1 = a.get_ylim()
        assert lo - pad <= y0 <= lo and hi <= y1 <= hi + pad, (a.get_title(), y0, y1, lo, hi)
        # nothing below the minimum speed is drawn, and the panel says so
        grey = a.get_lines()[0]
        assert np.all(np.isnan(np.asarray(grey.get_ydata(), float)[slow]))
        assert "not shown" in a.get_title()
    _legends_clear_of_axes(fig)
    assert "\n" in fig._suptitle.get_text()  # wrapped, not clipped at the figure's edges


def test_zone_axis_holds_only_the_zone_samples(result):
    lo = result.longitudinal
    t = np.asarray(lo.series["time"], float)
    t = t - t[0]
    for i in range(len(lo.zones)):
        used = np.asarray(lo.series["used"], bool) & (np.asarray(lo.series["zone"]) == i)
        if not used.any():
            continue
        fig = zone_figure(result, i)
        x0, x1 = fig.axes[2].get_xlim()
        x, cuts = zone_axis(t, used)
        assert np.all((x[used] >= x0) & (x[used] <= x1))
        dt = t[1] - t[0]
        span_samples = used.sum() * dt
        # the axis is the zone's samples plus the joins and small breaks, not the recording
        assert x1 - x0 < 0.5 * (t[-1] - t[0]) or span_samples > 0.3 * (t[-1] - t[0])
        assert x1 - x0 <= (np.nanmax(x) - np.nanmin(x)) * 1.05 + 2 * dt
        _legends_clear_of_axes(fig)
    # the idle zone of these experiments: a few seconds at each end of each experiment
    used0 = np.asarray(lo.series["used"], bool) & (np.asarray(lo.series["zone"]) == 0)
    x0, x1 = zone_figure(result, 0).axes[2].get_xlim()
    assert used0.sum() * (t[1] - t[0]) < 0.2 * t[-1] and x1 - x0 < 0.3 * t[-1]


def test_zone_axis_joins_runs_and_keeps_a_single_stretch_in_real_time():
    t = np.arange(0, 100, 0.1)
    used = ((t >= 10) & (t < 12)) | ((t >= 60) & (t < 63))
    x, cuts = zone_axis(t, used, join_gap_s=2.0)
    assert np.isnan(x[~used]).all()
    assert [c[1] for c in cuts] == pytest.approx([10.0, 60.0])
    assert np.nanmax(x) < 6.0  # 1.9 s + 2.9 s of samples and one small break
    one = (t >= 10) & (t < 12)
    x1, cuts1 = zone_axis(t, one)
    assert cuts1 == [] and np.allclose(x1[one], t[one])


def test_a_zone_without_samples_says_so(result):
    r = copy.copy(result)
    r.longitudinal = copy.copy(result.longitudinal)
    r.longitudinal.series = dict(result.longitudinal.series)
    r.longitudinal.series["used"] = np.zeros(len(result.longitudinal.series["time"]), bool)
    fig = zone_figure(r, 1)
    texts = [tx.get_text() for a in fig.axes for tx in a.texts]
    assert any("no samples" in tx for tx in texts)
    assert "NO SAMPLES" in fig._suptitle.get_text()


def test_replay_figure_plots_the_position_error_against_time(result):
    rp = result.steering.series["replay"]
    fig = replay_figure(result)
    err_ax = fig.axes[1]
    assert "error" in err_ax.get_ylabel() and "[m]" in err_ax.get_ylabel()
    y = np.asarray(err_ax.get_lines()[0].get_ydata(), float)
    err = np.hypot(np.asarray(rp["x_pred"]) - rp["x"], np.asarray(rp["y_pred"]) - rp["y"])
    ok = np.isfinite(y)
    assert ok.sum() > 0.5 * np.isfinite(err).sum()
    assert np.allclose(y[ok], err[ok])
    # the replay's own rms figure is of the same size as the plotted error
    rms = result.steering.fits["position_replay"].rms_error
    assert 0.2 * rms < np.sqrt(np.nanmean(err**2)) < 5 * rms
