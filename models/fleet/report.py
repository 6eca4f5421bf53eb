"""``hmpc fleet report``: per vehicle and parameter, every drive's value with its interval, the
pooled value (``models.fleet.stats.pool``) and any drift (``models.fleet.stats.drift``); per
vehicle model, the vehicles side by side; the failed drives with their errors.

The per-drive table is the store's ``drives/*/values.parquet`` files, queried with DuckDB as
one table (no loop over per-drive files); the failed drives come from the ``status.json``
files the same way.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from hmpc.models.errors import InputError
from hmpc.models.fleet import store as st
from hmpc.models.fleet.stats import Z95, drift, pool, se_from_ci

#: family-wise rate at which a vehicle is named as differing from the other vehicles of its
#: model (per parameter, Bonferroni over the vehicles): 1 %, as for drift
OUTLIER_ALPHA = 0.01


def _sql_path(p: Path) -> str:
    return str(p).replace("'", "''")


def query_values(store):
    """The per-drive table of finished drives, ordered by vehicle, key, start time, drive:
    a list of row tuples (models.fleet.drive.VALUE_COLUMNS)."""
    import duckdb

    store = Path(store)
    pattern = store / st.DRIVES / "*" / st.VALUES
    if not any((store / st.DRIVES).glob(f"*/{st.VALUES}")):
        return []
    con = duckdb.connect()
    try:
        return con.execute(
            "SELECT vehicle_id, model, drive_id, start_time, key, value, ci_lo, ci_hi, "
            f"identifiable FROM read_parquet('{_sql_path(pattern)}') "
            "ORDER BY vehicle_id, key, start_time, drive_id"
        ).fetchall()
    finally:
        con.close()


def query_statuses(store):
    """(drive_id, vehicle_id, start_time, exit, error) of every drive in the store."""
    import duckdb

    store = Path(store)
    if not any((store / st.DRIVES).glob(f"*/{st.STATUS}")):
        return []
    pattern = store / st.DRIVES / "*" / st.STATUS
    con = duckdb.connect()
    try:
        return con.execute(
            'SELECT drive_id, vehicle_id, start_time, "exit", error FROM read_json('
            f"'{_sql_path(pattern)}', columns={{drive_id: 'VARCHAR', vehicle_id: 'VARCHAR', "
            "start_time: 'VARCHAR', \"exit\": 'INTEGER', error: 'VARCHAR'}) "
            "ORDER BY vehicle_id, start_time, drive_id"
        ).fetchall()
    finally:
        con.close()


def _parameter(rows) -> dict:
    """One vehicle's one parameter: per-drive values, pooled value, drift."""
    per = [
        {
            "drive_id": r[2],
            "start_time": r[3],
            "value": r[5],
            "ci95": None if r[6] is None or r[7] is None else [r[6], r[7]],
            **({} if r[8] is None else {"identifiable": bool(r[8])}),
        }
        for r in rows
    ]
    used = [p for p in per if p.get("identifiable", True)]
    y = [p["value"] for p in used]
    se = [se_from_ci(*(p["ci95"] or (None, None))) for p in used]
    m, ci, tau2 = pool(y, se)
    d = drift(y, se)
    return {
        "pooled": m,
        "ci95": None if ci is None else [ci[0], ci[1]],
        "between_drive_sd": None if not math.isfinite(tau2) else math.sqrt(tau2),
        "per_drive": per,
        "drift": None
        if d is None
        else {
            "from_drive": used[d.index]["drive_id"],
            "before": d.before,
            "after": d.after,
            "kind": d.kind,
            "z": d.z,
            "bound": d.bound,
        },
    }


def build_report(store) -> dict:
    """The report JSON of docs/conventions.md ("Fleet"): ``vehicles``, ``models``,
    ``failed``."""
    store = Path(store)
    if not (store / st.DRIVES).is_dir():
        raise InputError(
            "not a fleet store (no drives/ folder; make one with hmpc fleet run)", str(store)
        )
    rows = query_values(store)
    statuses = query_statuses(store)
    vehicles: dict = {}
    models: dict = {}
    groups: dict = {}
    for r in rows:
        groups.setdefault((r[0], r[4]), []).append(r)
        models.setdefault(r[1], set()).add(r[0])
    drives_of: dict = {}
    for did, vid, _, code, _ in statuses:
        if code == 0:
            drives_of.setdefault(vid, set()).add(did)
    for (vid, key), rs in groups.items():
        v = vehicles.setdefault(
            vid, {"model": rs[0][1], "drives": len(drives_of.get(vid, ())), "parameters": {}}
        )
        v["parameters"][key] = _parameter(rs)
    failed = [
        {"vehicle_id": vid, "drive_id": did, "start_time": t, "exit": code, "error": err}
        for did, vid, t, code, err in statuses
        if code != 0
    ]
    return {
        "store": str(store),
        "vehicles": vehicles,
        "models": {m: _compare(sorted(vs), vehicles) for m, vs in sorted(models.items())},
        "failed": failed,
    }


def _compare(vids: list[str], vehicles: dict) -> dict:
    """Per parameter, the vehicles of one model side by side: each vehicle's pooled value, the
    model's pooled value over vehicles (between-vehicle spread as tau), and the vehicles that
    differ from the others beyond their intervals (leave-one-out, Bonferroni)."""
    keys = sorted({k for v in vids for k in vehicles[v]["parameters"]})
    out = {}
    for key in keys:
        have = [
            (v, vehicles[v]["parameters"][key]) for v in vids if key in vehicles[v]["parameters"]
        ]
        vals = [p["pooled"] for _, p in have]
        ses = [se_from_ci(*(p["ci95"] or (None, None))) for _, p in have]
        m, ci, tau2 = pool(vals, ses)
        differs = []
        if len(have) >= 2:
            bound = _z_bound(OUTLIER_ALPHA / (2 * len(have)))
            for i, (vid, _) in enumerate(have):
                rest = [j for j in range(len(have)) if j != i]
                mo, cio, t2o = pool([vals[j] for j in rest], [ses[j] for j in rest])
                if cio is None or not math.isfinite(ses[i]):
                    continue
                se_o = (cio[1] - cio[0]) / (2 * Z95)
                z = (vals[i] - mo) / math.sqrt(ses[i] ** 2 + se_o**2 + max(t2o, 0.0))
                if abs(z) > bound:
                    differs.append(vid)
        out[key] = {
            "vehicles": {
                vid: {"pooled": p["pooled"], "ci95": p["ci95"], "drift": p["drift"] is not None}
                for vid, p in have
            },
            "pooled": m,
            "ci95": None if ci is None else [ci[0], ci[1]],
            "between_vehicle_sd": None if not math.isfinite(tau2) else math.sqrt(tau2),
            "differs": differs,
        }
    return out


def _z_bound(level: float) -> float:
    from scipy.stats import norm

    return float(norm.isf(level))


def finite_or_none(obj):
    """``obj`` with NaN and infinities as None (strict JSON)."""
    if isinstance(obj, dict):
        return {k: finite_or_none(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [finite_or_none(v) for v in obj]
    if isinstance(obj, (float, np.floating)):
        return float(obj) if math.isfinite(obj) else None
    return obj
