"""Figures of an identification, laid out like the report's Figs. 2-5 (matplotlib, own Agg canvas).

- ``fig2_steering.png`` (Fig. 2): turn rate from the front wheel-speed difference (eq. 5),
  the front wheel speeds, the steering-wheel angle, and the model's road-wheel angle (eq. 7)
  against the angle from the wheel speeds (eqs. 2-6) and from the yaw rate.
- ``steering_replay.png``: measured track against the eq. 1 replay windows (the refinement).
- ``fig3_idle.png``, ``fig4_low.png``, ``fig5_high.png`` (Figs. 3-5; one per zone, named by
  zone order for the default zones, ``zone_<name>.png`` otherwise): upper panel accelerator
  pedal, brake and speed; lower panels measured against modelled acceleration (eq. 8) and the
  speed reconstructed from the model.

Plotting only: every number comes from the identification result.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from hmpc.models.report.figure import new_figure, save_png


_REPORT_FIG = {0: "fig3", 1: "fig4", 2: "fig5"}


def _t(series) -> np.ndarray:
    t = np.asarray(series["time"], dtype=float)
    return t - t[0]


def plot_steering(result, path: str | Path) -> str:
    """Fig. 2: the steering model against the two measured road-wheel angles."""
    s = result.steering.series
    t = _t(s)
    st = result.steering
    fig, ax = new_figure(5, 1, figsize=(10, 11), sharex=True)
    ax[0].plot(t, s["turn_rate_wheels_radps"], lw=0.7)
    ax[0].set_ylabel("turn rate, eq. 5 [rad/s]")
    ax[0].set_title("front wheel-speed difference / track width")
    ax[1].plot(t, s["wheel_speed_fl"], lw=0.7, label="front left")
    ax[1].plot(t, s["wheel_speed_fr"], lw=0.7, label="front right")
    ax[1].set_ylabel("wheel speed [m/s]")
    ax[1].legend(loc="upper right", fontsize=8)
    ax[2].plot(t, np.degrees(s["steering_wheel_angle"]), lw=0.7)
    ax[2].set_ylabel("steering-wheel angle [deg]")
    trust = np.asarray(s["trustworthy"], dtype=bool)
    model = np.degrees(s["delta_model_rad"])
    ax[3].plot(t, np.degrees(s["delta_wheels_rad"]), lw=0.5, color="0.6",
               label="from wheel speeds (eqs. 2-6)")
    ax[3].plot(t, np.where(trust, model, np.nan), lw=1.0, color="C3", label="model (eq. 7)")
    ax[3].set_ylabel("road-wheel angle [deg]")
    ax[3].legend(loc="upper right", fontsize=8)
    if s.get("delta_yaw_rad") is not None:
        ax[4].plot(t, np.degrees(s["delta_yaw_rad"]), lw=0.5, color="0.6",
                   label="from yaw rate, atan(L r / v)")
    ax[4].plot(t, np.where(trust, model, np.nan), lw=1.0, color="C3", label="model (eq. 7)")
    ax[4].set_ylabel("road-wheel angle [deg]")
    ax[4].set_xlabel("time [s]")
    ax[4].legend(loc="upper right", fontsize=8)
    for a in ax:
        a.grid(True, alpha=0.3)
    verdict = "identifiable" if st.identifiable else "NOT identifiable"
    fig.suptitle(f"steering map: offset {st.offset_rad:+.4f} rad "
                 f"[{st.offset_ci95_rad[0]:+.4f}, {st.offset_ci95_rad[1]:+.4f}], scale "
                 f"{st.scale:.4f} [{st.scale_ci95[0]:.4f}, {st.scale_ci95[1]:.4f}] "
                 f"({st.method}, {verdict}); model shown on trustworthy samples", fontsize=9)
    return _save(fig, path)


def plot_replay(result, path: str | Path) -> str | None:
    """Measured track and the eq. 1 replay windows of the refinement (None without positions)."""
    rp = result.steering.series.get("replay")
    if rp is None:
        return None
    fig, ax = new_figure(figsize=(8, 8))
    ax.plot(rp["x"], rp["y"], lw=0.8, color="0.5", label="measured (INS/GNSS)")
    ax.plot(rp["x_pred"], rp["y_pred"], lw=1.0, color="C3", label="eq. 1 replay from each window start")
    ax.set_xlabel("east x [m]")
    ax.set_ylabel("north y [m]")
    ax.set_aspect("equal", adjustable="datalim")
    ax.grid(True, alpha=0.3)
    ax.legend(loc="best", fontsize=8)
    fit = result.steering.fits.get("position_replay")
    if fit is not None:
        ax.set_title(f"position replay: rms position error {fit.rms_error:.3f} m over "
                     f"{fit.extra['windows']} windows of {fit.extra['window_s']:g} s")
    return _save(fig, path)


def plot_zone(result, zone_index: int, path: str | Path) -> str | None:
    """Figs. 3-5: one zone's inputs, measured vs modelled acceleration, reconstructed speed."""
    lo = result.longitudinal
    s = lo.series
    z = lo.zones[zone_index]
    a_model_all = s["a_model_mps2"].get(z.name)
    if a_model_all is None:
        return None
    t = _t(s)
    used = np.asarray(s["used"], dtype=bool) & (np.asarray(s["zone"]) == zone_index)
    a_meas = np.where(used, s["a_meas_mps2"], np.nan)
    a_mod = np.where(used, a_model_all, np.nan)
    fig, ax = new_figure(3, 1, figsize=(10, 8), sharex=True)
    ax[0].plot(t, s["accel_pedal"], lw=0.8, label="accelerator pedal [0..1]")
    if s.get("brake_pedal") is not None:
        ax[0].plot(t, s["brake_pedal"], lw=0.8, label="brake pedal [0..1]")
    ax0b = ax[0].twinx()
    ax0b.plot(t, s["v_mps"], lw=0.8, color="k", label="speed")
    ax0b.axhspan(z.v_min_mps, z.v_max_mps, color="C2", alpha=0.08)
    ax0b.set_ylabel("speed [m/s]")
    ax[0].set_ylabel("pedal [0..1]")
    ax[0].legend(loc="upper left", fontsize=8)
    ax[1].plot(t, a_meas, lw=0.8, color="0.4", label="measured")
    ax[1].plot(t, a_mod, lw=1.0, color="C3", label="model (eq. 8 + brake)")
    ax[1].set_ylabel("acceleration [m/s^2]")
    ax[1].legend(loc="upper right", fontsize=8)
    # speed reconstructed over runs of zone samples (as speed_rmse_mps)
    v = np.asarray(s["v_mps"], dtype=float)
    ap = np.nan_to_num(np.asarray(s["accel_pedal"], dtype=float))
    bp = np.zeros_like(ap) if s.get("brake_pedal") is None else \
        np.nan_to_num(np.asarray(s["brake_pedal"], dtype=float))
    dt = float(np.median(np.diff(s["time"])))
    tau = lo.dead_time_s
    shift = int(round(tau / dt))
    if shift:
        ap = np.concatenate([np.zeros(shift), ap[:-shift]])
        bp = np.concatenate([np.zeros(shift), bp[:-shift]])
    a_raw = z.offset_mps2 + z.scale_mps2 * ap - z.brake_scale_mps2 * bp
    tt, vv = [], []
    idx = np.flatnonzero(np.diff(np.concatenate([[0], used.astype(np.int8), [0]])))
    seg = max(int(round(10.0 / dt)), 2)
    for a0, e0 in zip(idx[::2], idx[1::2]):
        for a in range(a0, e0, seg):
            e = min(a + seg, e0)
            aa = a_raw[a:e]
            vv += list(np.maximum(v[a] + np.concatenate(
                [[0.0], np.cumsum(0.5 * dt * (aa[1:] + aa[:-1]))]), 0.0)) + [np.nan]
            tt += list(t[a:e]) + [np.nan]  # NaN: a new run starts from the measured speed
    ax[2].plot(t, np.where(used, v, np.nan), lw=0.8, color="0.4", label="measured")
    ax[2].plot(tt, vv, lw=1.0, color="C3",
               label="integrated from the model (restarted every run / 10 s)")
    ax[2].set_ylabel("speed [m/s]")
    ax[2].set_xlabel("time [s]")
    ax[2].legend(loc="upper right", fontsize=8)
    for a in ax:
        a.grid(True, alpha=0.3)
    nm = "n/a" if z.nmse_pct is None else f"{z.nmse_pct:.1f}%"
    sr = "n/a" if z.speed_rmse_mps is None else f"{z.speed_rmse_mps:.3f} m/s"
    fig.suptitle(f"zone {z.name} ({z.v_min_mps:g}, {z.v_max_mps:g}] m/s: a = "
                 f"{z.offset_mps2:+.3f} + {z.scale_mps2:.3f} accel - {z.brake_scale_mps2:.3f} "
                 f"brake [m/s^2]; NMSE {nm}, speed RMSE {sr}"
                 f"{'' if z.identifiable else ' (NOT identifiable)'}", fontsize=9)
    return _save(fig, path)


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
