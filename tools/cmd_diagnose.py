"""`hmpc diagnose`: where the report's model and a recording differ, which physics is missing
(a named catalogue hypothesis, or "unexplained"), and the held-out fit with it added."""
from __future__ import annotations

import argparse
from pathlib import Path

from hmpc.models.errors import InputError
from hmpc.tools.common import add_ingest_options, progress_printer, recording_or_log, write_json
from hmpc.models.params import dump_params, load_params


def add_arguments(p: argparse.ArgumentParser) -> None:

    p.add_argument("recording", metavar="REC",
                   help="canonical recording (.csv, .csv.gz, .parquet), or a raw CAN log when "
                        "--dbc and --signals are given")
    p.add_argument("--vehicle", required=True, metavar="GEOMETRY.yaml",
                   help="vehicle geometry (params/*.yaml; at least wheelbase_m, track_front_m)")
    p.add_argument("--params", metavar="P.yaml",
                   help="the model to replay (its zones are used); default: the report's model "
                        "identified from the same recording")
    p.add_argument("--json", metavar="FILE", help="findings, unexplained mismatch, replay")
    p.add_argument("--report", metavar="DIR", help="write an HTML report with figures")
    p.add_argument("--params-out", metavar="P2.yaml",
                   help="write the extended model: the conventions' keys plus the findings in "
                        "its extensions: section (catalogue id -> subsystem -> parameters)")
    g = p.add_argument_group("raw log input (the options of `hmpc ingest`)")
    add_ingest_options(g, log_required=False)


_progress = progress_printer("diagnose")


def summary_lines(dg) -> list[str]:
    out = [f"longitudinal input: {dg.longitudinal_input}"]
    for name, c in dg.channels.items():
        base = c.get("heldout_rmse_baseline", c.get("rmse_baseline"))
        floor = c.get("noise_floor")
        out.append(f"  channel {name:17s} baseline RMSE {base if base is None else f'{base:.4g}'}"
                   f" {c['unit']}  noise floor "
                   f"{'n/a' if floor is None else f'{floor:.3g}'} {c['unit']}")
    if not dg.findings:
        out.append("no catalogue hypothesis improves the held-out fit")
    for i, f in enumerate(dg.findings, 1):
        ps = ", ".join(f"{k} {v:.4g} [{f['intervals'][k][0]:.4g}, {f['intervals'][k][1]:.4g}]"
                       if k in f["intervals"] else f"{k} {v:.4g}"
                       for k, v in f["parameters"].items() if isinstance(v, float))
        below = f" (on top of {', '.join(f['on_top_of'])})" if f.get("on_top_of") else ""
        out.append(f"{i}. {f['effect']} ({f['subsystem']}){below}: {ps}")
        out.append(f"   held-out {f['channel']} RMSE {f['heldout_rmse_before']:.4g} -> "
                   f"{f['heldout_rmse_after']:.4g} ({100 * f['gain']:.0f} % better)")
        if f.get("chosen_because"):
            alt = ", ".join(f"{a['effect']} ({_values(a['parameters'])})"
                            for a in f.get("alternatives", []))
            out.append(f"   named over {alt}: {f['chosen_because']}")
    for u in dg.unexplained:
        out.append(f"unexplained ({u['channel']}): windows {u['windows']}, "
                   f"{100 * u['share_of_error']:.0f} % of the error")
    for e in dg.evidence:
        out.append(f"baseline check: {e['why']}")
    for n in dg.notes:
        out.append(f"note: {n}")
    return out


def _values(parameters: dict) -> str:
    """A finding's numeric parameters, ``name value`` joined by commas."""
    return ", ".join(f"{k} {v:.3g}" for k, v in parameters.items() if isinstance(v, float))


def run(args) -> int:
    from hmpc.models.diagnose.diagnose import diagnose

    vehicle = load_params(args.vehicle).vehicle
    params = load_params(args.params, require_model=True) if args.params else None
    rec, sources, ingest_summary = recording_or_log(args, _progress)
    dg = diagnose(rec, vehicle, params, progress=_progress)
    for line in summary_lines(dg):
        print(line)
    payload = dg.to_json()
    payload["recording"] = sources
    if ingest_summary is not None:
        payload["ingest"] = ingest_summary
    if args.params_out:
        out = Path(args.params_out)
        try:
            dump_params(dg.params_out, out)
        except OSError as exc:
            raise InputError(f"cannot write the parameter file ({exc.strerror or exc})",
                             str(out)) from None
        load_params(out, require_model=True)  # what we wrote must load strictly
        print(f"wrote {out}")
        payload["params_out"] = {"file": str(out),
                                 "extensions": sorted(dg.params_out.extensions)}
    if args.report:
        from hmpc.models.diagnose.report import write_report
        _progress(f"writing the HTML report to {args.report}")
        try:
            index = write_report(dg, args.report, title=str(args.recording))
        except OSError as exc:
            raise InputError(f"cannot write the report ({exc.strerror or exc})",
                             args.report) from None
        print(f"wrote {index}")
        payload["report"] = str(index)
    if args.json:
        try:
            write_json(args.json, payload)
        except OSError as exc:
            raise InputError(f"cannot write JSON ({exc.strerror or exc})", args.json) from None
    return 0
