"""``hmpc fleet run``: every drive of a manifest through ingest, identify and diagnose on a Dask
distributed cluster, each drive's results committed whole to the store.

The client hashes every input first (sha256) and skips a drive whose finished status has the
same inputs, hmpc version and steps (``models.fleet.store.finished``); when nothing is left
to do no cluster is started, so a rerun of a finished fleet takes the time of the hashing.
The drives left are submitted to a LocalCluster of worker processes (one thread each) or to
an existing scheduler; each worker runs ``models.fleet.drive.process_drive``, which commits
the drive's folder itself, so a drive finished before an interrupt stays usable.
"""

from __future__ import annotations

import logging
import math
import os
import signal
import sys
import threading
import time
import uuid
from dataclasses import dataclass, field

from hmpc import __version__
from hmpc.models.errors import InputError
from hmpc.models.fleet import store as st
from hmpc.models.fleet.drive import base_status, process_drive
from hmpc.models.fleet.manifest import Drive, file_sha256, inputs_digest, read_manifest


@dataclass
class RunResult:
    """What a run did (the run JSON: docs/conventions.md, "Fleet")."""

    drives: int = 0
    done: list = field(default_factory=list)
    skipped: list = field(default_factory=list)
    failed: list = field(default_factory=list)
    wall_s: float = 0.0
    statuses: dict = field(default_factory=dict)
    interrupted: bool = False

    def to_json(self) -> dict:
        return {
            "drives": self.drives,
            "done": self.done,
            "skipped": self.skipped,
            "failed": self.failed,
            "wall_s": round(self.wall_s, 3),
            "interrupted": self.interrupted,
        }


def _hash_inputs(drive: Drive) -> tuple[dict, str]:
    """({role: {path, sha256}}, inputs_sha256); InputError when a file cannot be read."""
    hashes = {role: file_sha256(p) for role, p in drive.files.items()}
    inputs = {role: {"path": drive.files[role], "sha256": h} for role, h in hashes.items()}
    return inputs, inputs_digest(drive, hashes)


def _failed_entry(status: dict) -> dict:
    return {
        "vehicle_id": status["vehicle_id"],
        "drive_id": status["drive_id"],
        "exit": status["exit"],
        "error": status["error"],
    }


#: characters of the progress bar: the whole line stays within 80 columns
_BAR_CHARS = 24
#: how long to wait for a scheduler to answer [s]: a scheduler on the network answers in
#: well under a second; 20 s rides out a busy one without hanging a typo for long
_CONNECT_TIMEOUT_S = 20


class Progress:
    """One status line on stderr: done, failed, to go, ETA (rewritten in place on a
    terminal, a line per drive otherwise)."""

    def __init__(self, total: int, stream=None):
        self.total, self.done, self.failed = total, 0, 0
        self.stream = stream or sys.stderr
        self.tty = hasattr(self.stream, "isatty") and self.stream.isatty()
        self.t0 = time.perf_counter()

    def update(self, ok: bool, drive_id: str) -> None:
        self.done += ok
        self.failed += not ok
        n = self.done + self.failed
        el = time.perf_counter() - self.t0
        eta = el / n * (self.total - n) if n else math.nan
        fill = int(round(_BAR_CHARS * n / max(self.total, 1)))
        line = (
            f"hmpc fleet: [{'#' * fill}{'.' * (_BAR_CHARS - fill)}] {n}/{self.total} "
            f"done {self.done}, failed {self.failed}, ETA {_clock(eta)} ({drive_id})"
        )
        if self.tty:
            print("\r" + line, end="" if n < self.total else "\n", file=self.stream, flush=True)
        else:
            print(line, file=self.stream, flush=True)


def _clock(s: float) -> str:
    if not math.isfinite(s):
        return "?"
    s = int(round(s))
    return f"{s // 3600}:{s // 60 % 60:02d}:{s % 60:02d}"


def plan(drives: list[Drive], store, steps) -> tuple[list, list, dict]:
    """(to do [(drive, inputs, digest)], skipped ids, unreadable {drive_id: status})."""
    todo, skipped, unreadable = [], [], {}
    for d in drives:
        try:
            inputs, digest = _hash_inputs(d)
        except InputError as exc:
            status = base_status(d, {}, "", steps)
            status["exit"], status["error"] = 2, " ".join(exc.one_line().split())
            unreadable[d.drive_id] = status
            continue
        if st.finished(st.read_status(store, d.drive_id), digest, __version__, steps):
            skipped.append(d.drive_id)
        else:
            todo.append((d, inputs, digest))
    return todo, skipped, unreadable


def _commit_status(store, status: dict) -> None:
    """A drive that failed outside a worker's drive task (its inputs cannot be read, or its
    worker was lost): its status committed like any other failure."""
    tmp = st.new_tmp_dir(store, status["drive_id"])
    st.write_json_file(tmp / st.STATUS, status)
    st.commit(tmp, store, status["drive_id"])


def run_fleet(
    manifest,
    store,
    *,
    steps=st.STEPS,
    workers: int | None = None,
    scheduler: str | None = None,
    progress_stream=None,
) -> RunResult:
    """Run the fleet of ``manifest`` into ``store`` (see the module doc).

    On Ctrl-C (KeyboardInterrupt) the drives not finished are cancelled and the result says
    ``interrupted``; every drive finished before it is in the store.

    Raises:
        InputError: a bad manifest, or a scheduler that cannot be reached (exit 2).
    """
    t0 = time.perf_counter()
    drives = read_manifest(manifest)
    store = os.path.abspath(store)
    os.makedirs(store, exist_ok=True)
    st.clear_tmp(store)
    res = RunResult(drives=len(drives))
    todo, res.skipped, unreadable = plan(drives, store, steps)
    prog = Progress(len(todo) + len(unreadable), progress_stream)
    for did, status in unreadable.items():
        _commit_status(store, status)
        res.statuses[did] = status
        res.failed.append(_failed_entry(status))
        prog.update(False, did)
    if todo:
        try:
            _submit_all(todo, store, tuple(steps), workers, scheduler, res, prog)
        except KeyboardInterrupt:
            # the drives not finished are cancelled; each finished one is already committed,
            # also those whose result had not reached this process yet
            res.interrupted = True
            for d, _, digest in todo:
                if d.drive_id not in res.statuses and st.finished(
                    st.read_status(store, d.drive_id), digest, __version__, steps
                ):
                    res.done.append(d.drive_id)
    order = {d.drive_id: i for i, d in enumerate(drives)}
    res.done.sort(key=lambda d: order[d])
    res.failed.sort(key=lambda f: order[f["drive_id"]])
    res.wall_s = time.perf_counter() - t0
    return res


def _client(workers: int | None, scheduler: str | None):
    """A Dask client: on the scheduler at ``scheduler``, or on a LocalCluster of ``workers``
    single-threaded worker processes (default: the machine's cores)."""
    from distributed import Client, LocalCluster

    if scheduler:
        try:
            return Client(scheduler, timeout=f"{_CONNECT_TIMEOUT_S}s"), None
        except (OSError, TimeoutError, ValueError) as exc:
            raise InputError(
                f"cannot reach the Dask scheduler ({' '.join(str(exc).split())})", scheduler
            ) from None
    n = workers or os.cpu_count() or 1
    # the worker processes start with SIGINT ignored (inherited; Python then installs no
    # KeyboardInterrupt handler in them): Ctrl-C reaches this process alone, which cancels
    # the drives not finished and closes the cluster, instead of every worker dying on it
    # with a traceback of its own
    old = signal.signal(signal.SIGINT, signal.SIG_IGN) if _main_thread() else None
    try:
        # no dashboard; the scheduler's small HTTP server on a free loopback port (the
        # default, 8787, warns when another cluster on the machine holds it)
        cluster = LocalCluster(
            n_workers=n,
            threads_per_worker=1,
            processes=True,
            host="127.0.0.1",
            dashboard_address=None,
            scheduler_kwargs={"dashboard_address": "127.0.0.1:0"},
            silence_logs=logging.CRITICAL,
        )
    finally:
        if old is not None:
            signal.signal(signal.SIGINT, old)
    return Client(cluster), cluster


def _main_thread() -> bool:
    return threading.current_thread() is threading.main_thread()


def _submit_all(todo, store, steps, workers, scheduler, res: RunResult, prog: Progress):
    from distributed import as_completed

    client, cluster = _client(workers, scheduler)
    futures, of = [], {}
    try:
        for d, inputs, digest in todo:
            # pure=False: a drive is a side effect on the store, never taken from a cache
            fut = client.submit(
                process_drive,
                d,
                inputs,
                digest,
                store,
                steps,
                key=f"hmpc-fleet-{d.drive_id}-{uuid.uuid4().hex[:8]}",
                pure=False,
            )
            futures.append(fut)
            of[fut.key] = (d, inputs, digest)
        for fut in as_completed(futures):
            try:
                status = fut.result()
            except Exception as exc:  # noqa: BLE001 -- a lost worker fails its drive only
                d, inputs, digest = of[fut.key]
                status = base_status(d, inputs, digest, steps)
                status["exit"] = 1
                status["error"] = " ".join(f"worker failed: {type(exc).__name__}: {exc}".split())
                _commit_status(store, status)
            res.statuses[status["drive_id"]] = status
            if status["exit"] == 0:
                res.done.append(status["drive_id"])
            else:
                res.failed.append(_failed_entry(status))
            prog.update(status["exit"] == 0, status["drive_id"])
    finally:
        for f in futures:
            if not f.done():
                f.cancel()
        client.close()
        if cluster is not None:
            cluster.close()
