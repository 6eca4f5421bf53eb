"""Overview figure of a canonical recording: what a user looks at first after ingest."""

from __future__ import annotations

import numpy as np

from hmpc.models.logs.recording import Recording
from hmpc.models.report.figure import new_figure, save_png


def plot_overview(rec: Recording, path: str, title: str = "") -> str:
    """Write a PNG with steering, speeds, pedals, yaw rate and the ENU track (where present)."""
    t = rec.time - rec.time[0]
    panels = []
    if "steering_wheel_angle" in rec:
        panels.append(
            (
                "steering-wheel angle [deg]",
                [("steering_wheel_angle", np.degrees(rec["steering_wheel_angle"]))],
            )
        )
    speeds = [
        (n, rec[n])
        for n in (
            "speed",
            "wheel_speed_fl",
            "wheel_speed_fr",
            "wheel_speed_rl",
            "wheel_speed_rr",
            "gps_speed",
        )
        if n in rec
    ]
    if speeds:
        panels.append(("speed [m/s]", speeds))
    pedals = [(n, rec[n]) for n in ("accel_pedal", "brake_pedal") if n in rec]
    if pedals:
        panels.append(("pedal [0..1]", pedals))
    if "yaw_rate" in rec:
        panels.append(("yaw rate [deg/s]", [("yaw_rate", np.degrees(rec["yaw_rate"]))]))
    if "accel_x" in rec:
        panels.append(("longitudinal accel [m/s^2]", [("accel_x", rec["accel_x"])]))
    has_track = "x" in rec and "y" in rec
    n = len(panels) + (1 if has_track else 0)
    fig, axes = new_figure(n, 1, figsize=(11.5, 2.2 * n), squeeze=False)
    axes = axes[:, 0]
    for ax, (label, series) in zip(axes, panels):
        for name, values in series:
            ax.plot(t, values, lw=0.8, label=name)
        ax.set_ylabel(label)
        ax.grid(True, alpha=0.3)
        # outside the axes, to their right: never over the traces
        ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0.0, fontsize=7)
        ax.set_xlabel("time [s]")
    if has_track:
        ax = axes[-1]
        ax.plot(rec["x"], rec["y"], lw=1.0)
        ax.set_xlabel("east x [m]")
        ax.set_ylabel("north y [m]")
        ax.set_aspect("equal", adjustable="datalim")
        ax.grid(True, alpha=0.3)
        ax.set_title("track in local ENU (equal scales)")
    if title:
        fig.suptitle(title)
    save_png(fig, path, dpi=110)
    return path
