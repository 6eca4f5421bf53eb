"""One drive of a fleet run, as a Dask worker runs it: ingest, identify, diagnose with hmpc's
library functions (what ``hmpc ingest``, ``identify`` and ``diagnose`` call), every output
written under ``STORE/.tmp`` and the folder renamed into place when complete
(``models.fleet.store``). A failure never raises: it is the drive's status (exit 2 for bad
input, 1 for an internal failure, with a one-line error).
"""

from __future__ import annotations

import math
import os
import resource
import shutil
import socket
import time
from datetime import datetime, timezone

from hmpc import __version__
from hmpc.models.errors import HmpcError, InputError
from hmpc.models.fleet import store as st
from hmpc.models.fleet.manifest import Drive

#: the per-drive table's columns (STORE/drives/*/values.parquet), in order
VALUE_COLUMNS = (
    "vehicle_id",
    "model",
    "drive_id",
    "start_time",
    "key",
    "value",
    "ci_lo",
    "ci_hi",
    "identifiable",
)

#: parameter-file value -> the key of its 95 % interval, for the steering map and the zones
_CI_KEYS = {
    "offset_rad": "offset_ci95_rad",
    "scale": "scale_ci95",
    "offset_mps2": "offset_ci95_mps2",
    "scale_mps2": "scale_ci95_mps2",
    "brake_scale_mps2": "brake_scale_ci95_mps2",
    "dead_time_s": None,
}


def _one_line(text: str) -> str:
    return " ".join(str(text).split())


def _load_recording(drive: Drive, progress):
    """The drive's canonical recording and its sources: a raw log ingested (models.logs.ingest)
    or a canonical recording loaded."""
    from hmpc.models.logs.recording import Recording

    f = drive.files
    if drive.raw:
        from hmpc.models.logs.ingest import ingest_files

        res = ingest_files(
            f["log"],
            f["dbc"],
            f["signals"],
            nav_path=f.get("nav"),
            imu_path=f.get("imu"),
            progress=progress,
        )
        sources = {k: f.get(k) for k in ("log", "dbc", "signals", "nav", "imu")}
        return res.recording, sources
    return Recording.load(f["recording"]), {"recording": f["recording"]}


def flat_values(params) -> list[tuple]:
    """(dotted key, value, ci_lo, ci_hi, identifiable) for every number of a parameter file
    that the fleet report tracks: the steering map, each zone's coefficients, the dead times
    and every extension parameter (docs/conventions.md, "Fleet")."""
    out = []
    d = params.to_dict()
    s = d.get("steering") or {}
    for k, ci_key in _CI_KEYS.items():
        if isinstance(s.get(k), (int, float)) and not isinstance(s.get(k), bool):
            ci = s.get(ci_key) if ci_key else None
            out.append((f"steering.{k}", s[k], ci, s.get("identifiable")))
    lon = d.get("longitudinal") or {}
    if isinstance(lon.get("dead_time_s"), (int, float)):
        out.append(("longitudinal.dead_time_s", lon["dead_time_s"], None, None))
    for z in lon.get("zones") or []:
        for k in ("offset_mps2", "scale_mps2", "brake_scale_mps2"):
            out.append(
                (
                    f"longitudinal.zones.{z['name']}.{k}",
                    z[k],
                    z.get(_CI_KEYS[k]),
                    z.get("identifiable"),
                )
            )
    for eid, subs in sorted((d.get("extensions") or {}).items()):
        for sub, entry in sorted(subs.items()):
            iv = entry.get("intervals") or {}
            for k, v in entry.items():
                if isinstance(v, (int, float)) and not isinstance(v, bool):
                    out.append((f"extensions.{eid}.{sub}.{k}", v, iv.get(k), None))
    rows = []
    for key, v, ci, ok in out:
        lo, hi = (float(ci[0]), float(ci[1])) if ci is not None and len(ci) == 2 else (None, None)
        rows.append((key, float(v), lo, hi, None if ok is None else bool(ok)))
    return rows


def write_values(path, drive: Drive, params) -> None:
    """The drive's rows of the per-drive table, as Parquet (pyarrow)."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    rows = [r for r in flat_values(params) if math.isfinite(r[1])]
    cols = {
        "vehicle_id": [drive.vehicle_id] * len(rows),
        "model": [drive.model] * len(rows),
        "drive_id": [drive.drive_id] * len(rows),
        "start_time": [drive.start_time] * len(rows),
        "key": [r[0] for r in rows],
        "value": [r[1] for r in rows],
        "ci_lo": [r[2] for r in rows],
        "ci_hi": [r[3] for r in rows],
        "identifiable": [r[4] for r in rows],
    }
    schema = pa.schema(
        [
            ("vehicle_id", pa.string()),
            ("model", pa.string()),
            ("drive_id", pa.string()),
            ("start_time", pa.string()),
            ("key", pa.string()),
            ("value", pa.float64()),
            ("ci_lo", pa.float64()),
            ("ci_hi", pa.float64()),
            ("identifiable", pa.bool_()),
        ]
    )
    pq.write_table(pa.table(cols, schema=schema), str(path))


def _peak_rss_mb() -> float:
    # ru_maxrss is in KiB on Linux: the worker process's peak resident memory so far
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def base_status(drive: Drive, inputs: dict, inputs_sha256: str, steps) -> dict:
    return {
        "vehicle_id": drive.vehicle_id,
        "drive_id": drive.drive_id,
        "start_time": drive.start_time,
        "model": drive.model,
        "inputs": inputs,
        "inputs_sha256": inputs_sha256,
        "hmpc_version": __version__,
        "steps": list(steps),
        "exit": None,
        "error": None,
        "timings_s": {},
        "worker": f"{socket.gethostname()}:{os.getpid()}",
        "worker_peak_rss_mb": None,
        "finished_at": None,
    }


def process_drive(drive: Drive, inputs: dict, inputs_sha256: str, store: str, steps: tuple) -> dict:
    """Run ``steps`` on one drive, commit its folder to the store and return its status
    (status.json's content). Never raises for the drive's own failures."""
    from threadpoolctl import threadpool_limits

    status = base_status(drive, inputs, inputs_sha256, steps)
    t0 = time.perf_counter()
    tmp = st.new_tmp_dir(store, drive.drive_id)
    try:
        # one BLAS thread: a worker is one process per core (as the CLI does for one command)
        with threadpool_limits(limits=1, user_api="blas"):
            _steps(drive, steps, tmp, status)
        status["exit"] = 0
    except InputError as exc:
        status["exit"], status["error"] = 2, _one_line(exc.one_line())
    except HmpcError as exc:
        status["exit"], status["error"] = 2, _one_line(f"{drive.drive_id}: {exc}")
    except Exception as exc:  # noqa: BLE001 -- one drive's bug must not stop the fleet
        status["exit"] = 1
        status["error"] = _one_line(f"internal error: {type(exc).__name__}: {exc}")
    if status["exit"] != 0:  # a failed drive keeps only its status
        for p in tmp.iterdir():
            if p.is_dir():
                shutil.rmtree(p, ignore_errors=True)
            else:
                p.unlink()
    status["timings_s"]["total"] = round(time.perf_counter() - t0, 3)
    status["worker_peak_rss_mb"] = round(_peak_rss_mb(), 1)
    status["finished_at"] = datetime.now(timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ")
    st.write_json_file(tmp / st.STATUS, status)
    st.commit(tmp, store, drive.drive_id)
    return status


def _steps(drive: Drive, steps, tmp, status) -> None:
    from hmpc.models.params import dump_params, load_params

    timings = status["timings_s"]
    say = lambda msg: None  # noqa: E731 -- a worker prints nothing; the status says it all
    t = time.perf_counter()
    vehicle = load_params(drive.files["geometry"]).vehicle
    rec, sources = _load_recording(drive, say)
    if "ingest" in steps:
        rec.save(tmp / st.RECORDING)
    timings["ingest"] = round(time.perf_counter() - t, 3)
    params = None
    if "identify" in steps:
        from hmpc.models.identify.pipeline import identify

        t = time.perf_counter()
        params = identify(
            rec, vehicle, sources={**sources, "vehicle": drive.files["geometry"]}, progress=say
        ).params
        timings["identify"] = round(time.perf_counter() - t, 3)
    if "diagnose" in steps:
        params = _diagnose(rec, vehicle, params, sources, drive, tmp, timings, say)
    if params is not None:
        dump_params(params, tmp / st.PARAMS)
        write_values(tmp / st.VALUES, drive, params)


def _diagnose(rec, vehicle, params, sources, drive, tmp, timings, say):
    """`hmpc diagnose` on the recording (the report's model refitted on it, as the command
    does without --params): diagnosis.json, the HTML report, and the parameter file with the
    findings in its extensions: section (identify's values kept where identify ran)."""
    from hmpc.models.diagnose.diagnose import diagnose
    from hmpc.models.diagnose.report import write_report

    t = time.perf_counter()
    dg = diagnose(rec, vehicle, None, progress=say)
    payload = dg.to_json()
    payload["recording"] = sources
    st.write_json_file(tmp / st.DIAGNOSIS, payload)
    write_report(dg, tmp / st.REPORT, title=drive.drive_id)
    timings["diagnose"] = round(time.perf_counter() - t, 3)
    if params is None:
        return dg.params_out
    params.extensions = dict(dg.params_out.extensions)
    return params
