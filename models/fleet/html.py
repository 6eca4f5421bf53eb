"""``hmpc fleet report --html DIR``: the report as one HTML page (jinja2) with a figure per
vehicle (``models.report.fleet``), the fleet-wide comparison per model, the failed drives with
their errors, and links to each drive's diagnosis report in the store."""

from __future__ import annotations

import os
from pathlib import Path

from hmpc.models.fleet import store as st

TEMPLATE = """<!doctype html>
<html lang="en"><head><meta charset="utf-8"><title>hmpc fleet report</title>
<style>
body{font-family:sans-serif;margin:1.5em;max-width:1300px}
table{border-collapse:collapse;margin:.5em 0 1.5em}
td,th{border:1px solid #bbb;padding:2px 6px;font-size:13px;text-align:right}
td:first-child,th:first-child{text-align:left}
.drift{color:#b00;font-weight:bold}.fail{color:#b00}
img{max-width:100%}
</style></head><body>
<h1>hmpc fleet report</h1>
<p>Store: <code>{{ store }}</code>. {{ vehicles|length }} vehicle(s), {{ n_drives }} finished
drive(s), {{ failed|length }} failed. Intervals are 95 %; pooled values weight each drive by
the inverse of its variance plus the between-drive variance (DerSimonian-Laird). A drift is a
step or trend across drives beyond their intervals (family-wise false-alarm rate 1 % per
parameter).</p>
{% for vid, v in vehicles.items() %}
<h2 id="vehicle-{{ vid }}">Vehicle {{ vid }} (model {{ v.model }}, {{ v.drives }} drives)</h2>
<img src="{{ figures[vid] }}" alt="parameters of vehicle {{ vid }} against drive date">
<table><tr><th>parameter</th><th>pooled</th><th>95 % interval</th><th>between-drive sd</th>
<th>drift</th></tr>
{% for key, e in v.parameters.items() %}
<tr><td>{{ key }}</td><td>{{ fmt(e.pooled) }}</td>
<td>{% if e.ci95 %}[{{ fmt(e.ci95[0]) }}, {{ fmt(e.ci95[1]) }}]{% else %}n/a{% endif %}</td>
<td>{{ fmt(e.between_drive_sd) }}</td>
<td>{% if e.drift %}<span class="drift">{{ e.drift.kind }} from {{ e.drift.from_drive }}:
{{ fmt(e.drift.before) }} &rarr; {{ fmt(e.drift.after) }}</span>{% else %}none{% endif %}</td>
</tr>{% endfor %}</table>
<p>Drives: {% for d in drives[vid] %}<a href="{{ d.link }}">{{ d.drive_id }}</a>
({{ d.start_time }}){% if not loop.last %}, {% endif %}{% endfor %}</p>
{% endfor %}
<h2>Vehicles of one model compared</h2>
{% for model, keys in models.items() %}
<h3>Model {{ model }}</h3>
<table><tr><th>parameter</th>{% for vid in model_vehicles[model] %}<th>{{ vid }}</th>
{% endfor %}<th>model pooled</th><th>between-vehicle sd</th><th>differs</th></tr>
{% for key, e in keys.items() %}
<tr><td>{{ key }}</td>{% for vid in model_vehicles[model] %}<td>{% if vid in e.vehicles %}
{{ fmt(e.vehicles[vid].pooled) }}{% if e.vehicles[vid].drift %} <span class="drift">
(drift)</span>{% endif %}{% endif %}</td>{% endfor %}
<td>{{ fmt(e.pooled) }}</td><td>{{ fmt(e.between_vehicle_sd) }}</td>
<td>{{ e.differs|join(", ") or "none" }}</td></tr>{% endfor %}</table>
{% endfor %}
<h2>Failed drives</h2>
{% if failed %}<table><tr><th>drive</th><th>vehicle</th><th>exit</th><th>error</th></tr>
{% for f in failed %}<tr class="fail"><td>{{ f.drive_id }}</td><td>{{ f.vehicle_id }}</td>
<td>{{ f.exit }}</td><td style="text-align:left">{{ f.error }}</td></tr>{% endfor %}
</table>{% else %}<p>none</p>{% endif %}
</body></html>
"""


def _fmt(x) -> str:
    return "n/a" if x is None else f"{x:.6g}"


def write_html(report: dict, out_dir) -> str:
    """Write ``index.html`` and one PNG per vehicle into ``out_dir``; return the index path."""
    import jinja2

    from hmpc.models.report.fleet import vehicle_figure

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    store = Path(report["store"])
    figures, drives = {}, {}
    for vid, v in report["vehicles"].items():
        name = f"vehicle_{vid}.png"
        vehicle_figure(vid, v["parameters"], out / name)
        figures[vid] = name
        seen: dict = {}
        for e in v["parameters"].values():
            for p in e["per_drive"]:
                seen.setdefault(p["drive_id"], p["start_time"])
        drives[vid] = [
            {"drive_id": d, "start_time": t, "link": _link(store / st.DRIVES / d, out)}
            for d, t in sorted(seen.items(), key=lambda kv: (kv[1], kv[0]))
        ]
    model_vehicles = {
        m: sorted({vid for e in keys.values() for vid in e["vehicles"]})
        for m, keys in report["models"].items()
    }
    html = (
        jinja2.Environment(autoescape=True)
        .from_string(TEMPLATE)
        .render(
            store=str(store),
            vehicles=report["vehicles"],
            failed=report["failed"],
            models=report["models"],
            model_vehicles=model_vehicles,
            figures=figures,
            drives=drives,
            fmt=_fmt,
            n_drives=sum(v["drives"] for v in report["vehicles"].values()),
        )
    )
    index = out / "index.html"
    tmp = out / ".index.html.tmp"
    tmp.write_text(html, encoding="utf-8")
    os.replace(tmp, index)
    return str(index)


def _link(drive_folder: Path, out: Path) -> str:
    """The drive's diagnosis report when it has one, else its folder, relative to ``out``."""
    target = drive_folder / st.REPORT / "index.html"
    if not target.exists():
        target = (
            drive_folder / st.PARAMS
            if (drive_folder / st.PARAMS).exists()
            else drive_folder / st.STATUS
        )
    return os.path.relpath(target.resolve(), out.resolve())
