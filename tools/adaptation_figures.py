"""The adaptation figures of docs/results.md and docs/adaptation.md: per hidden parameter set
(``hmpc.models.sim.hidden``) and scenario, the controller given the file with and without
``--adapt`` against the controller given the truth, the learned values against the truth,
and the learned parameters against time (plots: ``models/report/adaptation.py``).

    .venv/bin/python -m hmpc.tools.adaptation_figures [--seeds 1,2,...] [--png DIR]
        [--plot-seed N] [--json FILE]

Prints the markdown tables; with ``--png DIR`` writes DIR/adaptation_<scenario>.png for the
set ``--plot-seed`` (estimate, 95 % interval and truth of each learned value).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from hmpc.controller.adapt import ModelAdapter
from hmpc.controller.adapt.config import KEY_STEER_OFFSET, KEY_STEER_SCALE, zone_key
from hmpc.controller.build import make_controller
from hmpc.controller.closed_loop import run_closed_loop
from hmpc.models.params import load_params
from hmpc.models.sim.hidden import hidden_params
from hmpc.models.sim.scenarios import make_scenario
from hmpc.tools.datafiles import PARAMS_DIR

SCENARIOS = ("figure8", "ramp_sequence")
MODES = ("truth", "file", "adapt")


def run(params, truth, scenario: str, mode: str):
    """One closed loop: the controller given the truth, the file, or the file and the
    learner; returns (metrics, adapter or None)."""
    cp = truth if mode == "truth" else params
    ad = ModelAdapter(params, 0.1) if mode == "adapt" else None
    res = run_closed_loop(
        make_controller("mpc", cp),
        make_scenario(scenario, params),
        cp,
        plant_params=truth,
        adapter=ad,
    )
    return res.metrics, ad


def learned_errors(report: dict, truth) -> dict:
    """Final learned values against the truth: offset [mrad], scale and the low and high
    zones' accelerator gains [%]."""
    z1, z2 = truth.zones[1], truth.zones[2]
    return {
        "offset_mrad": 1e3 * (report[KEY_STEER_OFFSET]["final"] - truth.steering.offset_rad),
        "scale_pct": 100 * (report[KEY_STEER_SCALE]["final"] / truth.steering.scale - 1),
        "low_pct": 100 * (report[zone_key(z1.name, "scale_mps2")]["final"] / z1.scale_mps2 - 1),
        "high_pct": 100 * (report[zone_key(z2.name, "scale_mps2")]["final"] / z2.scale_mps2 - 1),
    }


def truth_values(truth) -> dict:
    """The hidden set's values under the learner's keys (the plots' truth lines)."""
    tr = {KEY_STEER_OFFSET: truth.steering.offset_rad, KEY_STEER_SCALE: truth.steering.scale}
    for z in truth.zones:
        tr.update(
            {
                zone_key(z.name, c): getattr(z, c)
                for c in ("offset_mps2", "scale_mps2", "brake_scale_mps2")
            }
        )
    return tr


def table(rows: list) -> str:
    """Markdown table of one scenario's rows (seed, metrics per mode, learned errors)."""
    out = [
        "| set | speed RMS truth / file / adapt [m/s] | lateral RMS truth / file / adapt [m] "
        "| reversals >=1 deg truth / file / adapt [1/min] | offset err [mrad] | scale err "
        "[%] | low gain err [%] | high gain err [%] | failures |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        m = r["metrics"]
        f = lambda k, m=m: " / ".join(f"{m[x][k]:.3f}" for x in MODES)  # noqa: E731
        rev = " / ".join(f"{m[x]['steering_reversals_per_min']['1deg']:.1f}" for x in MODES)
        e = r["learned"]
        fails = sum(m[x]["failures"] for x in MODES)
        out.append(
            f"| {r['seed']} | {f('speed_error_rms_mps')} | {f('lateral_error_rms_m')} | "
            f"{rev} | {e['offset_mrad']:+.2f} | {e['scale_pct']:+.1f} | "
            f"{e['low_pct']:+.1f} | {e['high_pct']:+.1f} | {fails} |"
        )
    return "\n".join(out)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", default="1,2,3,4,5,6,7,8")
    ap.add_argument("--png", metavar="DIR", help="write the learned-parameter plots here")
    ap.add_argument("--plot-seed", type=int, default=2)
    ap.add_argument("--json", metavar="FILE")
    args = ap.parse_args(argv)
    from hmpc.models.report.adaptation import plot_adaptation

    try:
        seeds = [int(s) for s in args.seeds.split(",")]
    except ValueError:
        ap.error(f"--seeds {args.seeds}: give whole numbers separated by commas")
    if args.png:  # made before the runs: a missing folder must not end minutes of work
        Path(args.png).mkdir(parents=True, exist_ok=True)
    params = load_params(PARAMS_DIR / "report_2008.yaml")
    rows: dict = {sc: [] for sc in SCENARIOS}
    for seed in seeds:
        truth = hidden_params(params, seed)
        for sc in SCENARIOS:
            print(f"adaptation_figures: set {seed}, {sc} ...", file=sys.stderr, flush=True)
            got = {mode: run(params, truth, sc, mode) for mode in MODES}
            m = {mode: v[0] for mode, v in got.items()}
            ad = got["adapt"][1]
            rows[sc].append(
                {
                    "seed": seed,
                    "metrics": m,
                    "learned": learned_errors(m["adapt"]["adaptation"], truth),
                }
            )
            if args.png and seed == args.plot_seed:
                t, v, s = ad.history.arrays()
                out = Path(args.png) / f"adaptation_{sc}.png"
                plot_adaptation(
                    t - t[0],
                    ad.keys,
                    v,
                    s,
                    out,
                    title=f"{sc}, hidden set {seed}: learned parameters "
                    "(estimate, 95 % interval, truth)",
                    truth=truth_values(truth),
                )
    for sc, rs in rows.items():
        print(f"\n**{sc}**\n")
        print(table(rs))
    if args.json:
        slim = {
            sc: [
                {
                    "seed": r["seed"],
                    "learned": r["learned"],
                    "metrics": {
                        k: {
                            q: r["metrics"][k][q]
                            for q in (
                                "speed_error_rms_mps",
                                "lateral_error_rms_m",
                                "steering_reversals_per_min",
                                "failures",
                            )
                        }
                        for k in MODES
                    },
                }
                for r in rs
            ]
            for sc, rs in rows.items()
        }
        tmp = Path(args.json).with_suffix(".tmp")
        tmp.write_text(json.dumps(slim, indent=2) + "\n", encoding="utf-8")
        tmp.replace(args.json)
    return 0


if __name__ == "__main__":
    sys.exit(main())
