"""Is hmpc's actuator-delay estimate biased when the car is driven by an ACC request in closed
loop on a hilly road? Generates recordings with tests/indep/acc_truth.py (a known dead time d
and lag tau between ``accel_cmd`` and the car's acceleration; the request closes the loop on
the measured wheel speeds; the car's ECU rejects the grade through its own integrator),
diagnoses each with hmpc's library call ``diagnose(rec, vehicle)`` and prints, per case:

- the truth: d, tau, d + tau [s];
- every longitudinal finding with its parameters and intervals, and the longitudinal
  dead-time / lag hypotheses that were not findings (their fit, gain and why);
- the joint dead time + lag fit (``channels[...]['response']``) and the notes about it;
- errors: the named single description against the truth's effective delay d + tau (a single
  dead time or a single lag describes the whole response; for a pure dead-time truth this is
  ``delay_s`` against d), the joint fit's ``effective_delay_s`` (its 63 % step-response time,
  d + tau) against d + tau and its d and tau against the truth's, and whether the truth lies
  in the intervals;

then a summary per case and duration (mean, spread and median of the errors over the seeds).
The same seed gives the same planner, road and steering in every case (paired comparisons).

Test-only (hmpc never imports it); run from the repository root:
``.venv/bin/python tests/indep/acc_matrix.py [--cases ...] [--seeds60 0 1 2] [--seed600 0]
[--durations 600 60] [--gain 1.0] [--json OUT]``.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from indep import acc_truth as at  # noqa: E402

#: case -> (dead time d [s], lag tau [s], grade amplitude [rad])
CASES = {
    "dead05": (0.5, 0.0, 0.03),
    "dead03_lag02": (0.3, 0.2, 0.03),
    "dead025": (0.25, 0.0, 0.03),
    "lag04": (0.05, 0.4, 0.03),
    "dead05_flat": (0.5, 0.0, 0.0),
}
RESPONSE = {"actuator_delay": "delay_s", "actuator_lag": "tau_s"}


def _r(x, nd=3):
    """Round floats (and lists of them) for printing; pass anything else through."""
    if isinstance(x, float):
        return round(x, nd)
    if isinstance(x, (list, tuple)):
        return [_r(v, nd) for v in x]
    return x


def run_case(case: str, duration_s: float, seed: int, gain: float = 1.0) -> dict:
    """Generate and diagnose one recording; the matrix row (plain data, picklable)."""
    from hmpc.models.diagnose.diagnose import diagnose
    from hmpc.models.logs.recording import Recording
    from hmpc.models.params import parse_params

    d, tau, amp = CASES[case]
    sc = at.scenario(d, tau, seed=seed, duration_s=duration_s, grade_amp_rad=amp, gain=gain)
    t0 = time.perf_counter()
    rec = Recording(at.record(sc), meta={"path": f"acc_truth {case} {duration_s:g}s seed {seed}"})
    t_gen = time.perf_counter() - t0
    t0 = time.perf_counter()
    row = {
        "case": case,
        "duration_s": duration_s,
        "seed": seed,
        "gain_K": gain,
        "d": d,
        "tau": tau,
        "eff": d + tau,
        "t_gen_s": round(t_gen, 1),
    }
    try:
        dg = diagnose(rec, parse_params(at.geometry()).vehicle)
    except Exception:  # report hmpc's traceback, do not hide it
        import traceback

        row["crash"] = traceback.format_exc()
        return row
    row["t_diag_s"] = round(time.perf_counter() - t0, 1)
    row["input"] = getattr(dg, "longitudinal_input", None)
    row["findings"] = [
        {
            "effect": f["effect"],
            "gain": _r(f["gain"]),
            "parameters": {k: _r(v, 4) for k, v in f["parameters"].items() if isinstance(v, float)},
            "intervals": {k: _r(v, 4) for k, v in f["intervals"].items()},
            "on_top_of": f.get("on_top_of"),
        }
        for f in dg.findings
        if f["subsystem"] == "longitudinal"
    ]
    row["other_hyp"] = [
        {
            "effect": h["effect"],
            "finding": h.get("finding"),
            "gain": _r(h.get("gain")),
            "parameters": {k: _r(v, 4) for k, v in h.get("parameters", {}).items()},
            "intervals": {k: _r(v, 4) for k, v in h.get("intervals", {}).items()},
            "why": h.get("why"),
        }
        for h in dg.hypotheses
        if h.get("subsystem") == "longitudinal"
        and h.get("effect") in RESPONSE
        and not h.get("finding")
    ]
    # the joint dead time + lag fit (present when a delay or lag was found or hinted at)
    resp = dg.channels.get("speed", {}).get("response") or {}
    row["joint"] = {
        k: _r(v, 4)
        for k, v in resp.items()
        if k
        in (
            "dead_time_s",
            "tau_s",
            "effective_delay_s",
            "intervals",
            "lr_dead_time_only",
            "lr_lag_only",
            "on_top_of",
            "grid_step_s",
            "gnss_speed",
        )
    }
    row["notes"] = [n for n in dg.notes if "dead time" in n or "delay" in n]
    row["unexplained"] = [
        (u.get("channel"), u.get("windows"), _r(u.get("share_of_error"))) for u in dg.unexplained
    ]
    # errors against the truth
    named = next(
        (f for f in dg.findings if f["subsystem"] == "longitudinal" and f["effect"] in RESPONSE),
        None,
    )
    if named is not None:
        key = RESPONSE[named["effect"]]
        est = float(named["parameters"][key])
        lo, hi = named["intervals"][key]
        ref = d + tau  # a single dead time or lag stands for the whole response
        row["named"] = {
            "effect": named["effect"],
            "key": key,
            "est": est,
            "lo": lo,
            "hi": hi,
            "ref": ref,
            "err": est - ref,
            "covers": bool(lo <= ref <= hi),
        }
    j = row["joint"]
    if j:
        lo, hi = j["intervals"]["effective_delay_s"]
        eff = j["effective_delay_s"]
        row["joint_err"] = {
            "eff": eff,
            "err_eff": eff - d - tau,
            "err_d": j["dead_time_s"] - d,
            "err_tau": j["tau_s"] - tau,
            "covers_eff": bool(lo <= d + tau <= hi),
        }
    return row


def _print_row(r: dict) -> None:
    head = (
        f"== {r['case']} {r['duration_s']:g} s seed {r['seed']} K={r['gain_K']}: truth "
        f"d={r['d']:.3f} tau={r['tau']:.3f} d+tau={r['eff']:.3f} s"
    )
    print(head + (f"  ({r['t_gen_s']}+{r.get('t_diag_s')} s)"))
    if "crash" in r:
        print("  hmpc CRASHED:\n" + r["crash"])
        return
    print(f"  input={r['input']}")
    for f in r["findings"]:
        print(
            f"  finding {f['effect']:18s} gain={f['gain']} params={f['parameters']} "
            f"intervals={f['intervals']}"
            + (f" on_top_of={f['on_top_of']}" if f["on_top_of"] else "")
        )
    for h in r["other_hyp"]:
        print(
            f"  not-a-finding {h['effect']:12s} gain={h['gain']} params={h['parameters']} "
            f"intervals={h['intervals']} ({h['why']})"
        )
    j = r["joint"]
    if j:
        print(
            f"  joint: d={j['dead_time_s']} tau={j['tau_s']} d+tau={j['effective_delay_s']} "
            f"intervals={j['intervals']} lr_d_only={j['lr_dead_time_only']} "
            f"lr_lag_only={j['lr_lag_only']} on_top_of={j['on_top_of']} grid={j['grid_step_s']}"
            + (
                f" on GNSS speed d+tau={j['gnss_speed']['effective_delay_s']}"
                if "gnss_speed" in j
                else ""
            )
        )
    for n in r["notes"]:
        print(f"  note: {n}")
    if r["unexplained"]:
        print(f"  unexplained: {r['unexplained']}")
    e = r.get("named")
    if e:
        print(
            f"  ERR named {e['effect']} {e['key']}={e['est']:.3f} [{e['lo']:.3f}, {e['hi']:.3f}]"
            f" vs d+tau {e['ref']:.3f}: {e['err']:+.3f} s (interval covers it: {e['covers']})"
        )
    else:
        print("  ERR named: no longitudinal dead time or lag named")
    je = r.get("joint_err")
    if je:
        print(
            f"  ERR joint d+tau={je['eff']:.3f} vs {r['eff']:.3f}: {je['err_eff']:+.3f} s "
            f"(covers {je['covers_eff']}); d {je['err_d']:+.3f}, tau {je['err_tau']:+.3f}"
        )


def _summary(rows: list[dict]) -> None:
    print(
        "\n== summary (errors in s against d + tau: mean +- sd [median] over seeds; named: "
        "the single delay_s or tau_s hmpc names; joint: its effective delay d + tau; covers: "
        "truth d + tau inside the joint interval)"
    )
    print(
        f"{'case':14s} {'dur':>5s} {'n':>2s} {'d/tau':>9s}  {'named (count)':18s} "
        f"{'named err':>24s} {'joint d+tau err':>24s} {'covers':>6s}"
    )
    groups: dict = {}
    for r in rows:
        groups.setdefault((r["case"], r["duration_s"], r["gain_K"]), []).append(r)
    for (case, dur, K), rs in groups.items():
        ok = [r for r in rs if "crash" not in r]
        names: dict = {}
        for r in ok:
            nm = r["named"]["effect"] if r.get("named") else "none"
            names[nm] = names.get(nm, 0) + 1
        ne = [r["named"]["err"] for r in ok if r.get("named")]
        je = [r["joint_err"]["err_eff"] for r in ok if r.get("joint_err")]
        cov = sum(r["joint_err"]["covers_eff"] for r in ok if r.get("joint_err"))

        def ms(x):
            return (
                "-"
                if not x
                else (
                    f"{np.mean(x):+.3f}+-{np.std(x):.3f} [{np.median(x):+.3f}]"
                    if len(x) > 1
                    else f"{x[0]:+.3f}"
                )
            )

        nm_s = ", ".join(f"{k.replace('actuator_', '')}:{v}" for k, v in names.items())
        tag = case + ("" if K == 1.0 else f" K{K}")
        print(
            f"{tag:14s} {dur:5.0f} {len(rs):2d} {rs[0]['d']:4.2f}/{rs[0]['tau']:4.2f}  "
            f"{nm_s:18s} {ms(ne):>24s} {ms(je):>24s} {cov:>3d}/{len(je)}"
            + (f"  CRASHES {len(rs) - len(ok)}" if len(ok) < len(rs) else "")
        )


def main(argv=None) -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--cases", nargs="+", default=list(CASES))
    ap.add_argument("--durations", nargs="+", type=float, default=[600.0, 60.0])
    ap.add_argument(
        "--seed600", nargs="+", type=int, default=[0], help="seeds of the long recordings"
    )
    ap.add_argument(
        "--seeds60",
        nargs="+",
        type=int,
        default=[0, 1, 2],
        help="seeds of the recordings shorter than 600 s",
    )
    ap.add_argument("--gain", type=float, default=1.0, help="the car's powertrain gain K")
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--quiet", action="store_true", help="summary only")
    ap.add_argument("--json")
    a = ap.parse_args(argv)
    jobs = [
        (c, dur, sd, a.gain)
        for dur in a.durations
        for c in a.cases
        for sd in (a.seed600 if dur >= 600 else a.seeds60)
    ]
    t0 = time.perf_counter()
    with ProcessPoolExecutor(a.jobs) as ex:
        rows = list(ex.map(run_case, *zip(*jobs)))
    if not a.quiet:
        for r in rows:
            _print_row(r)
    _summary(rows)
    print(f"(wall time {time.perf_counter() - t0:.0f} s)")
    if a.json:
        Path(a.json).write_text(json.dumps(rows, indent=1, default=float))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
