"""Figure of an online model estimate: each learned parameter against time with its 95 %
interval (``hmpc simulate --adapt --plots``, ``hmpc drive``/``teleop``/``replay``, and the
adaptation section of the docs).

Computes nothing: it draws the history a run recorded (``controller.adapt``'s), on its own Agg
canvas (``models.report.figure``), units on every axis.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from hmpc.models.report.figure import new_figure, save_png

#: how a key's values are shown: (scale to the axis unit, axis label)
_UNITS = {
    "offset_rad": (1e3, "[mrad]"),
    "scale": (1.0, "[1]"),
    "_mps2": (1.0, "[m/s^2]"),
    "accel_cmd_gain": (1.0, "[1]"),
    "_s": (1.0, "[s]"),
}


def _unit(key: str) -> tuple[float, str]:
    for suffix, u in _UNITS.items():
        if key.endswith(suffix):
            return u
    return 1.0, ""


def plot_adaptation(
    t_s,
    keys,
    values,
    sigmas,
    out_path: str | Path,
    *,
    title: str = "",
    truth: dict | None = None,
    used_from: dict | None = None,
    only_moved: bool = True,
) -> str:
    """One PNG: a panel per parameter, its estimate against time [s] with the 95 % band
    (+-1.96 sigma), the starting value dashed and, with ``truth`` ({key: value}), the true
    value dotted. ``values``/``sigmas``: (samples, keys). ``only_moved``: leave out
    parameters that no data moved. Returns the file name."""
    t = np.asarray(t_s, dtype=float)
    v = np.asarray(values, dtype=float).reshape(len(t), len(keys))
    s = np.asarray(sigmas, dtype=float).reshape(len(t), len(keys))
    show = [
        j
        for j, k in enumerate(keys)
        if not only_moved or (len(t) and np.any(v[:, j] != v[0, j])) or (truth and k in truth)
    ]
    if not show:
        show = list(range(min(len(keys), 2)))
    ncol = 3 if len(show) > 4 else max(len(show), 1)
    nrow = int(math.ceil(len(show) / ncol))
    fig, axes = new_figure(nrow, ncol, figsize=(4.2 * ncol, 2.6 * nrow), squeeze=False)
    for ax, j in zip(axes.ravel(), show):
        key = keys[j]
        k, unit = _unit(key)
        y, half = v[:, j] * k, 1.96 * s[:, j] * k
        ax.plot(t, y, color="C0", lw=1.2, label="estimate")
        ok = np.isfinite(half)
        if ok.any():
            lo = y - np.where(ok, half, 0)
            if key.endswith("_s"):  # a dead time or a lag is never negative
                lo = np.maximum(lo, 0.0)
            ax.fill_between(
                t, lo, y + np.where(ok, half, 0), color="C0", alpha=0.2, lw=0, label="95 % interval"
            )
        if len(t):
            ax.axhline(v[0, j] * k, color="0.4", ls="--", lw=0.8, label="start (file)")
        if truth and key in truth:
            ax.axhline(truth[key] * k, color="C3", ls=":", lw=1.2, label="truth")
        short = key.replace("longitudinal.zones.", "zone ").replace("extensions.", "")
        ax.set_title(short, fontsize=9)
        ax.set_xlabel("time [s]")
        ax.set_ylabel(f"{short.rsplit('.', 1)[-1]} {unit}", fontsize=8)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=6, loc="best")
    for ax in axes.ravel()[len(show) :]:
        ax.set_visible(False)
    if title:
        fig.suptitle(title, fontsize=10)
    return save_png(fig, out_path, dpi=110)
