"""Figures of closed-loop runs: ``hmpc simulate``'s run and ``hmpc replay``'s two modes.

Each function takes a finished run and writes labelled PNGs (units on every axis) on its own
Agg canvas (``models.report.figure``); it computes nothing the run did not already hold.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from hmpc.models.report.figure import new_figure, save_png


def _smoothness_panel(ax, t, ch, m, upd) -> None:
    """The commands' rates (steering wheel [rad/s] left, pedals [1/s] right) with the
    smoothness figures written on the panel. A rate is a command's change at a
    control update (recording samples ``upd``) over the time since the previous one: the
    commands are held in between, and differences at the recording's rate would show each
    change as a spike period/dt times the rate."""
    tu = t[upd]
    dt = np.diff(tu)

    def rate(name):
        return np.diff(ch[name][upd]) / dt

    # each rate held over the period that ends at its update
    ax.step(
        tu[1:],
        rate("steering_cmd"),
        where="pre",
        color="C0",
        lw=0.8,
        label="steering-wheel cmd rate",
    )
    ax.set_ylabel("steering-wheel rate [rad/s]")
    ax2 = ax.twinx()
    ax2.step(
        tu[1:],
        rate("accel_pedal_cmd"),
        where="pre",
        color="C2",
        lw=0.8,
        label="accel pedal cmd rate",
    )
    ax2.step(
        tu[1:],
        rate("brake_pedal_cmd"),
        where="pre",
        color="C3",
        lw=0.8,
        label="brake pedal cmd rate",
    )
    ax2.set_ylabel("pedal rate [1/s]")
    rv = m["steering_reversals_per_min"]
    ax.text(
        0.01,
        0.95,
        f"steering reversals >= 1 deg: {rv['1deg']:.1f}/min, >= 5 deg: "
        f"{rv['5deg']:.1f}/min; steering rate RMS {m['steering_rate_rms_radps']:.3f} rad/s; "
        f"pedal rate RMS accel {m['accel_pedal_rate_rms_ps']:.3f} /s, brake "
        f"{m['brake_pedal_rate_rms_ps']:.3f} /s",
        transform=ax.transAxes,
        va="top",
        fontsize=8,
        bbox={"facecolor": "white", "alpha": 0.8, "lw": 0},
    )
    h1, l1 = ax.get_legend_handles_labels()
    h2, l2 = ax2.get_legend_handles_labels()
    ax.legend(h1 + h2, l1 + l2, loc="lower right", fontsize=8)


def plot_closed_loop(res, ref, out_dir: str | Path, controller: str, zones, updates) -> list[str]:
    """A closed-loop run as labelled PNGs (units on every axis); returns the file names.

    Args:
        res: the run (``controller.closed_loop.ClosedLoopResult``: its recording, speed
            reference, lateral error, zones and metrics).
        ref: the reference it followed.
        out_dir: folder the PNGs are written to.
        controller: the controller's name, for the titles.
        zones: (name, v_min [m/s], v_max [m/s]) per zone index, the zone axis's ticks.
        updates: indices of the recording's samples at the control updates.
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    ch = res.recording.channels
    t = ch["time"]
    files = []
    fig, ax = new_figure(6, 1, figsize=(10, 14), sharex=True)
    ax[0].plot(t, res.speed_ref_mps, "k--", label="reference")
    ax[0].plot(t, ch["speed"], label="speed")
    ax[0].set_ylabel("speed [m/s]")
    ax[0].legend(loc="best")
    ax[1].plot(t, res.lateral_error_m)
    ax[1].set_ylabel("lateral error [m]")
    ax[2].plot(t, ch["accel_pedal_cmd"], label="accelerator (cmd)")
    ax[2].plot(t, ch["brake_pedal_cmd"], label="brake (cmd)")
    ax[2].set_ylabel("pedal [0..1]")
    ax[2].legend(loc="best")
    ax[3].plot(t, ch["steering_cmd"], label="command")
    ax[3].plot(t, ch["steering_wheel_angle"], label="applied")
    ax[3].set_ylabel("steering-wheel angle [rad]")
    ax[3].legend(loc="best")
    m = res.metrics
    _smoothness_panel(ax[4], t, ch, m, updates)
    ax[5].step(t, res.zone, where="post")
    ax[5].set_yticks(range(len(zones)), [f"{n} ({lo:g}-{hi:g} m/s)" for n, lo, hi in zones])
    ax[5].set_ylabel("plant zone")
    ax[5].set_xlabel("time [s]")
    fig.suptitle(
        f"{controller} on {ref.name}: speed RMS {m['speed_error_rms_mps']:.3f} m/s, "
        f"lateral RMS {m['lateral_error_rms_m']:.3f} m, "
        f"{m['pedal_switches_per_min']:.1f} pedal switches/min"
    )
    files.append(save_png(fig, out / "closed_loop.png", dpi=90))
    fig, ax = new_figure(figsize=(7, 7))
    ax.plot(ref.x_m, ref.y_m, "k--", label="reference path")
    ax.plot(ch["x"], ch["y"], label="driven")
    ax.set_xlabel("x (east) [m]")
    ax.set_ylabel("y (north) [m]")
    ax.set_aspect("equal", adjustable="datalim")
    ax.legend(loc="best")
    ax.set_title(f"{controller} on {ref.name}: path")
    files.append(save_png(fig, out / "path.png", dpi=90))
    return files


def _shade(ax, windows, color="C3") -> None:
    """Shade the windows where the two differ most (the JSON's ``windows``)."""
    for i, w in enumerate(windows):
        ax.axvspan(
            w["t0_s"],
            w["t1_s"],
            color=color,
            alpha=0.12,
            label="largest differences" if i == 0 else None,
        )


def _panels(rows: int):
    return new_figure(rows, 1, figsize=(10, 2.6 * rows), sharex=True)


def plot_reference_replay(rr, out_dir: str | Path, controller: str, zones=()) -> list[str]:
    """Controller on the plant against the car: speed, distance from the driven path,
    steering-wheel angle, pedals, zones (labelled PNGs, units on every axis; ``zones``:
    (name, v_min, v_max) per zone index, the zone axis's tick labels)."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    ch, car, win = rr.run.recording.channels, rr.car, rr.summary["windows"]
    t = ch["time"]
    fig, ax = _panels(5)
    ax[0].plot(t, car["speed_mps"], "k--", label="car (recorded)")
    ax[0].plot(t, ch["speed"], label=f"{controller} on the identified plant")
    _shade(ax[0], win["speed_mps"])
    ax[0].set_ylabel("speed [m/s]")
    ax[1].plot(t, rr.run.lateral_error_m, color="C1")
    _shade(ax[1], win["lateral_m"])
    ax[1].set_ylabel("distance from the\ndriven path [m]")
    ax[2].plot(t, np.degrees(car["steering_wheel_angle_rad"]), "k--", label="car (recorded)")
    ax[2].plot(t, np.degrees(ch["steering_wheel_angle"]), label=controller)
    _shade(ax[2], win["steering_wheel_angle_rad"])
    ax[2].set_ylabel("steering-wheel angle [deg]")
    ax[3].plot(t, car["accel_pedal"], "k--", label="car accelerator")
    ax[3].plot(t, ch["accel_pedal_cmd"], label=f"{controller} accelerator")
    ax[3].plot(t, ch["brake_pedal_cmd"], label=f"{controller} brake")
    ax[3].set_ylabel("pedal [0..1]")
    ax[4].step(t, car["zone"], "k--", where="post", label="car")
    ax[4].step(t, rr.run.zone, where="post", label=controller)
    ax[4].set_ylabel("speed zone")
    if zones:
        ax[4].set_yticks(
            range(len(zones)), [f"{n} ({lo:g}-{hi:g} m/s)" for n, lo, hi in zones], fontsize=8
        )
    ax[4].set_xlabel("time from the recording's start [s]")
    for a in ax:
        a.legend(loc="best", fontsize=8)
    k = rr.summary["kpis"]["controller"]
    fig.suptitle(
        f"reference replay, {controller}: speed error RMS {k['speed_error_rms_mps']:.3f} "
        f"m/s, lateral RMS {k['lateral_error_rms_m']:.3f} m"
    )
    files = [save_png(fig, out / "replay_reference.png", dpi=90)]
    fig, a = new_figure(figsize=(7, 7))
    a.plot(rr.reference.x_m, rr.reference.y_m, "k--", label="car (recorded path)")
    a.plot(ch["x"], ch["y"], label=controller)
    a.set_xlabel("x (east) [m]")
    a.set_ylabel("y (north) [m]")
    a.set_aspect("equal", adjustable="datalim")
    a.legend(loc="best")
    a.set_title(f"reference replay, {controller}: path")
    files.append(save_png(fig, out / "replay_path.png", dpi=90))
    return files


def plot_log_replay(lr, out_dir: str | Path, controller: str) -> list[str]:
    """hmpc's commands against the log's, one panel per signal, engaged spans marked."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    sig = lr.signals
    fig, ax = _panels(len(sig) + 1)
    ax = np.atleast_1d(ax)
    for a, (name, s) in zip(ax, sig.items()):
        a.plot(s["t_s"], s["log"], "k", lw=0.8, label="log (recorded sender)")
        a.plot(s["t_s"], s["hmpc"], "C0", lw=0.8, label=f"hmpc ({controller})")
        both = s["engaged_log"] & s["engaged_hmpc"]
        a.fill_between(
            s["t_s"],
            0,
            1,
            where=~both,
            color="0.5",
            alpha=0.15,
            transform=a.get_xaxis_transform(),
            label="not both engaged",
        )
        _shade(a, lr.summary["windows"].get(name, []))
        a.set_ylabel(f"{name}\n[{s['unit']}]", fontsize=8)
        a.legend(loc="best", fontsize=7)
    tr = lr.drive.trace
    eng = np.asarray(tr["engaged"]) > 0.5
    t = np.asarray(tr["t_s"])
    ax[-1].plot(
        t[eng],
        np.degrees(np.asarray(tr["sw"])[eng]),
        "k",
        lw=0.8,
        label="measured (what the log's controller steered)",
    )
    ax[-1].plot(
        t[eng],
        np.degrees(np.asarray(tr["sw_cmd"])[eng]),
        "C0",
        lw=0.8,
        label="hmpc's angle command",
    )
    ax[-1].set_ylabel("steering-wheel\nangle [deg]")
    ax[-1].set_xlabel("time from the log's first frame [s]")
    ax[-1].legend(loc="best", fontsize=7)
    fig.suptitle(f"log replay, {controller}: sha256 {lr.summary['hash']['sha256'][:16]}...")
    return [save_png(fig, out / "replay_log.png", dpi=90)]
