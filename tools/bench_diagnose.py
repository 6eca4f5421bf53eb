"""Benchmark of `hmpc diagnose` on hmpc's concealed-effect recordings (models.diagnose.testdata).

Prints, per case and seed: the top finding, whether it is the concealed effect, the parameter
recovered against the truth, the held-out gain and the time; then detection and false-alarm
rates, the localisation of the out-of-catalogue change, the time to diagnose a 10-minute
recording (target < 30 s) and, side by side on the longitudinal recordings, the held-out
free-run speed error of SysIdentPy (FROLS NARX) and PySINDy (STLSQ) fitted on the same
candidate terms (pedals, v, v^2 and products), next to hmpc's extended model. The two
libraries are optional (pip install sysidentpy pysindy); missing ones are skipped with a
message.

    .venv/bin/python -m hmpc.tools.bench_diagnose [--seeds 1 2] [--json OUT]
    .venv/bin/python -m hmpc.tools.bench_diagnose --closed-loop --seeds 1   # closing the loop
    .venv/bin/python -m hmpc.tools.bench_diagnose --closed-loop --lag-methods stage delay none
    .venv/bin/python -m hmpc.tools.bench_diagnose --speed-only              # 10-minute timing
"""

from __future__ import annotations

import argparse
import json
import sys
import time
import warnings

import numpy as np

from hmpc.models.diagnose import longitudinal as lon
from hmpc.models.diagnose.common import DiagnoseConfig, rmse, windows
from hmpc.models.diagnose.diagnose import diagnose
from hmpc.models.diagnose.testdata import ALL_EXPERIMENTS, CASES, make_case

LON_CASES = ("aero_drag", "road_grade", "idle_creep", "actuator_delay_longitudinal", "clean")


def _recovered(name, truth, got) -> float:
    """Relative parameter error [fraction]; a scale near 1 is judged on its departure from 1."""
    if name == "scale":
        return abs((got - 1) - (truth - 1)) / abs(truth - 1)
    return abs(got - truth) / abs(truth)


def run_cases(seeds) -> list[dict]:
    rows = []
    for case, (effect, subsystem, _, param, _) in CASES.items():
        for seed in seeds:
            rec, info = make_case(case, seed=seed)
            t0 = time.perf_counter()
            dg = diagnose(rec, info["params"].vehicle)
            el = time.perf_counter() - t0
            top = dg.findings[0] if dg.findings else None
            row = {
                "case": case,
                "seed": seed,
                "duration_s": float(rec.time[-1] - rec.time[0]),
                "time_s": el,
                "top": top and f"{top['effect']}/{top['subsystem']}",
                "findings": [
                    (f["effect"], f["subsystem"], round(f["gain"], 3)) for f in dg.findings
                ],
                "unexplained": dg.unexplained,
            }
            if effect is not None:
                row["detected"] = bool(
                    top and (top["effect"], top["subsystem"]) == (effect, subsystem)
                )
                row["gain"] = top["gain"] if row["detected"] else 0.0
                if row["detected"]:
                    row["param_err"] = _recovered(param[0], param[1], top["parameters"][param[0]])
                row["extra_findings"] = len(dg.findings) - (1 if row["detected"] else 0)
            if case == "mass_change":
                u = dg.unexplained[0] if dg.unexplained else None
                row["change_t_s"] = info["change_t_s"]
                row["localisation_err_s"] = (
                    abs(u["windows"][0][0] - info["change_t_s"]) if u else None
                )
                row["share_of_error"] = u["share_of_error"] if u else None
            rows.append(row)
            print(
                f"{case:28s} seed {seed}: {rec.time[-1] - rec.time[0]:5.0f} s in {el:5.2f} s  "
                f"top {row['top']}  "
                + (
                    f"param err {100 * row['param_err']:.1f} %  gain {100 * row['gain']:.0f} %"
                    if row.get("param_err") is not None
                    else ""
                )
                + (
                    f"  unexplained from {row['unexplained'][0]['windows'][0][0]:.0f} s "
                    f"(change at {row['change_t_s']:.0f} s)"
                    if case == "mass_change" and row["unexplained"]
                    else ""
                ),
                flush=True,
            )
    return rows


# ----------------------------------------------------------------- optional baselines
def _split(d: lon.LonData):
    idx = np.flatnonzero(d.ok)
    cut = d.t[idx[int(0.8 * len(idx))]]
    train = d.ok & (d.t < cut - DiagnoseConfig.guard_s)
    test = d.ok & (d.t >= cut)
    return train, windows(test, int(DiagnoseConfig.window_lon_s / d.dt))


def _freerun(d, idx, accel_fn):
    v = d.vs[idx[:, 0]].copy()
    out = np.empty(idx.shape)
    for j in range(idx.shape[1]):
        out[:, j] = v
        v = np.maximum(v + accel_fn(v, idx[:, j]) * d.dt, 0.0)
    return out - d.v[idx]


def baseline_pysindy(d, train, idx):
    import pysindy as ps

    use = train & np.isfinite(d.a) & (d.vs > DiagnoseConfig.v_stop_mps)
    U = np.nan_to_num(d.U)
    model = ps.SINDy(
        feature_library=ps.PolynomialLibrary(degree=2), optimizer=ps.STLSQ(threshold=0.005)
    )
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        model.fit(d.vs[use][:, None], t=d.dt, u=U[use], x_dot=d.a[use][:, None])
    f = lambda v, k: model.predict(v[:, None], u=U[k])[:, 0]  # noqa: E731
    return rmse(_freerun(d, idx, f)), model.equations()[0]


def baseline_sysidentpy(d, train, idx):
    from sysidentpy.basis_function import Polynomial
    from sysidentpy.model_structure_selection import FROLS
    from sysidentpy.parameter_estimation import LeastSquares

    step = max(int(round(0.1 / d.dt)), 1)  # 10 Hz: a one-step NARX at 50 Hz is near identity
    sel = np.flatnonzero(train)[::step]
    U = np.nan_to_num(d.U)
    m = FROLS(
        order_selection=True,
        n_info_values=8,
        ylag=1,
        xlag=[[1]] * U.shape[1],
        info_criteria="bic",
        estimator=LeastSquares(),
        basis_function=Polynomial(degree=2),
    )
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        m.fit(X=U[sel], y=d.v[sel][:, None])
    errs = []
    for row in idx:
        r = row[::step]
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            yp = m.predict(X=U[r], y=d.v[r][:1, None])[:, 0]
        errs.append(yp - d.v[r])
    return rmse(np.concatenate(errs)), f"{len(m.final_model)} terms"


def baseline_hmpc(d, train, idx, effect):
    cfg = DiagnoseConfig()
    base, _, _ = lon.fit_best(d, None, train, cfg)
    ext, _, _ = lon.fit_best(d, effect, train, cfg) if effect else (base, 0, 0)
    return rmse(lon.free_run(d, base, idx)), rmse(lon.free_run(d, ext, idx))


def side_by_side(seed: int) -> list[dict]:
    rows = []
    libs = {}
    for name, fn in (("pysindy", baseline_pysindy), ("sysidentpy", baseline_sysidentpy)):
        try:
            __import__(name)
            libs[name] = fn
        except ImportError:
            print(f"  {name} not importable: skipped (pip install {name} into .venv)")
    for case in LON_CASES:
        rec, info = make_case(case, seed=seed)
        d = lon.prepare(rec.channels)
        train, idx = _split(d)
        eff = info["effect"] if info["subsystem"] == "longitudinal" else None
        b, e = baseline_hmpc(d, train, idx, eff)
        row = {"case": case, "hmpc_baseline_mps": b, "hmpc_extended_mps": e}
        for name, fn in libs.items():
            t0 = time.perf_counter()
            try:
                row[name + "_mps"], row[name + "_model"] = fn(d, train, idx)
            except Exception as exc:  # a baseline library failing is reported, not fatal
                row[name + "_mps"], row[name + "_model"] = float("nan"), f"failed: {exc}"
            row[name + "_time_s"] = time.perf_counter() - t0
        rows.append(row)
        print(
            f"  {case:28s} hmpc report model {b:.3f}  hmpc + {eff or '-':15s} {e:.3f}  "
            + "  ".join(f"{n} {row[n + '_mps']:.3f}" for n in libs)
            + "  [m/s]",
            flush=True,
        )
        for n in libs:
            if n == "pysindy":
                print(f"      pysindy: {row['pysindy_model']}")
    return rows


def ten_minutes(seed: int) -> dict:
    from hmpc.models.identify.pipeline import concat_recordings
    from hmpc.models.sim.simulator import random_params, run_experiment

    truth = random_params(seed)
    recs, dur, i = [], 0.0, 0
    while dur < 600.0:
        r = run_experiment(
            ALL_EXPERIMENTS[i % len(ALL_EXPERIMENTS)], truth, seed=seed + i
        ).recording
        recs.append(r)
        dur += float(r.time[-1])
        i += 1
    rec = concat_recordings(recs)
    times, cpu = [], []
    for _ in range(3):
        t0, c0 = time.perf_counter(), time.process_time()
        diagnose(rec, truth.vehicle)
        times.append(time.perf_counter() - t0)
        cpu.append(time.process_time() - c0)
    # CPU time beside the wall time: on a shared machine the wall time also counts the waits
    out = {
        "duration_s": float(rec.time[-1] - rec.time[0]),
        "hmpc_s": float(np.median(times)),
        "hmpc_cpu_s": float(np.median(cpu)),
    }
    try:  # baseline in the same run: one PySINDy term selection on the same recording
        import pysindy  # noqa: F401

        d = lon.prepare(rec.channels)
        train, idx = _split(d)
        t0 = time.perf_counter()
        baseline_pysindy(d, train, idx)
        out["pysindy_one_fit_s"] = time.perf_counter() - t0
    except ImportError:
        pass
    return out


# ----------------------------------------------------------------- closing the loop
#: scenario the MPC tracks for each case: the one that exercises what the effect acts on
CL_SCENARIO = {"steering": "figure8", "longitudinal": "ramps", "idle_creep": "idle_hold"}


def _track(
    model,
    truth,
    effects,
    ref,
    plant_dt_s: float = 0.02,
    period_s: float = 0.1,
    seed: int = 0,
    lag_method: str | None = None,
) -> dict:
    """The MPC built on ``model`` drives the ground-truth plant (``truth`` with the concealed
    ``effects``: ``run_closed_loop(effects=)``, models.sim.truth_plant.TruthPlant) along ``ref``,
    fed as a car is: simulated sensors through the EKF, at the default noise, the same seed for
    every model (only the model differs between runs). ``lag_method``: the MPC's handling of
    an actuator lag (``MpcController.lag_method``; None: its default). Returns the tracking
    RMSEs."""
    from hmpc.controller.closed_loop import run_closed_loop
    from hmpc.controller.mpc import MpcController

    mpc = MpcController(model)
    if lag_method is not None:
        mpc.use_lag_method(lag_method)
    res = run_closed_loop(
        mpc,
        ref,
        model,
        plant_params=truth,
        control_period_s=period_s,
        plant_dt_s=plant_dt_s,
        seed=seed,
        effects=effects,
    )
    m = res.metrics
    return {
        "speed_rmse_mps": m["speed_error_rms_mps"],
        "lateral_rmse_m": m["lateral_error_rms_m"],
        "not_ok_steps": int(m["failures"]),
    }


def controller_view(p) -> tuple[object, list[str]]:
    """What of the extended model ``p`` the MPC uses, and what it does not.

    The MPC (controller/mpc/) predicts through ``steering.dead_time_s`` and
    ``longitudinal.dead_time_s`` and, through ``HybridPlant(params, extensions=True)``
    (models.plant.plant_extensions), with the physics of ``extensions:`` that belongs to a
    prediction model, on the steering map and zones each was fitted jointly with (``base:``):
    drag, rolling resistance and idle creep in eq. 8 (and so in the QP's linearisation), the
    rack's cubic and the understeer gradient in the road-wheel angle, and an actuator lag
    simulated from its own commands in the prediction through the commands in flight, its
    command the inverse of the lag applied to the plan (u + tau du/dt; lag as a dead time of
    tau and a one-stage exact inverse tracked worse, see ``MpcController.lag_method``). A
    road grade is of the road recorded, not the road ahead: the keys hold the zones fitted
    with it taken out and the MPC has no grade preview."""
    notes = []
    for eid, subs in p.extensions.items():
        for sub in subs:
            if eid == "actuator_lag":
                notes.append(
                    f"{eid}/{sub}: lag simulated in the MPC's prediction, command "
                    "u + tau du/dt of the plan"
                )
            elif eid in ("aero_drag", "rolling_resistance", "idle_creep"):
                notes.append(
                    f"{eid}/{sub}: in the MPC's eq. 8, with the zones it was fitted with (base)"
                )
            elif eid in ("steering_nonlinearity", "understeer"):
                notes.append(
                    f"{eid}/{sub}: in the MPC's road-wheel angle, with the steering "
                    "map it was fitted with (base)"
                )
            elif eid == "road_grade":
                notes.append(
                    f"{eid}/{sub}: zones fitted with the grade taken out; the MPC has "
                    "no grade preview"
                )
    return p, notes


def ideal_model(truth, effects):
    """The true model with the concealed effect as the MPC can represent it (its keys and
    ``extensions:``): the best any diagnosis can hand the MPC, so the headroom a finding has.
    None where the MPC has no such term (a road grade ahead, sensor effects: there the truth
    without the effect is the ideal)."""
    import copy
    from hmpc.models.sim import effects as fx
    from hmpc.models.sim import effects_extra as fx2

    m = copy.deepcopy(truth)
    m.extensions = dict(m.extensions or {})
    for e in effects:
        if isinstance(e, fx.SteeringDeadTime):
            m.steering.dead_time_s = e.delay_s
        elif isinstance(e, fx.PedalDeadTime):
            m.longitudinal_dead_time_s = e.delay_s
        elif isinstance(e, fx.SteeringLag):
            m.extensions["actuator_lag"] = {"steering": {"tau_s": e.tau_s}}
        elif isinstance(e, fx.SteeringCubic):
            m.extensions["steering_nonlinearity"] = {
                "steering": {"cubic_per_rad2": e.cubic_per_rad2}
            }
        elif isinstance(e, fx.Understeer):
            m.extensions["understeer"] = {
                "steering": {"gradient_rad_per_mps2": e.gradient_rad_per_mps2}
            }
        elif isinstance(e, fx.AeroDrag):
            m.extensions["aero_drag"] = {"longitudinal": {"coeff_per_m": e.coeff_per_m}}
        elif isinstance(e, fx2.IdleCreep):
            m.extensions["idle_creep"] = {
                "longitudinal": {"accel_mps2": e.accel_mps2, "creep_speed_mps": e.creep_speed_mps}
            }
        else:
            return None
    return m


def closed_loop(seed: int, cases=None, lag_methods=(), with_truth: bool = True) -> list[dict]:
    """Per benchmark effect: the MPC on the ground-truth plant with the report's baseline
    model and with the extended model, both from ``diagnose`` on that case's recording; with
    an actuator lag found, also with each of ``lag_methods`` (``MpcController.lag_method``).
    ``with_truth``: also with the true model without the effect (the row's ``truth``)."""
    from hmpc.models.sim.scenarios import make_scenario

    rows = []
    for case, (effect, subsystem, make_effects, _, _) in CASES.items():
        if effect is None or (cases and case not in cases):
            continue
        rec, info = make_case(case, seed=seed)
        dg = diagnose(rec, info["params"].vehicle)
        truth = info["params"]
        scn = CL_SCENARIO.get(effect, CL_SCENARIO[subsystem])
        ref = make_scenario(scn, truth)
        ext, notes = controller_view(dg.params_out)
        row = {
            "case": case,
            "scenario": scn,
            "notes": notes,
            "found": [f"{f['effect']}/{f['subsystem']}" for f in dg.findings],
        }
        ideal = ideal_model(truth, make_effects())
        for label, model in (
            ("truth", truth),
            ("baseline", dg.baseline_out),
            ("extended", ext),
            ("ideal", ideal),
        ):
            if model is not None and (with_truth or label != "truth"):
                row[label] = _track(model, truth, make_effects(), ref)
        key = "lateral_rmse_m" if subsystem == "steering" else "speed_rmse_mps"
        if "actuator_lag" in ext.extensions:
            for m in lag_methods:
                row[f"extended_lag_{m}"] = _track(ext, truth, make_effects(), ref, lag_method=m)
                print(f"      lag as '{m}': {key} {row[f'extended_lag_{m}'][key]:.4f}")
        b, e = row["baseline"][key], row["extended"][key]
        row.update(metric=key, change=(e - b) / b if b > 0 else 0.0)
        rows.append(row)
        print(
            f"  {case:28s} {scn:9s} {key:15s} "
            + (f"true model without the effect {row['truth'][key]:.4f}  " if with_truth else "")
            + f"baseline {b:.4f}  extended {e:.4f}  ({100 * row['change']:+.1f} %)"
            + (
                f"  ideal (true model with the effect) {row['ideal'][key]:.4f}"
                if "ideal" in row
                else ""
            )
            + "".join(f"\n      {n}" for n in notes),
            flush=True,
        )
    return rows


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, nargs="+", default=[1, 2])
    ap.add_argument("--json", help="write every figure here")
    ap.add_argument(
        "--speed-only", action="store_true", help="only the time to diagnose a 10-minute recording"
    )
    ap.add_argument(
        "--closed-loop",
        action="store_true",
        help="only the closed-loop comparison: the MPC on each case's ground-truth "
        "plant with the baseline and with the extended model",
    )
    ap.add_argument(
        "--lag-methods",
        nargs="*",
        default=[],
        choices=["inverse", "stage", "delay", "none"],
        help="with --closed-loop: also track the actuator-lag case with each way "
        "the MPC can handle a lag",
    )
    args = ap.parse_args(argv)
    print(f"seeds {args.seeds}")
    if args.speed_only:
        tm = ten_minutes(args.seeds[0])
        print(
            f"diagnose {tm['duration_s'] / 60:.1f} min at 50 Hz: hmpc {tm['hmpc_s']:.2f} s wall, "
            f"{tm['hmpc_cpu_s']:.2f} s CPU (target < 30 s)"
            + (
                f"; baseline one PySINDy fit+replay {tm['pysindy_one_fit_s']:.2f} s, ratio "
                f"{tm['hmpc_s'] / tm['pysindy_one_fit_s']:.1f}x"
                if "pysindy_one_fit_s" in tm
                else ""
            )
        )
        return 0
    if args.closed_loop:
        print(
            "=== closed loop: MPC tracking RMSE on the ground-truth plant (sensors -> EKF -> MPC)"
        )
        cl = closed_loop(args.seeds[0], lag_methods=args.lag_methods)
        if args.json:
            with open(args.json, "w") as fh:
                json.dump({"closed_loop": cl}, fh, indent=1)
        return 0
    rows = run_cases(args.seeds)
    eff = [r for r in rows if "detected" in r]
    clean = [r for r in rows if r["case"] == "clean"]
    mass = [r for r in rows if r["case"] == "mass_change"]
    det = np.mean([r["detected"] for r in eff])
    fa_clean = np.mean([any(g > 0.10 for _, _, g in r["findings"]) for r in clean])
    extra = np.mean([r["extra_findings"] for r in eff])
    perr = [r["param_err"] for r in eff if r.get("param_err") is not None]
    gains = [r["gain"] for r in eff if r["detected"]]
    print("\n=== summary")
    print(f"detection rate (top finding = concealed effect): {100 * det:.0f} % of {len(eff)}")
    print(
        f"false alarms: clean recordings with a finding > 10 % gain: {100 * fa_clean:.0f} % "
        f"of {len(clean)}; other findings per effect recording: {extra:.2f}"
    )
    print(
        f"parameter recovery: median error {100 * np.median(perr):.1f} %, worst "
        f"{100 * np.max(perr):.1f} % (target <= 20 %)"
    )
    print(
        f"held-out gain of the top finding: median {100 * np.median(gains):.0f} %, "
        f"min {100 * np.min(gains):.0f} %"
    )
    for r in mass:
        loc, share = r["localisation_err_s"], r["share_of_error"]
        where = "not reported" if loc is None else f"{loc:.1f} s off the change"
        print(
            f"out-of-catalogue mass change (seed {r['seed']}): unexplained {where}, "
            f"share of error {'-' if share is None else f'{share:.2f}'}"
        )
    print(
        "\n=== held-out free-run speed RMSE on the last 20 % (10-s windows), same candidate terms"
    )
    sbs = side_by_side(args.seeds[0])
    print("\n=== speed")
    tm = ten_minutes(args.seeds[0])
    line = (
        f"diagnose {tm['duration_s'] / 60:.1f} min at 50 Hz: hmpc {tm['hmpc_s']:.2f} s "
        f"wall, {tm['hmpc_cpu_s']:.2f} s CPU (target < 30 s)"
    )
    if "pysindy_one_fit_s" in tm:
        line += (
            f"; baseline one PySINDy fit+replay on it {tm['pysindy_one_fit_s']:.2f} s, "
            f"ratio {tm['hmpc_s'] / tm['pysindy_one_fit_s']:.1f}x (hmpc fits "
            "~400 models: 11 hypotheses x 6 folds x grids)"
        )
    print(line)
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(
                {"cases": rows, "side_by_side": sbs, "ten_minutes": tm},
                fh,
                indent=1,
                default=lambda o: o.item() if hasattr(o, "item") else str(o),
            )
    return 0


if __name__ == "__main__":
    sys.exit(main())
