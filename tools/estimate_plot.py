"""The state estimator on the real comma2k19 RAV4 minute, plotted against the raw channels.

    .venv/bin/python -m hmpc.tools.estimate_plot [--out DIR] [--params P.yaml] [--gnss-latency S]

Ingests the bundled minute (CAN + INS + IMU, as ``hmpc ingest`` / the demo do), identifies its
model with the RAV4 geometry unless ``--params`` is given, runs ``controller.estimator`` over
every raw message (``estimate_recording``), and writes ``estimate_comma.png`` and
``estimate_comma.json`` (final state, 1-sigma, per-sensor accepted/rejected counts).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

import numpy as np

from hmpc.controller.estimator import (
    IBR,
    IDOFF,
    IKWS,
    IPSI,
    IV,
    IX,
    IY,
    STATE_NAMES,
    EstimateRun,
    EstimatorConfig,
    estimate_recording,
)
from hmpc.models.params import Params, load_params
from hmpc.models.report.figure import new_figure, save_png
from hmpc.tools.datafiles import PARAMS_DIR, bundled

COMMA = "rav4-comma2k19"


def plot_estimate(run: EstimateRun, rec, params: Params, path, title: str) -> str:
    """Six panels, estimate against the raw channels it was fed; returns the PNG path."""
    t0 = float(run.t_s[0])
    t = run.t_s - t0
    x, s = run.state, run.sigma
    ok = np.isfinite(x[:, IX])
    fig, ax = new_figure(3, 2, figsize=(13, 11))
    ax = ax.ravel()
    gt, gx = rec.raw["x"]
    gy = rec.raw["y"][1]
    # 1: path
    ax[0].plot(gx, gy, ".", ms=2, color="0.6", label="GNSS/INS fixes (raw, 20 Hz)")
    ax[0].plot(x[ok, IX], x[ok, IY], "-", lw=1, color="C0", label="estimate")
    ax[0].set_xlabel("east x [m]")
    ax[0].set_ylabel("north y [m]")
    ax[0].set_title("path (local ENU; axes not to the same scale)")
    ax[0].legend(fontsize=8)
    # 2: estimate minus fix, along/across track
    inside = (run.t_s >= gt[0]) & (run.t_s <= gt[-1])  # no extrapolated fixes
    ex = np.where(inside, x[:, IX] - np.interp(run.t_s, gt, gx), np.nan)
    ey = np.where(inside, x[:, IY] - np.interp(run.t_s, gt, gy), np.nan)
    c, sn = np.cos(x[:, IPSI]), np.sin(x[:, IPSI])
    along, across = c * ex + sn * ey, -sn * ex + c * ey
    ax[1].plot(t, 100 * along, lw=0.8, label="along track")
    ax[1].plot(t, 100 * across, lw=0.8, label="across track")
    ax[1].fill_between(t, -200 * s[:, IX], 200 * s[:, IX], color="0.85", label="estimate +-2 sigma")
    ax[1].set_ylim(-15, 15)
    ax[1].set_xlabel("time [s]")
    ax[1].set_ylabel("estimate - GNSS fix [cm]")
    ax[1].set_title("position against the raw fixes")
    ax[1].legend(fontsize=8)
    # 3: speed
    wt = rec.raw["wheel_speed_fl"][0]
    wmean = sum(rec.raw[f"wheel_speed_{w}"][1] for w in ("fl", "fr", "rl", "rr")) / 4.0
    ax[2].plot(wt - t0, wmean, lw=0.6, color="0.6", label="CAN wheel-speed mean (raw, 83 Hz)")
    ax[2].plot(
        rec.raw["gps_speed"][0] - t0,
        rec.raw["gps_speed"][1],
        lw=0.8,
        color="C1",
        label="GNSS speed (raw)",
    )
    ax[2].plot(t, x[:, IV], lw=1.0, color="C0", label="estimate v")
    ax[2].set_xlabel("time [s]")
    ax[2].set_ylabel("speed [m/s]")
    ax[2].set_title("speed")
    ax[2].legend(fontsize=8)
    # 4: heading
    ht, hv = rec.raw["heading"]
    ax[3].plot(ht - t0, np.degrees(np.unwrap(hv)), lw=0.8, color="C1", label="INS heading (raw)")
    ax[3].plot(t, np.degrees(x[:, IPSI]), lw=1.0, ls="--", color="C0", label="estimate psi")
    ax[3].set_xlabel("time [s]")
    ax[3].set_ylabel("heading from east [deg]")
    ax[3].set_title("heading")
    ax[3].legend(fontsize=8)
    # 5: yaw rate
    yt, yv = rec.raw["yaw_rate"]
    ax[4].plot(yt - t0, yv, lw=0.5, color="0.6", label="IMU gyro (raw, 104 Hz)")
    track_r = params.vehicle.track_rear_m or params.vehicle.track_front_m
    ax[4].plot(
        wt - t0,
        (rec.raw["wheel_speed_rr"][1] - rec.raw["wheel_speed_rl"][1]) / track_r,
        lw=0.4,
        color="C2",
        alpha=0.3,
        zorder=1,
        label="rear wheel difference / track (eq. 5, not fed by default)",
    )
    swt, swv = rec.raw["steering_wheel_angle"]
    delta = (
        params.steering.offset_rad
        + params.steering.scale * np.interp(run.t_s, swt, swv)
        + x[:, IDOFF]
    )
    ax[4].plot(
        t,
        x[:, IV] * np.sin(delta) / params.vehicle.wheelbase_m,
        lw=1.0,
        color="C0",
        label="estimate v sin(delta) / b",
    )
    ax[4].plot(
        t,
        x[:, IV] * np.sin(delta) / params.vehicle.wheelbase_m + x[:, IBR],
        lw=0.8,
        color="C3",
        ls="--",
        label="+ estimated gyro bias",
    )
    ax[4].set_ylim(-0.06, 0.06)
    ax[4].set_xlabel("time [s]")
    ax[4].set_ylabel("yaw rate [rad/s] (clipped to +-0.06)")
    ax[4].set_title("yaw rate")
    ax[4].legend(fontsize=8)
    # 6: augmented states
    for i, scale, lab in (
        (IDOFF, 1e3, "road-wheel angle correction [mrad]"),
        (IBR, 1e3, "gyro bias [mrad/s]"),
        (IKWS, 100.0, "wheel-speed scale - 1 [%]"),
    ):
        val = (x[:, i] - (1.0 if i == IKWS else 0.0)) * scale
        (line,) = ax[5].plot(t, val, lw=1.0, label=lab)
        ax[5].fill_between(
            t,
            val - 2 * scale * s[:, i],
            val + 2 * scale * s[:, i],
            color=line.get_color(),
            alpha=0.15,
        )
    ax[5].set_xlabel("time [s]")
    ax[5].set_ylabel("value [unit in legend]")
    ax[5].set_title("augmented states (+-2 sigma)")
    ax[5].legend(fontsize=8)
    fig.suptitle(title)
    return save_png(fig, path, dpi=110)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="out/estimator", help="output folder (default out/estimator)")
    ap.add_argument("--params", help="model to use (default: identified from the minute)")
    ap.add_argument(
        "--gnss-latency",
        type=float,
        default=0.0,
        metavar="S",
        help="deliver each fix this late [s] (exercises the rewind on real data)",
    )
    args = ap.parse_args(argv)
    from hmpc.models.logs.ingest import ingest_files

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    res = ingest_files(
        bundled(f"{COMMA}/can.log.gz"),
        bundled("dbc/toyota_rav4_2017.dbc.gz"),
        PARAMS_DIR / "toyota_rav4_2017.signals.yaml",
        bundled(f"{COMMA}/nav.csv.gz"),
        bundled(f"{COMMA}/imu.csv.gz"),
    )
    rec = res.recording
    if args.params:
        params = load_params(args.params, require_model=True)
    else:
        from hmpc.models.identify.pipeline import identify

        params = identify(rec, load_params(PARAMS_DIR / "toyota_rav4_2017.yaml").vehicle).params
    cfg = EstimatorConfig()
    run = estimate_recording(rec, params, cfg, gnss_latency_s=args.gnss_latency)
    png = plot_estimate(
        run,
        rec,
        params,
        out / "estimate_comma.png",
        "controller.estimator on the comma2k19 RAV4 minute (I-280), raw channels",
    )
    last = int(np.flatnonzero(np.isfinite(run.state[:, 0]))[-1])
    summary = {
        "gnss_latency_s": args.gnss_latency,
        "ticks": int(len(run.t_s)),
        "messages": run.events,
        "stats": run.stats,
        "final_state": dict(zip(STATE_NAMES, map(float, run.state[last]))),
        "final_sigma": dict(zip(STATE_NAMES, map(float, run.sigma[last]))),
        "speed_vs_ingest_gps_ratio": res.summary.get("speed_vs_gps", {}).get("ratio_mean"),
    }
    (out / "estimate_comma.json").write_text(json.dumps(summary, indent=1, allow_nan=False) + "\n")
    print(json.dumps(summary, indent=1))
    print(f"wrote {png}", file=sys.stderr)
    return 0 if math.isfinite(summary["final_state"]["x_m"]) else 1


if __name__ == "__main__":
    sys.exit(main())
