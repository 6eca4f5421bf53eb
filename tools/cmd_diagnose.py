"""`hmpc diagnose`: where the report's model and a recording differ, which physics is missing
(a named catalogue hypothesis, or "unexplained"), and the held-out fit with it added."""

from __future__ import annotations

import argparse
import os
from pathlib import Path

import numpy as np
import yaml

from hmpc.models.diagnose import display as show
from hmpc.models.errors import InputError
from hmpc.tools.common import add_ingest_options, progress_printer, recording_or_log, write_json
from hmpc.models.params import load_params, parse_params


EPILOG = """\
what each part needs (channel names, units and signs: docs/conventions.md):
  sensors       any pair of: speed + gps_speed; speed + accel_x (+ yaw_rate for the
                mounting angle); left and right wheel speeds + yaw_rate or heading
  steering      steering_wheel_angle, speed, yaw_rate or heading; 10 s moving
  longitudinal  speed and an input (accel_pedal/brake_pedal or accel_cmd); 20 s moving
A part the recording cannot support is named under not_diagnosed (JSON and terminal) and in
the parameter file's not_identified:; the exit status is 0 when any part ran, 2 when none can.
"""


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.epilog = EPILOG
    p.formatter_class = argparse.RawDescriptionHelpFormatter

    p.add_argument(
        "recording",
        metavar="REC",
        help="canonical recording (.csv, .csv.gz, .parquet), or a raw CAN log when "
        "--dbc and --signals are given",
    )
    p.add_argument(
        "--vehicle",
        required=True,
        metavar="GEOMETRY.yaml",
        help="vehicle geometry (params/*.yaml; at least wheelbase_m, track_front_m)",
    )
    p.add_argument(
        "--params",
        metavar="P.yaml",
        help="the model to replay (its zones are used); default: the report's model "
        "identified from the same recording",
    )
    p.add_argument("--json", metavar="FILE", help="findings, unexplained mismatch, replay")
    p.add_argument("--report", metavar="DIR", help="write an HTML report with figures")
    p.add_argument(
        "--params-out",
        metavar="P2.yaml",
        help="write the extended model: the conventions' keys plus the findings in "
        "its extensions: section (catalogue id -> subsystem -> parameters); a "
        "part not diagnosed is named under not_identified:, and the given "
        "file's identifiable: false flags stay",
    )
    g = p.add_argument_group("raw log input (the options of `hmpc ingest`)")
    add_ingest_options(g, log_required=False)


_progress = progress_printer("diagnose")


def summary_lines(dg) -> list[str]:
    """What ``hmpc diagnose`` prints: the answer first (the verdict, the parts not diagnosed,
    the findings and what is left unexplained), the evidence below (channels against their
    noise floors, the samples used, checks, notes); angles in degrees."""
    out = [f"verdict: {dg.verdict.get('text', 'none')}"]
    for part, why in dg.not_diagnosed.items():
        out.append(f"not diagnosed: {part}: {why}")
    if not dg.findings:
        out.append("no catalogue hypothesis improves the held-out fit")
    for i, f in enumerate(dg.findings, 1):
        ps = ", ".join(
            show.value_with_interval(k, v, f["intervals"].get(k))
            for k, v in f["parameters"].items()
            if isinstance(v, float)
        )
        below = f" (on top of {', '.join(f['on_top_of'])})" if f.get("on_top_of") else ""
        k, unit = show.shown(1.0, show.CHANNEL_UNITS.get(f["channel"], ""))
        angle = f" {unit}" if k != 1.0 else ""  # the channel lines below give the SI units
        out.append(f"{i}. {f['effect']} ({f['subsystem']}){below}: {ps}")
        out.append(
            f"   held-out {f['channel']} RMSE {k * f['heldout_rmse_before']:.4g} -> "
            f"{k * f['heldout_rmse_after']:.4g}{angle} ({100 * f['gain']:.0f} % better)"
        )
        if f.get("chosen_because"):
            alt = ", ".join(
                f"{a['effect']} ({_values(a['parameters'])})" for a in f.get("alternatives", [])
            )
            out.append(f"   named over {alt}: {f['chosen_because']}")
    for u in dg.unexplained:
        out.append(
            f"unexplained ({u['channel']}): windows {u['windows']}, "
            f"{100 * u['share_of_error']:.0f} % of the error"
        )
    out.append("evidence:")
    if dg.longitudinal_input is not None:
        out.append(f"  longitudinal input: {dg.longitudinal_input}")
    for name, c in dg.channels.items():
        base = c.get("heldout_rmse_baseline", c.get("rmse_baseline"))
        out.append(
            f"  channel {name:17s} baseline RMSE {show.number(base, c['unit'])}  "
            f"noise floor {show.number(c.get('noise_floor'), c['unit'], '.3g')}"
        )
    ss = dg.steering_samples
    if ss:
        drops = "; ".join(f"{k}: {n}" for k, n in ss.get("dropped", {}).items()) or "none"
        out.append(
            f"  steering samples: {ss['angle_fit']} of {ss['total']} in the angle fit, "
            f"{ss['replay']} in the heading replay; dropped: {drops}"
        )
    for e in dg.evidence:
        out.append(f"baseline check: {e['why']}")
    for n in dg.notes:
        out.append(f"note: {n}")
    return out


def _values(parameters: dict) -> str:
    """A finding's numeric parameters, ``name value`` joined by commas (angles in deg)."""
    return ", ".join(
        show.value_with_interval(k, v) for k, v in parameters.items() if isinstance(v, float)
    )


def _plain(obj):
    """``obj`` with numpy scalars and tuples as plain Python (what a YAML file can hold)."""
    if isinstance(obj, dict):
        return {str(k): _plain(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_plain(v) for v in obj]
    if isinstance(obj, np.generic):
        return obj.item()
    return obj


def params_text(params, path: str) -> str:
    """The parameter file ``--params-out`` writes, checked with the loader's own rules before
    anything is written: a file hmpc would refuse is never written (InputError naming the key,
    from ``models.params.parse_params``)."""
    text = yaml.safe_dump(_plain(params.to_dict()), sort_keys=False, default_flow_style=None)
    parse_params(yaml.safe_load(text), path)
    return text


def write_params(text: str, out: Path) -> None:
    """Write ``text`` under a temporary name beside ``out``, load it back strictly, then rename
    it to ``out``: an interrupted or refused write never leaves ``out`` empty or half written."""
    tmp = out.with_name(f".{out.name}.{os.getpid()}.tmp")
    try:
        tmp.write_text(text, encoding="utf-8")
        load_params(tmp)  # what we wrote must load strictly (absent parts under not_identified)
        os.replace(tmp, out)
    except OSError as exc:
        raise InputError(
            f"cannot write the parameter file ({exc.strerror or exc})", str(out)
        ) from None
    finally:
        if tmp.exists():
            tmp.unlink()


def run(args) -> int:
    from hmpc.models.diagnose.diagnose import diagnose

    vehicle = load_params(args.vehicle).vehicle
    params = load_params(args.params, require_model=True) if args.params else None
    rec, sources, ingest_summary = recording_or_log(args, _progress)
    dg = diagnose(rec, vehicle, params, progress=_progress)
    text = params_text(dg.params_out, args.params_out) if args.params_out else None
    for line in summary_lines(dg):
        print(line)
    payload = dg.to_json()
    payload["recording"] = sources
    if ingest_summary is not None:
        payload["ingest"] = ingest_summary
    if args.params_out:
        out = Path(args.params_out)
        write_params(text, out)
        print(f"wrote {out}")
        payload["params_out"] = {
            "file": str(out),
            "extensions": sorted(dg.params_out.extensions),
            "not_identified": sorted(dg.params_out.not_identified),
        }
    if args.report:
        from hmpc.models.diagnose.report import write_report

        _progress(f"writing the HTML report to {args.report}")
        try:
            index = write_report(dg, args.report, title=str(args.recording))
        except OSError as exc:
            raise InputError(
                f"cannot write the report ({exc.strerror or exc})", args.report
            ) from None
        print(f"wrote {index}")
        payload["report"] = str(index)
    if args.json:
        try:
            write_json(args.json, payload)
        except OSError as exc:
            raise InputError(f"cannot write JSON ({exc.strerror or exc})", args.json) from None
    return 0
