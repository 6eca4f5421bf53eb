"""`hmpc fleet run` and `hmpc fleet report` on a small simulated fleet of known cars: vehicle A
unchanged over its drives, vehicle B whose pedal gains fall 20 % from its third drive. The run
finishes every drive, a rerun skips them all, the report pools A's steering scale near the
truth, finds no drift on A and B's step at B3; a scheduler with two workers started as separate
processes gives the same table; a corrupt drive fails alone."""

import hashlib
import json
import os
import shutil
import signal
import subprocess
import sys
import time

import pytest

from hmpc.models.fleet.report import query_values
from hmpc.models.fleet.simfleet import SimVehicle, write_fleet
from hmpc.models.params import load_params
from hmpc.tools import cli
from _data import PARAMS_DIR, bundled

pytestmark = pytest.mark.dask

VEHICLES = [SimVehicle("A", 11), SimVehicle("B", 22, drift_from=3, pedal_factor=0.8)]
DRIVES_PER_VEHICLE = 4
#: a short drive (arcs, then the open-loop pedal programme: about 190 s) identifies every
#: part of the model and keeps the module's CPU time small on two cores
DRIVE_S = 150.0
STEPS = "ingest,identify"
CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")


@pytest.fixture(scope="module")
def fleet(tmp_path_factory):
    d = tmp_path_factory.mktemp("fleet")
    manifest = write_fleet(d / "drives", VEHICLES, DRIVES_PER_VEHICLE, duration_s=DRIVE_S)
    store = d / "store"
    rc = cli.main(
        [
            "fleet",
            "run",
            str(manifest),
            "--out",
            str(store),
            "--workers",
            "2",
            "--steps",
            STEPS,
            "--json",
            str(d / "run1.json"),
        ]
    )
    assert rc == 0
    return {
        "dir": d,
        "manifest": manifest,
        "store": store,
        "run1": json.loads((d / "run1.json").read_text()),
    }


@pytest.fixture(scope="module")
def report(fleet):
    d = fleet["dir"]
    rc = cli.main(
        [
            "fleet",
            "report",
            str(fleet["store"]),
            "--json",
            str(d / "report.json"),
            "--html",
            str(d / "html"),
        ]
    )
    assert rc == 0
    return json.loads((d / "report.json").read_text())


def test_every_drive_finishes_and_its_folder_holds_each_output(fleet):
    run = fleet["run1"]
    ids = [f"{v.vehicle_id}{n}" for v in VEHICLES for n in range(1, DRIVES_PER_VEHICLE + 1)]
    assert run["drives"] == len(ids) and sorted(run["done"]) == sorted(ids)
    assert run["failed"] == [] and run["skipped"] == [] and run["wall_s"] > 0
    for did in ids:
        folder = fleet["store"] / "drives" / did
        status = json.loads((folder / "status.json").read_text())
        assert status["exit"] == 0 and status["error"] is None
        assert status["steps"] == ["ingest", "identify"]
        rec = fleet["manifest"].parent / f"{did}.parquet"
        assert (
            status["inputs"]["recording"]["sha256"] == hashlib.sha256(rec.read_bytes()).hexdigest()
        )
        assert status["hmpc_version"] and status["timings_s"]["identify"] > 0
        assert load_params(folder / "params.yaml", require_model=True).steering.scale > 0
        assert (folder / "recording.parquet").stat().st_size > 0
    assert not any((fleet["store"] / ".tmp").glob("*"))


def test_a_rerun_skips_every_finished_drive_and_rewrites_nothing(fleet, tmp_path):
    status = fleet["store"] / "drives" / "A1" / "status.json"
    before = status.stat().st_mtime_ns
    rc = cli.main(
        [
            "fleet",
            "run",
            str(fleet["manifest"]),
            "--out",
            str(fleet["store"]),
            "--workers",
            "2",
            "--steps",
            STEPS,
            "--json",
            str(tmp_path / "run2.json"),
        ]
    )
    run2 = json.loads((tmp_path / "run2.json").read_text())
    assert rc == 0 and run2["done"] == [] and run2["failed"] == []
    assert sorted(run2["skipped"]) == sorted(fleet["run1"]["done"])
    assert status.stat().st_mtime_ns == before


def test_report_pools_a_steering_scale_near_the_truth_and_finds_no_drift_on_a(report):
    a = report["vehicles"]["A"]
    truth = VEHICLES[0].truth(1)
    assert a["drives"] == DRIVES_PER_VEHICLE
    sc = a["parameters"]["steering.scale"]
    assert abs(sc["pooled"] / truth.steering.scale - 1) < 0.005
    assert sc["ci95"][0] < sc["pooled"] < sc["ci95"][1]
    assert [p["drive_id"] for p in sc["per_drive"]] == [f"A{n}" for n in range(1, 5)]
    for key, e in a["parameters"].items():
        assert e["drift"] is None, key


def test_report_finds_b_pedal_gain_step_from_its_third_drive(report):
    b = report["vehicles"]["B"]["parameters"]
    truth0 = VEHICLES[1].truth(1)
    for z in truth0.zones:
        for k in ("scale_mps2", "brake_scale_mps2"):
            d = b[f"longitudinal.zones.{z.name}.{k}"]["drift"]
            assert d is not None and d["from_drive"] == "B3" and d["kind"] == "step", (z, k)
            assert abs(d["after"] / d["before"] - 0.8) < 0.05
    assert b["steering.scale"]["drift"] is None
    # vehicles of one model compared (each vehicle here is its own model)
    assert set(report["models"]) == {"A", "B"}


def test_html_report_has_a_figure_per_vehicle_and_links_to_the_drives(report, fleet):
    html_dir = fleet["dir"] / "html"
    html = (html_dir / "index.html").read_text()
    assert "step from B3" in html and "Failed drives" in html
    for v in ("A", "B"):
        assert (html_dir / f"vehicle_{v}.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    links = [ln.split('"')[1] for ln in html.split("<a href=")[1:]]
    assert len(links) == 2 * DRIVES_PER_VEHICLE
    assert all((html_dir / link).resolve().exists() for link in links)


@pytest.mark.skipif(
    CHROMIUM is None,
    reason="no chromium on this machine (apt-get install chromium); the HTML test above still runs",
)
def test_html_report_renders_in_headless_chromium(report, fleet, tmp_path):
    import numpy as np
    from matplotlib.image import imread

    shot = tmp_path / "shot.png"
    url = (fleet["dir"] / "html" / "index.html").resolve().as_uri()
    subprocess.run(
        [
            CHROMIUM,
            "--headless",
            "--no-sandbox",
            "--disable-gpu",
            "--hide-scrollbars",
            f"--user-data-dir={tmp_path / 'profile'}",
            "--window-size=1200,1600",
            f"--screenshot={shot}",
            url,
        ],
        check=True,
        capture_output=True,
        timeout=120,
    )
    img = imread(shot)
    assert img.shape[0] >= 1000 and float(np.std(img[..., :3])) > 0.05


def _table_hash(store) -> str:
    return hashlib.sha256(repr(query_values(store)).encode()).hexdigest()


def _pooled(report_json: dict) -> dict:
    return {
        (vid, k): e["pooled"]
        for vid, v in report_json["vehicles"].items()
        for k, e in v["parameters"].items()
    }


def test_a_scheduler_with_two_worker_processes_gives_the_same_results(fleet, report, tmp_path):
    dask = [sys.executable, "-m", "dask"]
    sched_file = tmp_path / "scheduler.json"
    env = {**os.environ, "DASK_DISTRIBUTED__WORKER__DAEMON": "False"}
    procs = [
        subprocess.Popen(
            dask
            + [
                "scheduler",
                "--host",
                "127.0.0.1",
                "--port",
                "0",
                "--no-dashboard",
                "--scheduler-file",
                str(sched_file),
            ],
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
            env=env,
        )
    ]
    try:
        for _ in range(600):
            if sched_file.exists() and sched_file.stat().st_size:
                break
            time.sleep(0.1)
        address = json.loads(sched_file.read_text())["address"]
        for _ in range(2):
            procs.append(
                subprocess.Popen(
                    dask
                    + [
                        "worker",
                        "--scheduler-file",
                        str(sched_file),
                        "--nthreads",
                        "1",
                        "--no-dashboard",
                        "--host",
                        "127.0.0.1",
                    ],
                    stdout=subprocess.DEVNULL,
                    stderr=subprocess.DEVNULL,
                    env=env,
                )
            )
        store = tmp_path / "store"
        rc = cli.main(
            [
                "fleet",
                "run",
                str(fleet["manifest"]),
                "--out",
                str(store),
                "--scheduler",
                address,
                "--steps",
                STEPS,
                "--json",
                str(tmp_path / "run.json"),
            ]
        )
        run = json.loads((tmp_path / "run.json").read_text())
        assert rc == 0 and len(run["done"]) == 2 * DRIVES_PER_VEHICLE
        workers = {
            json.loads((store / "drives" / d / "status.json").read_text())["worker"]
            for d in run["done"]
        }
        assert all(str(os.getpid()) != w.rsplit(":", 1)[1] for w in workers)
    finally:
        for p in procs:
            p.send_signal(signal.SIGINT)
        for p in procs:
            try:
                p.wait(timeout=30)
            except subprocess.TimeoutExpired:
                p.kill()
    assert _table_hash(store) == _table_hash(fleet["store"])
    assert cli.main(["fleet", "report", str(store), "--json", str(tmp_path / "rep.json")]) == 0
    other = _pooled(json.loads((tmp_path / "rep.json").read_text()))
    mine = _pooled(report)
    assert other.keys() == mine.keys()
    assert all(abs(other[k] - mine[k]) <= 1e-9 for k in mine)


def test_a_corrupt_drive_fails_alone_and_the_rest_finish(fleet, tmp_path, capsys):
    """One good drive with every step (diagnose too), a truncated CAN log, a missing file."""
    import gzip

    src = fleet["manifest"].parent
    log = tmp_path / "trunc.log"
    with gzip.open(bundled("rav4-comma2k19/can.log.gz"), "rt") as fh:
        log.write_text("".join(fh.readline() for _ in range(40)))
    dbc = bundled("dbc/toyota_rav4_2017.dbc.gz")
    sig = PARAMS_DIR / "toyota_rav4_2017.signals.yaml"
    m = tmp_path / "m.csv"
    m.write_text(
        "vehicle_id,drive_id,start_time,geometry,recording,log,dbc,signals\n"
        f"A,A1,2026-01-05T08:00:00Z,{src / 'A.geometry.yaml'},{src / 'A1.parquet'},,,\n"
        f"R,R1,2026-01-05T09:00:00Z,{PARAMS_DIR / 'toyota_rav4_2017.yaml'},,{log},"
        f"{dbc},{sig}\n"
        f"A,A9,2026-01-06T08:00:00Z,{src / 'A.geometry.yaml'},"
        f"{tmp_path / 'gone.csv'},,,\n"
    )
    store = tmp_path / "store"
    rc = cli.main(
        [
            "fleet",
            "run",
            str(m),
            "--out",
            str(store),
            "--workers",
            "2",
            "--json",
            str(tmp_path / "run.json"),
        ]
    )
    out = capsys.readouterr().out
    run = json.loads((tmp_path / "run.json").read_text())
    assert rc == 1 and run["done"] == ["A1"]
    failed = {f["drive_id"]: f for f in run["failed"]}
    assert set(failed) == {"R1", "A9"} and all(f["exit"] == 2 for f in failed.values())
    assert str(log) in failed["R1"]["error"] and "do not overlap" in failed["R1"]["error"]
    assert "gone.csv" in failed["A9"]["error"]
    assert all("\n" not in f["error"] for f in failed.values())
    assert "failed R1 (exit 2)" in out
    good = store / "drives" / "A1"
    assert (good / "diagnosis.json").exists() and (good / "report" / "index.html").exists()
    load_params(good / "params.yaml", require_model=True)
    for did in ("R1", "A9"):  # a failed drive keeps only its status
        assert [p.name for p in (store / "drives" / did).iterdir()] == ["status.json"]
    assert (
        cli.main(
            [
                "fleet",
                "report",
                str(store),
                "--json",
                str(tmp_path / "r.json"),
                "--html",
                str(tmp_path / "html"),
            ]
        )
        == 0
    )
    rep = json.loads((tmp_path / "r.json").read_text())
    assert {f["drive_id"] for f in rep["failed"]} == {"R1", "A9"}
    html = (tmp_path / "html" / "index.html").read_text()
    assert "gone.csv" in html and 'href="' in html
    link = html.split('<a href="')[1].split('"')[0]
    assert link.endswith("report/index.html") and (tmp_path / "html" / link).resolve().exists()


def _signal_state(pid: int) -> str:
    """What the kernel says of ``pid``'s SIGINT and process group as SIGINT is sent (for the
    failure message: a run that finished as if no Ctrl-C came)."""
    try:
        with open(f"/proc/{pid}/status") as fh:
            st = dict(ln.rstrip("\n").split(":\t", 1) for ln in fh if ":\t" in ln)
        bit = 1 << (signal.SIGINT - 1)
        sig = {
            k: bool(int(st[k], 16) & bit)
            for k in ("SigPnd", "ShdPnd", "SigBlk", "SigIgn", "SigCgt")
        }
        return f"pgid {os.getpgid(pid)} state {st['State']} threads {st['Threads']} SIGINT {sig}"
    except OSError as exc:
        return f"pid {pid}: {exc}"


def test_ctrl_c_leaves_every_finished_drive_usable_and_a_rerun_does_the_rest(fleet, tmp_path):
    """SIGINT to the whole process group (what Ctrl-C in a terminal sends) once the first
    drive is in the store."""
    store = tmp_path / "store"
    # started as from a terminal: SIGINT at its default, whatever this test process (an xdist
    # worker) holds (a child inherits an ignored SIGINT, and Python then raises no
    # KeyboardInterrupt in it)
    cmd = [
        sys.executable,
        "-c",
        "import runpy, signal, sys; signal.signal(signal.SIGINT, signal.default_int_handler); "
        "sys.argv[0] = 'hmpc'; runpy.run_module('hmpc', run_name='__main__', alter_sys=True)",
        "fleet",
        "run",
        str(fleet["manifest"]),
        "--out",
        str(store),
        "--workers",
        "2",
        "--steps",
        STEPS,
        "--json",
        str(tmp_path / "run.json"),
    ]
    p = subprocess.Popen(
        cmd, start_new_session=True, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )
    try:
        for _ in range(6000):
            if any((store / "drives").glob("*/status.json")) or p.poll() is not None:
                break
            time.sleep(0.05)
        sent = f"run: {_signal_state(p.pid)}; this process: {_signal_state(os.getpid())}"
        os.killpg(p.pid, signal.SIGINT)
        out, err = p.communicate(timeout=120)
    finally:
        if p.poll() is None:
            os.killpg(p.pid, signal.SIGKILL)
    run = json.loads((tmp_path / "run.json").read_text())
    assert p.returncode == 130 and run["interrupted"], (sent, out[-1000:], err[-2000:])
    assert "Traceback" not in err
    finished = sorted(d.name for d in (store / "drives").iterdir())
    assert finished and len(finished) < 2 * DRIVES_PER_VEHICLE
    for did in finished:  # every folder in the store is whole
        status = json.loads((store / "drives" / did / "status.json").read_text())
        assert status["exit"] == 0, status
        load_params(store / "drives" / did / "params.yaml", require_model=True)
    assert sorted(run["done"]) == finished
    rc = cli.main(
        [
            "fleet",
            "run",
            str(fleet["manifest"]),
            "--out",
            str(store),
            "--workers",
            "2",
            "--steps",
            STEPS,
            "--json",
            str(tmp_path / "run2.json"),
        ]
    )
    run2 = json.loads((tmp_path / "run2.json").read_text())
    assert rc == 0 and sorted(run2["skipped"]) == finished
    assert len(run2["done"]) == 2 * DRIVES_PER_VEHICLE - len(finished)
