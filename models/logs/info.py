"""What a CAN log holds (``hmpc info``): duration, frames and rates per bus and id, DBC message
names, gaps per id, clock problems and malformed lines.

:func:`log_info` returns the figures as a dict with stable keys in SI units (the ``--json``
payload); :func:`format_info` renders the same figures as a table for the terminal.
"""

from __future__ import annotations

import numpy as np

from hmpc.models.logs.canlog import (
    KIND_BACKWARDS,
    KIND_DUPLICATE,
    KIND_ERROR_FRAME,
    KIND_JUMP,
    KIND_MALFORMED,
    KIND_REMOTE,
    detect_format,
    read_log,
)
from hmpc.models.errors import Problems
from hmpc.models.logs.frames import FrameTable

#: an inter-frame interval longer than this many median periods counts as a gap
GAP_FACTOR = 3.0


def log_info(
    path, problems: Problems, *, dbc_path=None, fmt: str | None = None, jump_s: float = 1.0
) -> dict:
    """Read a CAN log and summarise it.

    Args:
        path: the log (any format :func:`models.logs.canlog.read_log` reads).
        problems: collector; the reader's recoverable problems land here too.
        dbc_path: optional DBC; adds message names and decodable/unknown frame counts.
        fmt: force the log format.
        jump_s: forward clock jumps longer than this [s] are reported.

    Returns:
        Figures with stable keys (times in s, rates in Hz); see ``tools/cmd_info.py``.

    Raises:
        InputError: the log or DBC cannot be used at all.
    """
    fmt = fmt or detect_format(path)
    frames = read_log(path, problems, fmt=fmt, jump_s=jump_s)
    db = None
    if dbc_path is not None:
        from hmpc.models.logs.dbc import load_dbc

        db = load_dbc(dbc_path)
    return summarise(frames, problems, fmt=fmt, db=db, dbc_path=dbc_path)


def _counts(problems: Problems, path: str, kind: str) -> tuple[int, list[int]]:
    for p in problems:
        if p.kind == kind and p.path == path:
            return int(p.count), [int(x) for x in p.first]
    return 0, []


def summarise(
    frames: FrameTable, problems: Problems, *, fmt: str = "", db=None, dbc_path=None
) -> dict:
    """The figures of :func:`log_info` for frames already read."""
    path = frames.path
    t = frames.t_s
    n = len(frames)
    duration = float(t[-1] - t[0]) if n else 0.0
    rate = n / duration if duration > 0 else 0.0
    names = None
    if db is not None:
        from hmpc.models.logs.decode import message_index

        msg_index = message_index(frames, db)
        names = [m.name for m in db.messages]
        lengths = np.array([m.length for m in db.messages] + [0])

    buses = []
    for b in np.unique(frames.bus):
        cnt = int(np.count_nonzero(frames.bus == b))
        buses.append(
            {"bus": int(b), "frames": cnt, "rate_hz": cnt / duration if duration > 0 else 0.0}
        )

    # one group per (bus, extended, id), in first-seen order of (bus, id)
    key = (
        (frames.bus.astype(np.int64) << 33)
        | (frames.is_extended.astype(np.int64) << 32)
        | frames.arb_id.astype(np.int64)
    )
    order = np.argsort(key, kind="stable")
    skey = key[order]
    starts = (
        np.flatnonzero(np.concatenate([[True], skey[1:] != skey[:-1]])) if n else np.zeros(0, int)
    )
    ends = np.concatenate([starts[1:], [n]])
    ids = []
    for s, e in zip(starts, ends):
        rows = order[s:e]
        tt = t[rows]
        cnt = len(rows)
        entry = {
            "bus": int(frames.bus[rows[0]]),
            "id": int(frames.arb_id[rows[0]]),
            "id_hex": f"0x{int(frames.arb_id[rows[0]]):X}",
            "extended": bool(frames.is_extended[rows[0]]),
            "frames": int(cnt),
            "rate_hz": cnt / duration if duration > 0 else 0.0,
            "dlc": sorted(int(x) for x in np.unique(frames.dlc[rows])),
        }
        if names is not None:
            mi = int(msg_index[rows[0]])
            entry["message"] = names[mi] if mi >= 0 else None
            entry["dbc_length"] = int(lengths[mi]) if mi >= 0 else None
        if cnt >= 2:
            dt = np.diff(tt)
            med = float(np.median(dt))
            k = int(np.argmax(dt))
            entry.update(
                {
                    "median_period_s": med,
                    "max_gap_s": float(dt[k]),
                    "max_gap_start_s": float(tt[k]),
                    "max_gap_where": int(frames.where[rows[k + 1]]),
                    "max_gap_periods": float(dt[k] / med) if med > 0 else None,
                    "gaps": int(np.count_nonzero(dt > GAP_FACTOR * med)) if med > 0 else 0,
                }
            )
        else:
            entry.update(
                {
                    "median_period_s": None,
                    "max_gap_s": None,
                    "max_gap_start_s": None,
                    "max_gap_where": None,
                    "max_gap_periods": None,
                    "gaps": 0,
                }
            )
        ids.append(entry)
    ids.sort(key=lambda e: (e["bus"], e["extended"], e["id"]))

    back, back_at = _counts(problems, path, KIND_BACKWARDS)
    jumps, jumps_at = _counts(problems, path, KIND_JUMP)
    dups, dups_at = _counts(problems, path, KIND_DUPLICATE)
    bad, bad_at = _counts(problems, path, KIND_MALFORMED)
    remote, remote_at = _counts(problems, path, KIND_REMOTE)
    errf, errf_at = _counts(problems, path, KIND_ERROR_FRAME)
    largest = float(np.max(np.diff(t))) if n >= 2 else 0.0
    out = {
        "file": str(path),
        "format": fmt,
        "frames": int(n),
        "start_s": float(t[0]) if n else None,
        "end_s": float(t[-1]) if n else None,
        "duration_s": duration,
        "rate_hz": rate,
        "buses": buses,
        "ids": ids,
        "clock": {
            "backwards": back,
            "backwards_where": back_at,
            "jumps": jumps,
            "jumps_where": jumps_at,
            "largest_step_s": largest,
            "duplicates_dropped": dups,
            "duplicates_where": dups_at,
        },
        "malformed_lines": bad,
        "malformed_where": bad_at,
        "remote_frames": remote,
        "remote_where": remote_at,
        "error_frames": errf,
        "error_where": errf_at,
    }
    if names is not None:
        known = msg_index >= 0
        present = np.unique(msg_index[known])
        out["dbc"] = {
            "file": str(dbc_path) if dbc_path is not None else None,
            "messages": len(names),
            "messages_present": [names[i] for i in present.tolist()],
            "frames_known_id": int(known.sum()),
            "frames_unknown_id": int((~known).sum()),
            "unknown_ids": int(
                len({(e["bus"], e["id"], e["extended"]) for e in ids if e.get("message") is None})
            ),
            "frames_shorter_than_dbc": int(np.sum(known & (frames.dlc < lengths[msg_index]))),
            "frames_longer_than_dbc": int(np.sum(known & (frames.dlc > lengths[msg_index]))),
        }
    out["problems"] = problems.to_list()
    out["information"] = problems.info_list()
    return out


def _ms(x) -> str:
    return "-" if x is None else f"{1000.0 * x:.1f}"


def format_info(info: dict) -> str:
    """The figures of :func:`log_info` as a text table."""
    lines = []
    lines.append(
        f"{info['file']}: {info['format']}, {info['frames']} frames, "
        f"{info['duration_s']:.3f} s ({info['start_s']:.6f} .. {info['end_s']:.6f}), "
        f"{info['rate_hz']:.1f} frames/s"
    )
    for b in info["buses"]:
        lines.append(f"  bus {b['bus']}: {b['frames']} frames, {b['rate_hz']:.1f} frames/s")
    has_dbc = "dbc" in info
    head = f"{'bus':>3} {'id':>10} {'ext':>3} "
    head += f"{'message':<24} " if has_dbc else ""
    head += (
        f"{'frames':>8} {'rate_Hz':>8} {'period_ms':>9} {'max_gap_ms':>10} {'gap/per':>7} "
        f"{'gaps':>5}"
    )
    lines.append("")
    lines.append(head)
    for e in info["ids"]:
        row = f"{e['bus']:>3} {e['id_hex']:>10} {'x' if e['extended'] else '':>3} "
        if has_dbc:
            row += f"{(e['message'] or '(not in DBC)')[:24]:<24} "
        ratio = "-" if e["max_gap_periods"] is None else f"{e['max_gap_periods']:.1f}"
        row += (
            f"{e['frames']:>8} {e['rate_hz']:>8.2f} {_ms(e['median_period_s']):>9} "
            f"{_ms(e['max_gap_s']):>10} {ratio:>7} {e['gaps']:>5}"
        )
        lines.append(row)
    c = info["clock"]
    lines.append("")
    lines.append(
        f"clock: {c['backwards']} step(s) backwards (re-sorted), {c['jumps']} jump(s) "
        f"forward, largest step {c['largest_step_s']:.6f} s, "
        f"{c['duplicates_dropped']} duplicate frame(s) dropped"
    )
    lines.append(
        f"malformed lines skipped: {info['malformed_lines']}"
        + (
            f" (first at {', '.join(map(str, info['malformed_where']))})"
            if info["malformed_where"]
            else ""
        )
        + f"; remote frames: {info['remote_frames']}; "
        f"error frames: {info['error_frames']}"
    )
    if has_dbc:
        d = info["dbc"]
        lines.append(
            f"DBC {d['file']}: {len(d['messages_present'])} of {d['messages']} messages "
            f"present; {d['frames_known_id']} frames with a DBC id, "
            f"{d['frames_unknown_id']} on {d['unknown_ids']} bus/id pair(s) not in the "
            f"DBC; "
            f"{d['frames_shorter_than_dbc']} shorter, {d['frames_longer_than_dbc']} "
            f"longer than the DBC length"
        )
    lines.append(f"gaps: intervals over {GAP_FACTOR:g} x the id's median period")
    return "\n".join(lines)
