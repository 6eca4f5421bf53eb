"""The HTML report of a diagnosis (jinja2 template ``templates/report.html.j2``) with its
figures: each channel's residual over time and by regime, before and after the finding on that
channel (baseline only where no finding changes it).

Times on the page and in its figures are seconds since the recording's first sample; the JSON of
``hmpc diagnose`` keeps the recording's own clock (epoch seconds for a real log), and the page
names the start time that separates the two."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from hmpc.models.diagnose.common import DiagnoseConfig
from hmpc.models.report.figure import new_figure, save_png

UNITS = {"speed": "m/s", "accel": "m/s^2", "heading": "rad", "road_wheel_angle": "rad",
         "position": "m", "speed_vs_gnss": "m/s", "yaw_rate": "rad/s"}
LABELS = {"speed": "speed free-run error", "accel": "acceleration equation error",
          "heading": "heading free-run error", "road_wheel_angle": "road-wheel angle error",
          "position": "position free-run error", "speed_vs_gnss": "CAN speed - GNSS speed"}


def _time_figure(t, name, s, path) -> str:
    fig, ax = new_figure(1, 1, figsize=(10, 3.2))
    tt = t - t[0]
    ax.plot(tt, s["before"], lw=0.7, color="tab:red", label="baseline (report's model)")
    if "after" in s:
        ax.plot(tt, s["after"], lw=0.7, color="tab:green",
                label=f"with {s.get('after_effect', 'finding')}")
    ax.set_xlabel(f"time since the start of the recording [s] (start = {t[0]:.2f} s "
                  "in the recording's clock)")
    # the channel's name goes in the title: as a y-label it is longer than the axes are tall
    ax.set_title(f"{LABELS.get(name, name)}"
                 f"{'' if 'after' in s else ' (baseline only: no finding on this channel)'}",
                 fontsize=10)
    ax.set_ylabel(f"error [{UNITS.get(name, '')}]")
    ax.grid(True, alpha=0.3)
    ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0.0, fontsize=8)
    return save_png(fig, path, 90)


def _regime_figure(rows, name, path) -> str | None:
    if not rows:
        return None
    fig, ax = new_figure(1, 1, figsize=(10, 0.28 * len(rows) + 1.2))
    y = np.arange(len(rows))
    lab = [f"{r['variable']}: {r['bin']}" for r in rows]
    ax.barh(y + 0.2, [r["rmse_before"] for r in rows], 0.4, color="tab:red", label="baseline")
    if all("rmse_after" in r for r in rows):
        ax.barh(y - 0.2, [r["rmse_after"] for r in rows], 0.4, color="tab:green",
                label="with the finding")
    ax.set_yticks(y, lab, fontsize=7)
    ax.invert_yaxis()
    ax.set_xlabel(f"RMS {LABELS.get(name, name)} [{UNITS.get(name, '')}]")
    ax.grid(True, axis="x", alpha=0.3)
    ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0.0, fontsize=8)
    return save_png(fig, path, 90)


def hypothesis_unit(h: dict) -> str:
    """Unit of a hypothesis's held-out RMSE columns: its channel's (empty when untested)."""
    return UNITS.get(h.get("channel") or "", "")


def write_report(dg, out_dir, title: str = "", cfg: DiagnoseConfig = DiagnoseConfig()) -> str:
    """Write ``index.html`` and its PNG figures into ``out_dir``; return the index path."""
    import jinja2

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    t = dg.series["t"]
    figures = []
    order = sorted((k for k in dg.series if k != "t"), key=lambda k: "after" not in dg.series[k])
    for name in order:
        s = dg.series[name]
        if name == "t" or name not in dg.channels or not np.isfinite(s["before"]).any():
            continue
        f = _time_figure(t, name, s, out / f"residual_time_{name}.png")
        which = (f"before and after {s.get('after_effect', 'the finding')}" if "after" in s
                 else "baseline only (no finding on this channel)")
        figures.append({"file": Path(f).name,
                        "title": f"{LABELS.get(name, name)} over time, {which}"})
        rows = dg.channels[name].get("regime") or []
        f = _regime_figure(rows, name, out / f"residual_regime_{name}.png")
        if f:
            which = ("before and after the finding" if all("rmse_after" in r for r in rows)
                     else "baseline only (no finding on this channel)")
            figures.append({"file": Path(f).name,
                            "title": f"{LABELS.get(name, name)} by regime, {which}"})
    env = jinja2.Environment(
        loader=jinja2.FileSystemLoader(str(Path(__file__).parent / "templates")),
        autoescape=jinja2.select_autoescape(["html", "j2"]), undefined=jinja2.StrictUndefined)
    channel_rows = [{"name": n, "unit": c.get("unit", ""), "noise_floor": c.get("noise_floor"),
                     "baseline": c.get("heldout_rmse_baseline", c.get("rmse_baseline")),
                     "elevated": c.get("elevated"), "change_point": c.get("change_point")}
                    for n, c in dg.channels.items()]
    html = env.get_template("report.html.j2").render(
        d=dg, title=title, channel_rows=channel_rows, t0=float(t[0]), figures=figures,
        units=UNITS, hypothesis_unit=hypothesis_unit, n_folds=cfg.n_folds,
        window_lon=dg.channels.get("speed", {}).get("window_s", cfg.window_lon_s),
        window_steer=cfg.window_steer_s)
    index = out / "index.html"
    index.write_text(html, encoding="utf-8")
    return str(index)
