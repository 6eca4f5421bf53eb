"""Identification benchmark: one hour of 50 Hz simulated recording, identified end to
end, against the 10 s target; and FOS against naive forward selection on the same data.

    .venv/bin/python -m hmpc.tools.bench_identify              # one hour
    .venv/bin/python -m hmpc.tools.bench_identify --minutes 10 # a quick run

1. Builds the hour by joining the report's experiments (``models.sim``, noise "typical", the
   report's parameters) with successive seeds until the duration is reached (not timed).
2. Times ``models.identify.pipeline.identify`` on it (steering fits, replay refinement, dead times,
   zone fits, FOS, intervals): hmpc's figure, printed beside the target (10 s) and the
   ratio target / figure (> 1 means faster than the target). Also checks the recovered
   parameters against the truth and exits 1 when they miss the accuracy tolerances, so a fast
   wrong answer fails the benchmark.
3. Baseline measured in the same run: term selection on the hour's high-zone candidate matrix
   by FOS (implicit Gram-Schmidt through the correlation recursions, ``models.identify.fos``)
   against naive forward selection that refits least squares for every candidate at every step
   (what FOS avoids); same terms selected, time ratio printed.

BLAS runs single-threaded (``OPENBLAS_NUM_THREADS=1`` etc., unless already set): on this
shared 2-core machine a multi-threaded BLAS call can stall for a second waking its threads,
which would time the machine's load, not hmpc. Progress goes to stderr, results to stdout.
"""

from __future__ import annotations

import os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402

from hmpc.models.identify.fos import fos  # noqa: E402
from hmpc.models.identify.pipeline import concat_recordings, identify  # noqa: E402
from hmpc.models.params import load_params  # noqa: E402
from hmpc.models.sim.plans import EXPERIMENTS  # noqa: E402
from hmpc.models.sim.simulator import simulate_experiment  # noqa: E402
from hmpc.tools.datafiles import PARAMS_DIR  # noqa: E402

TARGET_S = 10.0  # the target: identification of one hour of 50 Hz recording in under 10 s
# Accuracy the run must reach, or it exits 1 (the acceptance tolerances, the outer bound that
# tests/identify/test_identify_sim.py also keeps): a fast wrong answer is a failed benchmark.
STEER_OFFSET_TOL_RAD = 0.002
STEER_SCALE_TOL = 0.02  # relative
ZONE_OFFSET_TOL_MPS2 = 0.05
ZONE_SCALE_TOL = 0.05  # relative, throttle and brake scale


def progress(msg: str) -> None:
    print(f"[bench_identify] {msg}", file=sys.stderr, flush=True)


def build(minutes: float, truth):
    recs, total, seed = [], 0.0, 0
    while total < minutes * 60.0:
        for name in EXPERIMENTS:
            r = simulate_experiment(name, truth, seed=seed)
            recs.append(r)
            total += len(r) / r.rate_hz
            if total >= minutes * 60.0:
                break
        seed += 1
        progress(f"simulated {total / 60:.1f} of {minutes:g} min")
    return concat_recordings(recs)


def naive_forward(P, y, k):
    """Greedy forward selection by explicit least squares refits (the baseline)."""
    sel = []
    for _ in range(k):
        best, best_sse = None, np.inf
        for j in range(P.shape[1]):
            if j in sel:
                continue
            X = P[:, sel + [j]]
            coef, *_ = np.linalg.lstsq(X, y, rcond=None)
            sse = float(np.sum((y - X @ coef) ** 2))
            if sse < best_sse:
                best, best_sse = j, sse
        sel.append(best)
    return sel


def accuracy_failures(params, truth) -> list[str]:
    """What the identified ``params`` get wrong against ``truth``, beyond the tolerances above."""
    bad = []
    st, ts = params.steering, truth.steering
    if not abs(st.offset_rad - ts.offset_rad) <= STEER_OFFSET_TOL_RAD:
        bad.append(
            f"steering offset error {st.offset_rad - ts.offset_rad:+.5f} rad "
            f"(tolerance {STEER_OFFSET_TOL_RAD} rad)"
        )
    if not abs(st.scale / ts.scale - 1.0) <= STEER_SCALE_TOL:
        bad.append(
            f"steering scale error {100 * (st.scale / ts.scale - 1):+.3f}% "
            f"(tolerance {100 * STEER_SCALE_TOL:g}%)"
        )
    if [z.name for z in params.zones] != [z.name for z in truth.zones]:
        return bad + [f"zones {[z.name for z in params.zones]} != {[z.name for z in truth.zones]}"]
    for z, t in zip(params.zones, truth.zones):
        if not abs(z.offset_mps2 - t.offset_mps2) <= ZONE_OFFSET_TOL_MPS2:
            bad.append(f"zone {z.name} offset error {z.offset_mps2 - t.offset_mps2:+.4f} m/s^2")
        for what, got, true in (
            ("scale", z.scale_mps2, t.scale_mps2),
            ("brake scale", z.brake_scale_mps2, t.brake_scale_mps2),
        ):
            if not abs(got / true - 1.0) <= ZONE_SCALE_TOL:
                bad.append(
                    f"zone {z.name} {what} error {100 * (got / true - 1):+.2f}% "
                    f"(tolerance {100 * ZONE_SCALE_TOL:g}%)"
                )
    return bad


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--minutes", type=float, default=60.0, help="recording length (default 60)")
    args = ap.parse_args(argv)
    truth = load_params(PARAMS_DIR / "report_2008.yaml")
    progress("building the recording (not timed)")
    rec = build(args.minutes, truth)
    dur = (rec.time[-1] - rec.time[0]) / 60.0
    progress(f"identifying {len(rec)} samples ({dur:.1f} min at {rec.rate_hz:.0f} Hz)")
    t0 = time.perf_counter()
    res = identify(rec, truth.vehicle, progress=progress)
    wall = time.perf_counter() - t0
    st = res.params.steering
    print(f"identify: {len(rec)} samples ({dur:.1f} min at {rec.rate_hz:.0f} Hz) in {wall:.2f} s")
    scale = 60.0 / dur
    print(
        f"  scaled to one hour: {wall * scale:.2f} s; target < {TARGET_S:.0f} s per hour; "
        f"ratio target/hmpc = {TARGET_S / (wall * scale):.2f}x "
        f"({'met' if wall * scale < TARGET_S else 'MISSED'})"
    )
    print(
        f"  check: steering offset error {st.offset_rad - truth.steering.offset_rad:+.5f} rad, "
        f"scale error {100 * (st.scale / truth.steering.scale - 1):+.3f}%; zone scale errors "
        + ", ".join(
            f"{z.name} {100 * (z.scale_mps2 / t.scale_mps2 - 1):+.2f}%"
            for z, t in zip(res.params.zones, truth.zones)
        )
    )
    wrong = accuracy_failures(res.params, truth)
    print("  accuracy: " + ("ok" if not wrong else "FAILED: " + "; ".join(wrong)))

    # ---- FOS vs naive forward selection on the high zone's candidates
    lo = res.longitudinal.series
    used = np.asarray(lo["used"], bool) & (np.asarray(lo["zone"]) == 2)
    v = np.asarray(lo["v_mps"], float)
    ap_ = np.nan_to_num(np.asarray(lo["accel_pedal"], float))
    bp_ = np.nan_to_num(np.asarray(lo["brake_pedal"], float))
    rng = np.random.default_rng(0)
    cols = [np.ones_like(v), ap_, bp_, v, v * v, ap_ * v]
    cols += [rng.normal(size=len(v)) for _ in range(14)]  # distractors: 20 candidates
    P = np.column_stack(cols)[used]
    y = np.asarray(lo["a_meas_mps2"], float)[used]
    k = 6
    t_fos = t_naive = np.inf
    for _ in range(3):  # best of three: the machine is shared
        t0 = time.perf_counter()
        fr = fos(P, y, holdout=None, max_terms=k, min_reduction=0.0, noise_threshold=False)
        t_fos = min(t_fos, time.perf_counter() - t0)
        t0 = time.perf_counter()
        sel = naive_forward(P, y, k)
        t_naive = min(t_naive, time.perf_counter() - t0)
    same = sel == fr.indices
    print(
        f"term selection, {P.shape[0]} samples x {P.shape[1]} candidates, {k} terms: "
        f"FOS {1000 * t_fos:.1f} ms, naive forward selection (lstsq refits) "
        f"{1000 * t_naive:.1f} ms (best of 3 each), ratio naive/FOS {t_naive / t_fos:.1f}x; "
        f"same terms: {same}"
    )
    if not same:
        print("FOS and naive forward selection chose different terms", file=sys.stderr)
    return 0 if (same and not wrong) else 1


if __name__ == "__main__":
    sys.exit(main())
