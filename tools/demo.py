"""`make demo`: hmpc's main job on the real recordings bundled in tools/data.

Runs the same subcommands a user would (`hmpc info`, `ingest`, `identify`, ...) on the comma2k19
RAV4 minute and the VerifiedCAN stop-and-go drive, and saves tables, JSON and plots in --out.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from hmpc.tools import cli
from hmpc.tools.datafiles import PARAMS_DIR, bundled

COMMA = "rav4-comma2k19"
VCAN = "rav4-2019-verifiedcan"


def steps(out: Path) -> list[tuple[str, list[str]]]:
    comma_log, comma_dbc = bundled(f"{COMMA}/can.log.gz"), bundled("dbc/toyota_rav4_2017.dbc.gz")
    vcan_log = bundled(f"{VCAN}/drive.csv.gz")
    vcan_dbc = bundled("dbc/toyota_rav4_2019_tss2.dbc.gz")
    return [
        (
            "info: comma2k19 RAV4 minute",
            [
                "info",
                str(comma_log),
                "--dbc",
                str(comma_dbc),
                "--json",
                str(out / "comma_info.json"),
            ],
        ),
        (
            "ingest: comma2k19 RAV4 minute (CAN + INS + IMU)",
            [
                "ingest",
                str(comma_log),
                "--dbc",
                str(comma_dbc),
                "--signals",
                str(PARAMS_DIR / "toyota_rav4_2017.signals.yaml"),
                "--nav",
                str(bundled(f"{COMMA}/nav.csv.gz")),
                "--imu",
                str(bundled(f"{COMMA}/imu.csv.gz")),
                "--out",
                str(out / "comma_rec.csv"),
                "--json",
                str(out / "comma_ingest.json"),
            ],
        ),
        (
            "info: VerifiedCAN RAV4 stop-and-go",
            ["info", str(vcan_log), "--dbc", str(vcan_dbc), "--json", str(out / "vcan_info.json")],
        ),
        (
            "ingest: VerifiedCAN RAV4 stop-and-go (CAN only)",
            [
                "ingest",
                str(vcan_log),
                "--dbc",
                str(vcan_dbc),
                "--signals",
                str(PARAMS_DIR / "toyota_rav4_2019.signals.yaml"),
                "--out",
                str(out / "vcan_rec.csv"),
                "--json",
                str(out / "vcan_ingest.json"),
            ],
        ),
        (
            "identify: comma2k19 minute (steering map eq. 7, zone models eq. 8)",
            [
                "identify",
                str(out / "comma_rec.csv"),
                "--vehicle",
                str(PARAMS_DIR / "toyota_rav4_2017.yaml"),
                "--out",
                str(out / "comma_params.yaml"),
                "--plots",
                str(out / "comma_identify"),
                "--json",
                str(out / "comma_identify.json"),
            ],
        ),
        (
            "identify: VerifiedCAN stop-and-go (car's own sensors, no GNSS)",
            [
                "identify",
                str(out / "vcan_rec.csv"),
                "--vehicle",
                str(PARAMS_DIR / "toyota_rav4_2019.yaml"),
                "--out",
                str(out / "vcan_params.yaml"),
                "--plots",
                str(out / "vcan_identify"),
                "--json",
                str(out / "vcan_identify.json"),
            ],
        ),
        (
            "simulate: ground-truth 'arcs' experiment (report section III) with the report's "
            "steering map and zone boundaries (its zone coefficients are placeholders: "
            "params/report_2008.yaml)",
            [
                "simulate",
                "--experiment",
                "arcs",
                "--params",
                str(PARAMS_DIR / "report_2008.yaml"),
                "--out",
                str(out / "sim_arcs.csv"),
                "--json",
                str(out / "sim_arcs.json"),
            ],
        ),
        (
            "simulate: hybrid MPC holding 1 m/s at idle, then stop and go",
            [
                "simulate",
                "--params",
                str(PARAMS_DIR / "report_2008.yaml"),
                "--scenario",
                "idle_hold",
                "--controller",
                "mpc",
                "--out",
                str(out / "mpc_idle_hold.csv"),
                "--plots",
                str(out / "mpc_idle_hold"),
                "--json",
                str(out / "mpc_idle_hold.json"),
            ],
        ),
        (
            "simulate: naive PID on the same scenario, for comparison",
            [
                "simulate",
                "--params",
                str(PARAMS_DIR / "report_2008.yaml"),
                "--scenario",
                "idle_hold",
                "--controller",
                "pid",
                "--json",
                str(out / "pid_idle_hold.json"),
            ],
        ),
        (
            "simulate: hybrid MPC on figure eights against a plant with 20% weaker zones",
            [
                "simulate",
                "--params",
                str(PARAMS_DIR / "report_2008.yaml"),
                "--scenario",
                "figure8",
                "--plant-params",
                str(PARAMS_DIR / "report_2008_weak_zones.yaml"),
                "--controller",
                "mpc",
                "--plots",
                str(out / "mpc_figure8_mismatch"),
                "--json",
                str(out / "mpc_figure8_mismatch.json"),
            ],
        ),
        (
            "drive: hybrid MPC drives figure eights in real time through the RAV4's own command "
            "frames (STEERING_LKA, ACC_CONTROL) on python-can's virtual bus, against the simulated "
            "car",
            [
                "drive",
                "--params",
                str(PARAMS_DIR / "report_2008.yaml"),
                "--actuation",
                str(PARAMS_DIR / "toyota_rav4_2017.actuation.yaml"),
                "--vehicle-sim",
                "--scenario",
                "figure8",
                "--duration",
                "30",
                "--candump",
                str(out / "drive_figure8.log"),
                "--json",
                str(out / "drive_figure8.json"),
            ],
        ),
        (
            "ingest: the drive's own candump, read back as any log",
            [
                "ingest",
                str(out / "drive_figure8.log"),
                "--dbc",
                str(comma_dbc),
                "--signals",
                str(PARAMS_DIR / "toyota_rav4_2017.signals.yaml"),
                "--out",
                str(out / "drive_rec.csv"),
                "--json",
                str(out / "drive_ingest.json"),
            ],
        ),
        (
            "diagnose: where the report's model and the VerifiedCAN drive differ, and why",
            [
                "diagnose",
                str(out / "vcan_rec.csv"),
                "--vehicle",
                str(PARAMS_DIR / "toyota_rav4_2019.yaml"),
                "--report",
                str(out / "vcan_diagnose"),
                "--json",
                str(out / "vcan_diagnose.json"),
            ],
        ),
    ]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="out/demo", help="output folder (default out/demo)")
    args = ap.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    failed = []
    for title, argv_ in steps(out):
        print(f"\n=== {title}\n$ hmpc {' '.join(argv_)}", flush=True)
        t0 = time.perf_counter()
        rc = cli.main(argv_)
        print(f"--- exit {rc} in {time.perf_counter() - t0:.1f} s", flush=True)
        if rc != 0:
            failed.append(title)
    from hmpc.models.logs.recording import Recording
    from hmpc.models.report.recording import plot_overview

    for name, label in (
        ("comma_rec", "comma2k19 RAV4 2017, I-280 minute"),
        ("vcan_rec", "VerifiedCAN RAV4 2019, stop-and-go"),
        ("drive_rec", "hmpc drive: MPC on figure8 over the virtual bus (RAV4 frames)"),
    ):
        rec_path = out / f"{name}.csv"
        if rec_path.exists():
            png = plot_overview(Recording.load(rec_path), str(out / f"{name}.png"), label)
            print(f"plot: {png}")
    print(f"\nDemo outputs in {out}/: " + ", ".join(sorted(p.name for p in out.iterdir())))
    if failed:
        print("FAILED: " + "; ".join(failed), file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
