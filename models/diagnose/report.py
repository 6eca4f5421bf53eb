"""The HTML report of a diagnosis (jinja2 template ``templates/report.html.j2``) with its
figures: each channel's residual over time and by regime, before and after the finding on that
channel (baseline only where no finding changes it); for each pair of sensors compared, both
measurements with the fit that makes them agree; the path driven, where the recording has one.
The page leads with the answer (the verdict, the parts not diagnosed, the findings); the
evidence follows. Angles are shown in degrees (the JSON keeps radians); a figure has panels
only for channels the recording holds.

Times on the page and in its figures are seconds since the recording's first sample; the JSON of
``hmpc diagnose`` keeps the recording's own clock (epoch seconds for a real log), and the page
names the start time that separates the two."""

from __future__ import annotations

from pathlib import Path
from typing import cast

import numpy as np

from hmpc.models.diagnose import display as show
from hmpc.models.diagnose.common import DiagnoseConfig
from hmpc.models.report.figure import new_figure, save_png

#: the unit of each channel in the JSON (SI)
UNITS = show.CHANNEL_UNITS
LABELS = {
    "speed": "speed free-run error",
    "accel": "acceleration equation error",
    "heading": "heading free-run error",
    "road_wheel_angle": "road-wheel angle error",
    "position": "position free-run error",
    "speed_vs_gnss": "CAN speed - GNSS speed",
    "accel_vs_speed": "accel_x - its fit from dv/dt",
    "yaw_rate_vs_wheels": "wheel-speed yaw rate - its fit from the yaw rate",
}
#: a path whose extent in one direction is more than this many times the other is drawn with
#: unequal axes (to scale, a long straight is a sliver of a line)
PATH_MAX_ASPECT = 8.0


def _time_figure(t, name, s, path) -> str:
    fig, ax = new_figure(1, 1, figsize=(10, 3.2))
    tt = t - t[0]
    unit = UNITS.get(name, "")
    k = show.shown(1.0, unit)[0]
    ax.plot(tt, k * s["before"], lw=0.7, color="tab:red", label="baseline (report's model)")
    if "after" in s:
        ax.plot(
            tt,
            k * s["after"],
            lw=0.7,
            color="tab:green",
            label=f"with {s.get('after_effect', 'finding')}",
        )
    ax.set_xlabel(
        f"time since the start of the recording [s] (start = {t[0]:.2f} s in the recording's clock)"
    )
    # the channel's name goes in the title: as a y-label it is longer than the axes are tall
    ax.set_title(
        f"{LABELS.get(name, name)}"
        f"{'' if 'after' in s else ' (baseline only: no finding on this channel)'}",
        fontsize=10,
    )
    ax.set_ylabel(f"error [{show.shown(None, unit)[1]}]")
    ax.grid(True, alpha=0.3)
    ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0.0, fontsize=8)
    return save_png(fig, path, 90)


def _regime_figure(rows, name, path) -> str | None:
    if not rows:
        return None
    fig, ax = new_figure(1, 1, figsize=(10, 0.28 * len(rows) + 1.2))
    y = np.arange(len(rows))
    lab = [f"{r['variable']}: {r['bin']}" for r in rows]
    k, unit = show.shown(1.0, UNITS.get(name, ""))
    ax.barh(y + 0.2, [k * r["rmse_before"] for r in rows], 0.4, color="tab:red", label="baseline")
    if all("rmse_after" in r for r in rows):
        ax.barh(
            y - 0.2,
            [k * r["rmse_after"] for r in rows],
            0.4,
            color="tab:green",
            label="with the finding",
        )
    ax.set_yticks(y, lab, fontsize=7)
    ax.invert_yaxis()
    ax.set_xlabel(f"RMS {LABELS.get(name, name)} [{unit}]")
    ax.grid(True, axis="x", alpha=0.3)
    ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0.0, fontsize=8)
    return save_png(fig, path, 90)


def _pair_figure(t, name, pair: dict, path) -> str:
    """Two measurements of one quantity: both over time, the baseline's fit and the fit of the
    physics that makes them agree (where one was found)."""
    fig, ax = new_figure(1, 1, figsize=(10, 3.4))
    tt = t - t[0]
    k, unit = show.shown(1.0, UNITS.get(name, ""))
    measured, reference = pair["labels"]
    ax.plot(tt, k * pair["measured"], lw=0.8, color="0.35", label=measured)
    ax.plot(
        tt,
        k * pair["baseline_fit"],
        lw=0.7,
        color="tab:red",
        label=f"fit from {reference} (baseline)",
    )
    for key, y in pair.items():
        if key.startswith("fit_"):
            ax.plot(tt, k * y, lw=0.7, color="tab:green", label=f"with {key[4:]}")
    ax.set_xlabel("time since the start of the recording [s]")
    ax.set_ylabel(f"[{unit}]")
    ax.set_title(f"{measured} against {reference}", fontsize=10)
    ax.grid(True, alpha=0.3)
    ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0.0, fontsize=8)
    return save_png(fig, path, 90)


def _path_figure(x, y, err, path) -> tuple[str, bool]:
    """The path driven (x, y), coloured by the heading free-run error where it was replayed.
    Returns (file, to scale): a path far longer than wide is drawn with unequal axes
    (:data:`PATH_MAX_ASPECT`), so that a long straight is not a sliver."""
    fig, ax = new_figure(1, 1, figsize=(8, 5))
    ok = np.isfinite(x) & np.isfinite(y)
    ax.plot(x[ok], y[ok], lw=0.8, color="0.6", label="path driven")
    if err is not None and np.isfinite(err).any():
        e = np.isfinite(err) & ok
        sc = ax.scatter(x[e], y[e], c=np.degrees(np.abs(err[e])), s=3, cmap="viridis")
        fig.colorbar(sc, ax=ax, label="|heading free-run error| [deg]")
    wx, wy = np.ptp(x[ok]), np.ptp(y[ok])
    to_scale = max(wx, wy) <= PATH_MAX_ASPECT * max(min(wx, wy), 1e-9)
    if to_scale:
        ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("x [m]" + ("" if to_scale else " (axes not to scale)"))
    ax.set_ylabel("y [m]")
    ax.grid(True, alpha=0.3)
    return save_png(fig, path, 90), to_scale


def hypothesis_unit(h: dict) -> str:
    """Unit of a hypothesis's held-out RMSE columns as shown: its channel's, angles in deg
    (empty when untested)."""
    u = UNITS.get(h.get("channel") or "", "")
    return show.shown(None, u)[1] if u else ""


def hypothesis_factor(h: dict) -> float:
    """The factor from a hypothesis's held-out RMSE to its shown unit (deg for rad)."""
    return cast(float, show.shown(1.0, UNITS.get(h.get("channel") or "", ""))[0])  # given 1.0


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
        if "pair" in s:
            f = _pair_figure(t, name, s["pair"], out / f"sensors_{name}.png")
            figures.append(
                {
                    "file": Path(f).name,
                    "title": (
                        f"{s['pair']['labels'][0]} against {s['pair']['labels'][1]}: both "
                        "measurements and the fit that makes them agree"
                    ),
                }
            )
        f = _time_figure(t, name, s, out / f"residual_time_{name}.png")
        which = (
            f"before and after {s.get('after_effect', 'the finding')}"
            if "after" in s
            else "baseline only (no finding on this channel)"
        )
        figures.append(
            {"file": Path(f).name, "title": f"{LABELS.get(name, name)} over time, {which}"}
        )
        rows = dg.channels[name].get("regime") or []
        rf = _regime_figure(rows, name, out / f"residual_regime_{name}.png")
        if rf:
            which = (
                "before and after the finding"
                if all("rmse_after" in r for r in rows)
                else "baseline only (no finding on this channel)"
            )
            figures.append(
                {"file": Path(rf).name, "title": f"{LABELS.get(name, name)} by regime, {which}"}
            )
    xy = dg.series.get("path")
    if xy is not None:
        f, to_scale = _path_figure(
            xy["x"], xy["y"], dg.series.get("heading", {}).get("before"), out / "path.png"
        )
        figures.append(
            {
                "file": Path(f).name,
                "title": "path driven"
                + (
                    ""
                    if to_scale
                    else " (axes not to scale: the path is far longer than it is wide)"
                ),
            }
        )
    env = jinja2.Environment(
        loader=jinja2.FileSystemLoader(str(Path(__file__).parent / "templates")),
        autoescape=jinja2.select_autoescape(["html", "j2"]),
        undefined=jinja2.StrictUndefined,
    )
    channel_rows = []
    for n, c in dg.channels.items():
        k, unit = show.shown(1.0, c.get("unit", ""))
        base = c.get("heldout_rmse_baseline", c.get("rmse_baseline"))
        floor = c.get("noise_floor")
        channel_rows.append(
            {
                "name": n,
                "unit": unit,
                "noise_floor": None if floor is None else k * floor,
                "baseline": None if base is None else k * base,
                "elevated": c.get("elevated"),
                "change_point": c.get("change_point"),
            }
        )
    verdict_rows = []
    for n, v in (dg.verdict.get("channels") or {}).items():
        k, unit = show.shown(1.0, v.get("unit") or "")
        verdict_rows.append(
            {
                "name": n,
                "unit": unit,
                "rmse": k * v["rmse"],
                "noise_floor": None if v["noise_floor"] is None else k * v["noise_floor"],
                "factor": v["factor"],
                "skill": v["skill"],
                "misses": v["misses"],
            }
        )
    html = env.get_template("report.html.j2").render(
        d=dg,
        title=title,
        channel_rows=channel_rows,
        verdict_rows=verdict_rows,
        t0=float(t[0]),
        figures=figures,
        units=UNITS,
        hypothesis_unit=hypothesis_unit,
        hypothesis_factor=hypothesis_factor,
        param=show.parameter,
        unit_of=show.unit_of,
        n_folds=cfg.n_folds,
        window_lon=dg.channels.get("speed", {}).get("window_s", cfg.window_lon_s),
        window_steer=cfg.window_steer_s,
        shown_unit=lambda u: show.shown(None, u)[1],
        shown_factor=lambda u: show.shown(1.0, u)[0],
    )
    index = out / "index.html"
    index.write_text(html, encoding="utf-8")
    return str(index)
