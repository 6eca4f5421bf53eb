"""Figures of an identification, laid out like the report's Figs. 2-5 (matplotlib, own Agg canvas).

- ``fig2_steering.png`` (Fig. 2): turn rate from the front wheel-speed difference (eq. 5),
  the front wheel speeds, the steering-wheel angle, and the model's road-wheel angle (eq. 7)
  against the angle from the wheel speeds (eqs. 2-6) and from the yaw rate; panels of channels
  the recording lacks are left out. The measured angles are not drawn below the fit's minimum
  speed (they divide by the speed), and the angle panels are scaled to the samples the fit
  trusts: anything beyond is clipped, counted in the panel title. Angles in deg.
- ``steering_replay.png``: measured track against the eq. 1 replay windows (the refinement),
  and the position error of the replay against time (on a long, nearly straight road the path
  panel cannot show errors of a few decimetres; drawn at equal scale only while its extents
  differ by at most ``PATH_ASPECT_MAX``).
- ``fig3_idle.png``, ``fig4_low.png``, ``fig5_high.png`` (Figs. 3-5; one per zone, named by
  zone order for the default zones, ``zone_<name>.png`` otherwise): upper panel accelerator
  pedal, brake and speed; lower panels measured against modelled acceleration (eq. 8) and the
  speed reconstructed from the model. The time axis holds only the zone's samples: runs of
  zone samples more than ``JOIN_GAP_S`` apart are joined, the cuts marked by dotted lines
  labelled with the run's start time.

Plotting only: every number comes from the identification result. ``steering_figure``,
``replay_figure`` and ``zone_figure`` return the figure (tests inspect its axes); the
``plot_*`` functions write it.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from hmpc.models.identify.steering import SteeringIdConfig
from hmpc.models.report.figure import new_figure, save_png


_REPORT_FIG = {0: "fig3", 1: "fig4", 2: "fig5"}
#: [s] zone samples closer than this stay on one stretch of the time axis; longer gaps are cut.
JOIN_GAP_S = 2.0
#: [1] the path panel is drawn at equal scale only while its extents (east, north) differ by at
#: most this factor: a 1 km straight with 10 m of curvature at equal scale is an unreadable sliver.
PATH_ASPECT_MAX = 5.0


def _t(series) -> np.ndarray:
    t = np.asarray(series["time"], dtype=float)
    return t - t[0]


def _legend_right(ax, **kw) -> None:
    """Legend outside the axes, to their right: never over the data."""
    ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8, borderaxespad=0.0, **kw)


def _legend_above(ax, handles=None, ncol: int = 4) -> None:
    """Legend in one row just above the axes: never over the data."""
    kw = {} if handles is None else {"handles": handles}
    ax.legend(
        loc="lower left",
        bbox_to_anchor=(0.0, 1.01),
        ncol=ncol,
        fontsize=8,
        frameon=False,
        borderaxespad=0.0,
        **kw,
    )


def _trusted_limits(arrays, trust, pad: float = 0.1) -> tuple[float, float] | None:
    """(low, high) spanning ``arrays`` on the trusted samples, padded by ``pad`` of the span."""
    vals = np.concatenate([np.asarray(a, float)[trust] for a in arrays if a is not None])
    vals = vals[np.isfinite(vals)]
    if vals.size == 0:
        return None
    lo, hi = float(vals.min()), float(vals.max())
    span = max(hi - lo, 1e-3 * max(abs(lo), abs(hi)), 1e-6)
    return lo - pad * span, hi + pad * span


def steering_figure(result):
    """Fig. 2 as a figure: the steering model against the two measured road-wheel angles.

    Panels of channels the recording lacks are left out: without wheel speeds, the turn rate,
    the wheel speeds and the angle from them; without a yaw rate, the angle from it."""
    s = result.steering.series
    t = _t(s)
    st = result.steering
    fl = np.asarray(s["wheel_speed_fl"], float)
    fr = np.asarray(s["wheel_speed_fr"], float)
    have_wheels = bool(np.isfinite(fl).any() and np.isfinite(fr).any())
    measured = [
        (label, meas)
        for label, meas in (
            ("from wheel speeds (eqs. 2-6)", s.get("delta_wheels_rad")),
            ("from yaw rate, atan(L r / v)", s.get("delta_yaw_rad")),
        )
        if meas is not None and np.isfinite(np.asarray(meas, float)).any()
    ]
    if not measured:  # no measured angle (replay only): the model alone
        measured = [("model only (no measured road-wheel angle)", None)]
    n = (2 if have_wheels else 0) + 1 + len(measured)
    fig, ax = new_figure(n, 1, figsize=(12, 2.3 * n + 0.0), sharex=True, squeeze=False)
    ax = list(ax[:, 0])
    k = 0
    if have_wheels:
        ax[0].plot(t, s["turn_rate_wheels_radps"], lw=0.7)
        ax[0].set_ylabel("turn rate, eq. 5\n[rad/s]")
        ax[0].set_title("front wheel-speed difference / track width", fontsize=10)
        ax[1].plot(t, fl, lw=0.7, label="front left")
        ax[1].plot(t, fr, lw=0.7, label="front right")
        ax[1].set_ylabel("wheel speed [m/s]")
        _legend_right(ax[1])
        k = 2
    ax[k].plot(t, np.degrees(s["steering_wheel_angle"]), lw=0.7)
    # a car without a steering measurement: the map's input is the command (steering_cmd)
    ax[k].set_ylabel(
        "steering_cmd\n[deg]"
        if st.report.get("input") == "steering_cmd"
        else "steering-wheel\nangle [deg]"
    )
    trust = np.asarray(s["trustworthy"], dtype=bool)
    model = np.degrees(s["delta_model_rad"])
    # the measured angles divide by the speed: below the fit's minimum speed they are noise
    v_min = float(st.report.get("thresholds", {}).get("v_min_mps", SteeringIdConfig().v_min_mps))
    with np.errstate(invalid="ignore"):
        v_front = 0.5 * (fl + fr)
        slow = v_front < v_min
    have_speed = bool(np.isfinite(v_front).any())
    for a, (label, meas) in zip(ax[k + 1 :], measured):
        m = None if meas is None else np.degrees(np.asarray(meas, float))
        if m is not None:
            a.plot(t, np.where(slow, np.nan, m), lw=0.5, color="0.6", label=label)
        a.plot(t, np.where(trust, model, np.nan), lw=1.0, color="C3", label="model (eq. 7)")
        a.set_ylabel("road-wheel\nangle [deg]")
        lim = _trusted_limits([model] + ([] if m is None else [m]), trust)
        notes = [f"below {v_min:.3g} m/s not shown"] if have_speed and m is not None else []
        if lim is not None:
            a.set_ylim(*lim)
            if m is not None:
                with np.errstate(invalid="ignore"):
                    off = int(np.sum(~slow & ((m < lim[0]) | (m > lim[1]))))
                if off:
                    notes.append(f"{off} untrusted samples beyond the fitted range clipped")
        a.set_title(
            f"road-wheel angle {label.split(',')[0]} vs model"
            + (f" ({'; '.join(notes)})" if notes else ""),
            fontsize=9,
        )
        _legend_right(a)
    ax[-1].set_xlabel("time [s]")
    for a in ax:
        a.grid(True, alpha=0.3)
    verdict = "identifiable" if st.identifiable else "NOT identifiable"
    deg = np.degrees
    fig.suptitle(
        f"steering map (eq. 7): offset {deg(st.offset_rad):+.3f} deg "
        f"[{deg(st.offset_ci95_rad[0]):+.3f}, {deg(st.offset_ci95_rad[1]):+.3f}], scale "
        f"{st.scale:.4f} [{st.scale_ci95[0]:.4f}, {st.scale_ci95[1]:.4f}]\n"
        f"method {st.method}, {verdict}; model shown on trustworthy samples",
        fontsize=10,
    )
    return fig


def plot_steering(result, path: str | Path) -> str:
    """Write Fig. 2 (:func:`steering_figure`)."""
    return _save(steering_figure(result), path)


def replay_figure(result):
    """Measured track and the eq. 1 replay windows, and the replay's position error against
    time (None without positions)."""
    rp = result.steering.series.get("replay")
    if rp is None:
        return None
    t = _t(result.steering.series)
    x, y = np.asarray(rp["x"], float), np.asarray(rp["y"], float)
    xp, yp = np.asarray(rp["x_pred"], float), np.asarray(rp["y_pred"], float)
    err = np.hypot(xp - x, yp - y)
    # each window starts on the measured position (error 0): no line joins it to the window before
    err_line = np.where(np.isfinite(err) & (err < 1e-9), np.nan, err)
    fig, ax = new_figure(1, 2, figsize=(14, 6), gridspec_kw={"width_ratios": [1, 1.4]})
    ax[0].plot(x, y, lw=0.8, color="0.5", label="measured (INS/GNSS)")
    ax[0].plot(xp, yp, lw=1.0, color="C3", label="eq. 1 replay from each window start")
    ax[0].set_xlabel("east x [m]")
    ax[0].set_ylabel("north y [m]")
    ext = [float(np.nanmax(c) - np.nanmin(c)) if np.isfinite(c).any() else 0.0 for c in (x, y)]
    if min(ext) > 0 and max(ext) / min(ext) <= PATH_ASPECT_MAX:
        ax[0].set_aspect("equal", adjustable="datalim")
    else:  # a long straight at equal scale is a sliver: the axes are scaled apart, and say so
        ax[0].set_title(
            f"axes NOT to scale (the path spans {ext[0]:.0f} m east by {ext[1]:.0f} m north)",
            fontsize=9,
        )
    ax[0].legend(loc="best", fontsize=8)
    ax[1].plot(t, err_line, lw=1.0, color="C3")
    ax[1].set_xlabel("time [s]")
    ax[1].set_ylabel("position error of the replay [m]")
    ax[1].set_title(
        "distance between replayed and measured position (each window restarts at 0)", fontsize=10
    )
    ax[1].set_ylim(bottom=0.0)
    for a in ax:
        a.grid(True, alpha=0.3)
    fit = result.steering.fits.get("position_replay")
    if fit is not None:
        fig.suptitle(
            f"position replay: rms position error {fit.rms_error:.3f} m over "
            f"{fit.extra['windows']} windows of {fit.extra['window_s']:g} s",
            fontsize=11,
        )
    return fig


def plot_replay(result, path: str | Path) -> str | None:
    """Write the replay figure (:func:`replay_figure`; None without positions)."""
    fig = replay_figure(result)
    return None if fig is None else _save(fig, path)


def _runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """[start, end) index pairs of the runs of True in ``mask``."""
    idx = np.flatnonzero(np.diff(np.concatenate([[0], mask.astype(np.int8), [0]])))
    return list(zip(idx[::2].tolist(), idx[1::2].tolist()))


def zone_axis(t: np.ndarray, used: np.ndarray, join_gap_s: float = JOIN_GAP_S):
    """The time axis of a zone figure: (x per sample, NaN off the zone's stretches;
    [(x where a stretch starts, its real start time [s])], empty for a single stretch).

    Runs of zone samples less than ``join_gap_s`` apart form one stretch (drawn with the
    samples between them); stretches are laid end to end with a small break between them."""
    x = np.full(len(t), np.nan)
    runs = _runs(used)
    if not runs:
        return x, []
    stretches = [list(runs[0])]
    for a, e in runs[1:]:
        if t[a] - t[stretches[-1][1] - 1] < join_gap_s:
            stretches[-1][1] = e
        else:
            stretches.append([a, e])
    total = sum(t[e - 1] - t[a] for a, e in stretches)
    brk = max(0.02 * total, float(np.median(np.diff(t))) * 2)
    off, cuts = 0.0, []
    for k, (a, e) in enumerate(stretches):
        if k:
            off += brk
        cuts.append((off - 0.5 * brk if k else 0.0, float(t[a])))
        x[a:e] = off + (t[a:e] - t[a])
        off += t[e - 1] - t[a]
    if len(stretches) == 1:  # one stretch: keep the real time
        x[stretches[0][0] : stretches[0][1]] += t[stretches[0][0]]
        cuts = []
    return x, cuts


def zone_figure(result, zone_index: int):
    """Figs. 3-5 as a figure: one zone's inputs, measured vs modelled acceleration,
    reconstructed speed (None when the zone has no model series)."""
    lo = result.longitudinal
    s = lo.series
    z = lo.zones[zone_index]
    a_model_all = s["a_model_mps2"].get(z.name)
    if a_model_all is None:
        return None
    t = _t(s)
    used = np.asarray(s["used"], dtype=bool) & (np.asarray(s["zone"]) == zone_index)
    nm = "n/a" if z.nmse_pct is None else f"{z.nmse_pct:.1f}%"
    sr = "n/a" if z.speed_rmse_mps is None else f"{z.speed_rmse_mps:.3f} m/s"
    title = (
        f"zone {z.name} ({z.v_min_mps:g}, {z.v_max_mps:g}] m/s: a = "
        f"{z.offset_mps2:+.3f} + {z.scale_mps2:.3f} * accel_pedal - "
        f"{z.brake_scale_mps2:.3f} * brake_pedal [m/s^2]\nNMSE {nm}, speed RMSE {sr}"
        f"{'' if z.identifiable else ' (NOT identifiable)'}"
    )
    dt = float(np.median(np.diff(s["time"])))
    fig, ax = new_figure(3, 1, figsize=(11, 9), sharex=True)
    if not used.any():
        x, cuts = t, []
        ax[2].set_xlabel("time [s]")
        for a in ax[1:]:
            a.text(
                0.5,
                0.5,
                f"no samples in zone {z.name} ({z.v_min_mps:g}, {z.v_max_mps:g}] m/s",
                transform=a.transAxes,
                ha="center",
                va="center",
            )
        title += "; NO SAMPLES in this zone"
    else:
        x, cuts = zone_axis(t, used)
        n_s = used.sum() * dt
        ax[2].set_xlabel(
            f"time [s] ({n_s:.1f} s of zone samples)"
            if not cuts
            else f"time within the zone's stretches [s] ({n_s:.1f} s of zone samples; "
            f"gaps cut at the dotted lines, labelled with the real start time)"
        )
    # upper panel: the inputs and the speed on the zone's stretches
    h = ax[0].plot(x, s["accel_pedal"], lw=0.8, label="accelerator pedal [0..1]")
    if s.get("brake_pedal") is not None:
        h += ax[0].plot(x, s["brake_pedal"], lw=0.8, label="brake pedal [0..1]")
    ax0b = ax[0].twinx()
    h += ax0b.plot(x, s["v_mps"], lw=0.8, color="k", label="speed [m/s]")
    h.append(
        ax0b.axhspan(z.v_min_mps, z.v_max_mps, color="C2", alpha=0.08, label="zone speed range")
    )
    ax0b.set_ylabel("speed [m/s]")
    ax[0].set_ylabel("pedal [0..1]")
    _legend_above(ax[0], handles=h)
    if used.any():
        a_meas = np.where(used, s["a_meas_mps2"], np.nan)
        a_mod = np.where(used, a_model_all, np.nan)
        ax[1].plot(x, a_meas, lw=0.8, color="0.4", label="measured")
        ax[1].plot(x, a_mod, lw=1.0, color="C3", label="model (eq. 8 + brake)")
        _legend_above(ax[1])
        tt, vv = _reconstructed_speed(lo, z, s, used, x, dt)
        ax[2].plot(x, np.where(used, s["v_mps"], np.nan), lw=0.8, color="0.4", label="measured")
        ax[2].plot(
            tt,
            vv,
            lw=1.0,
            color="C3",
            label="integrated from the model (restarted every run / 10 s)",
        )
        _legend_above(ax[2])
        lo_x, hi_x = float(np.nanmin(x[used])), float(np.nanmax(x[used]))
        pad = max(0.01 * (hi_x - lo_x), dt)
        ax[2].set_xlim(lo_x - pad, hi_x + pad)
    ax[1].set_ylabel("acceleration [m/s^2]")
    ax[2].set_ylabel("speed [m/s]")
    for k, (xc, t_start) in enumerate(cuts[:12]):
        if k:
            for a in ax:
                a.axvline(xc, color="0.3", ls=":", lw=0.8)
        ax[2].annotate(
            f"{t_start:.1f} s",
            (xc, 0.0),
            xycoords=("data", "axes fraction"),
            xytext=(2, 2),
            textcoords="offset points",
            fontsize=7,
            color="0.3",
        )
    for a in ax:
        a.grid(True, alpha=0.3)
    fig.suptitle(title, fontsize=10)
    return fig


def _reconstructed_speed(lo, z, s, used, x, dt):
    """Speed integrated from the zone model over runs of zone samples, restarted from the
    measured speed every run and every 10 s (as ``speed_rmse_mps``): (x, v) with NaN breaks."""
    v = np.asarray(s["v_mps"], dtype=float)
    ap = np.nan_to_num(np.asarray(s["accel_pedal"], dtype=float))
    bp = (
        np.zeros_like(ap)
        if s.get("brake_pedal") is None
        else np.nan_to_num(np.asarray(s["brake_pedal"], dtype=float))
    )
    shift = int(round(lo.dead_time_s / dt))
    if shift:
        ap = np.concatenate([np.zeros(shift), ap[:-shift]])
        bp = np.concatenate([np.zeros(shift), bp[:-shift]])
    a_raw = z.offset_mps2 + z.scale_mps2 * ap - z.brake_scale_mps2 * bp
    tt, vv = [], []
    seg = max(int(round(10.0 / dt)), 2)
    for a0, e0 in _runs(used):
        for a in range(a0, e0, seg):
            e = min(a + seg, e0)
            aa = a_raw[a:e]
            vv += list(
                np.maximum(
                    v[a] + np.concatenate([[0.0], np.cumsum(0.5 * dt * (aa[1:] + aa[:-1]))]), 0.0
                )
            ) + [np.nan]
            tt += list(x[a:e]) + [np.nan]  # NaN: a new run starts from the measured speed
    return tt, vv


def plot_zone(result, zone_index: int, path: str | Path) -> str | None:
    """Write Figs. 3-5 for one zone (:func:`zone_figure`; None without a zone model)."""
    fig = zone_figure(result, zone_index)
    return None if fig is None else _save(fig, path)


def _save(fig, path: str | Path) -> str:
    """Lay out and write the PNG."""
    return save_png(fig, path, dpi=100)


def write_plots(result, out_dir: str | Path) -> list[str]:
    """Write every figure of ``result`` (an ``IdentifyResult``) into ``out_dir``; return paths."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    paths = []
    if result.steering is not None:
        paths.append(plot_steering(result, out / "fig2_steering.png"))
        p = plot_replay(result, out / "steering_replay.png")
        if p:
            paths.append(p)
    if result.longitudinal is None:
        return paths
    default_names = [z.name for z in result.longitudinal.zones] == ["idle", "low", "high"]
    for i, z in enumerate(result.longitudinal.zones):
        name = f"{_REPORT_FIG[i]}_{z.name}.png" if default_names else f"zone_{z.name}.png"
        p = plot_zone(result, i, out / name)
        if p:
            paths.append(p)
    return paths
