"""Regenerate the figures of docs/adaptation.md: per hidden parameter set (tests/_adapt.py) and
scenario, the controller given the file with and without --adapt against the controller given
the truth, the learned values against the truth, and the learned-parameter figures.

    .venv/bin/python docs/adaptation_figures.py [SEEDS] [--png]

Prints the markdown tables; with --png writes docs/img/adaptation_<scenario>.png (seed 2).
"""
from __future__ import annotations

import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent / "tests"))

from _adapt import hidden_params  # noqa: E402
from hmpc.controller.adapt import ModelAdapter  # noqa: E402
from hmpc.controller.adapt.config import KEY_STEER_OFFSET, KEY_STEER_SCALE, zone_key  # noqa: E402
from hmpc.controller.build import make_controller  # noqa: E402
from hmpc.controller.closed_loop import run_closed_loop  # noqa: E402
from hmpc.models.params import load_params  # noqa: E402
from hmpc.models.report.adaptation import plot_adaptation  # noqa: E402
from hmpc.models.sim.scenarios import make_scenario  # noqa: E402


def run(params, truth, scenario, adapt):
    cp = params if adapt in ("file", "adapt") else truth
    ad = ModelAdapter(params, 0.1) if adapt == "adapt" else None
    res = run_closed_loop(make_controller("mpc", cp), make_scenario(scenario, params), cp,
                          plant_params=truth, adapter=ad)
    return res.metrics, ad


def main(argv):
    seeds = [int(s) for s in (argv[0] if argv and argv[0][0].isdigit() else "1,2,3,4,5,6,7,8")
             .split(",")]
    png = "--png" in argv
    params = load_params(HERE.parent / "params" / "report_2008.yaml")
    rows = {"figure8": [], "ramp_sequence": []}
    for seed in seeds:
        truth = hidden_params(params, seed)
        for sc in rows:
            m = {k: run(params, truth, sc, k) for k in ("truth", "file", "adapt")}
            a, ad = m["adapt"]
            ad_rep = a["adaptation"]
            z1, z2 = truth.zones[1], truth.zones[2]
            learned = {
                "offset_mrad": 1e3 * (ad_rep[KEY_STEER_OFFSET]["final"] - truth.steering.offset_rad),
                "scale_pct": 100 * (ad_rep[KEY_STEER_SCALE]["final"] / truth.steering.scale - 1),
                "low_pct": 100 * (ad_rep[zone_key("low", "scale_mps2")]["final"] / z1.scale_mps2 - 1),
                "high_pct": 100 * (ad_rep[zone_key("high", "scale_mps2")]["final"] / z2.scale_mps2
                                   - 1)}
            rows[sc].append((seed, {k: v[0] for k, v in m.items()}, learned,
                             a["adaptation_details"]["cost_us"]))
            if png and seed == seeds[min(1, len(seeds) - 1)]:
                t, v, s = ad.history.arrays()
                tr = {KEY_STEER_OFFSET: truth.steering.offset_rad,
                      KEY_STEER_SCALE: truth.steering.scale}
                for z in truth.zones:
                    tr.update({zone_key(z.name, c): getattr(z, c)
                               for c in ("offset_mps2", "scale_mps2", "brake_scale_mps2")})
                plot_adaptation(t - t[0], ad.keys, v, s, HERE / "img" / f"adaptation_{sc}.png",
                                title=f"{sc}, hidden set {seed}: learned parameters "
                                      "(estimate, 95 % interval, truth)", truth=tr)
    for sc, rs in rows.items():
        print(f"\n{sc}\n")
        print("| set | speed RMS truth / file / adapt [m/s] | lateral RMS truth / file / adapt [m]"
              " | reversals >=1 deg truth / file / adapt [1/min] | offset err [mrad] | scale err"
              " [%] | low gain err [%] | high gain err [%] | cost p50 / p99 [us] |")
        print("|---|---|---|---|---|---|---|---|---|")
        for seed, m, lr, cost in rs:
            f = lambda k: " / ".join(f"{m[x][k]:.3f}" for x in ("truth", "file", "adapt"))  # noqa
            r = " / ".join(f"{m[x]['steering_reversals_per_min']['1deg']:.1f}"
                           for x in ("truth", "file", "adapt"))
            print(f"| {seed} | {f('speed_error_rms_mps')} | {f('lateral_error_rms_m')} | {r} | "
                  f"{lr['offset_mrad']:+.2f} | {lr['scale_pct']:+.1f} | {lr['low_pct']:+.1f} | "
                  f"{lr['high_pct']:+.1f} | {cost['p50']:.0f} / {cost['p99']:.0f} |")


if __name__ == "__main__":
    main(sys.argv[1:])
