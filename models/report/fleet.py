"""The fleet report's figure: one vehicle's parameters against drive start time, each drive's
value with its 95 % interval, the pooled value and interval as a band, a drift marked where it
began with its before/after levels (``hmpc fleet report --html``)."""

from __future__ import annotations

import math
from datetime import datetime

from hmpc.models.report.figure import new_figure, save_png

#: panels per row of the grid (a vehicle has a dozen parameters or more)
_COLS = 3
#: figure size per panel [inches] and resolution [dpi]: readable at a page's width
_PANEL_IN = (4.2, 2.6)
_DPI = 90


def _time(text: str) -> datetime:
    return datetime.fromisoformat(text.replace("Z", "+00:00"))


def vehicle_figure(vehicle_id: str, parameters: dict, path) -> str:
    """Write the PNG of one vehicle (``parameters``: the report JSON's KEY -> entry)."""
    keys = list(parameters)
    rows = max(1, math.ceil(len(keys) / _COLS))
    fig, axes = new_figure(
        rows, _COLS, figsize=(_PANEL_IN[0] * _COLS, _PANEL_IN[1] * rows), squeeze=False
    )
    for i, ax in enumerate(axes.flat):
        if i >= len(keys):
            ax.set_visible(False)
            continue
        key, e = keys[i], parameters[keys[i]]
        per = e["per_drive"]
        t = [_time(p["start_time"]) for p in per]
        y = [p["value"] for p in per]
        lo = [p["value"] - p["ci95"][0] if p["ci95"] else 0.0 for p in per]
        hi = [p["ci95"][1] - p["value"] if p["ci95"] else 0.0 for p in per]
        ax.errorbar(
            t, y, yerr=[lo, hi], fmt="o", ms=3, capsize=2, color="C0", label="drive, 95 % interval"
        )
        if e["ci95"]:
            ax.axhspan(
                e["ci95"][0], e["ci95"][1], color="C2", alpha=0.2, label="pooled, 95 % interval"
            )
        if e["pooled"] is not None and math.isfinite(e["pooled"]):
            ax.axhline(e["pooled"], color="C2", lw=1)
        d = e.get("drift")
        if d:
            start = next(_time(p["start_time"]) for p in per if p["drive_id"] == d["from_drive"])
            ax.axvline(
                start, color="C3", ls="--", lw=1.2, label=f"{d['kind']} from {d['from_drive']}"
            )
            ax.plot([t[0], start], [d["before"]] * 2, color="C3", lw=1)
            ax.plot(
                [start, t[-1]],
                [d["after"] if d["kind"] == "step" else d["before"], d["after"]],
                color="C3",
                lw=1,
            )
        ax.set_title(key, fontsize=8)
        ax.tick_params(labelsize=7)
        for lab in ax.get_xticklabels():
            lab.set_rotation(30)
        if i == 0 or d:
            ax.legend(fontsize=6, loc="best")
    fig.suptitle(f"vehicle {vehicle_id}: parameters against drive start time (UTC)", fontsize=10)
    return save_png(fig, path, _DPI)
