"""`hmpc identify`: the report's steering map (eq. 7) and zone accelerator models (eq. 8) from a
canonical recording or a raw CAN log (with the `hmpc ingest` options), as a parameter file."""

from __future__ import annotations

import argparse
import math
from dataclasses import fields, replace

from hmpc.models.errors import InputError
from hmpc.tools.common import add_ingest_options, progress_printer, recording_or_log, write_json
from hmpc.models.identify.pipeline import identify
from hmpc.models.identify.longitudinal import ACCEL_SOURCES, LongitudinalIdConfig
from hmpc.models.identify.steering import SENSOR_HEADLINE, SteeringIdConfig
from hmpc.models.params import dump_params, load_params

#: what a recording must hold, shown under --help
EPILOG = """\
what the recording must hold (channel names, units and signs: the channel table of
docs/conventions.md; SI units, a left turn positive):
  always        time
  steering      steering_wheel_angle (else steering_cmd: the map's input is then the
                command, written as steering.input: steering_cmd), and at least one of
  (eq. 7)         - wheel_speed_fl, wheel_speed_fr, wheel_speed_rl, wheel_speed_rr
                    (wheel-speed difference)
                  - yaw_rate and a speed: the rear wheel speeds, speed or gps_speed
                    (yaw-rate fit)
                  - x, y, heading and a speed (eq. 1 position replay)
                optional: gear (reverse is dropped)
  longitudinal  accel_pedal (0..1) and a speed: the wheel speeds, speed, gps_speed or
  (eq. 8)       accel_x; brake_pedal (0..1) for the brake term; accel_cmd is offered
                to the term selection; without accel_pedal, accel_cmd or speed_cmd
                is the input (longitudinal.input; zone gain accel_cmd_gain or
                speed_cmd_gain_ps [1/s], see docs/conventions.md)
A part whose channels are missing is listed under not_identified: with the reason (exit 0
while the other part is identified; exit 2 when neither is).

steering sample thresholds scale with the wheelbase below a passenger car's 2.65 m (equal
Froude number); --steering-threshold NAME=VALUE sets one, e.g. v_min_mps=0.5, and the
JSON's steering.samples.dropped says how many samples each threshold dropped.
"""


def _zones(text: str) -> tuple:
    """``idle:0:2,low:2:5,high:5:20`` -> ((name, v_min, v_max), ...)."""
    out = []
    for part in text.split(","):
        bits = part.strip().split(":")
        if len(bits) != 3:
            raise argparse.ArgumentTypeError(f"expected NAME:V_MIN:V_MAX[,...], got {part!r}")
        try:
            lo, hi = float(bits[1]), float(bits[2])
        except ValueError:
            raise argparse.ArgumentTypeError(
                f"zone speeds must be numbers [m/s], got {part!r}"
            ) from None
        if not (math.isfinite(lo) and math.isfinite(hi) and hi > lo):
            raise argparse.ArgumentTypeError(f"zone needs finite v_max > v_min, got {part!r}")
        out.append((bits[0], lo, hi))
    if out[0][1] != 0.0 or any(abs(out[i][1] - out[i - 1][2]) > 1e-9 for i in range(1, len(out))):
        raise argparse.ArgumentTypeError("zones must be contiguous and start at 0 m/s")
    return tuple(out)


def _nonneg(text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not (math.isfinite(v) and v >= 0):
        raise argparse.ArgumentTypeError(f"expected a number >= 0, got {text!r}")
    return v


#: what the outputs hold, for the CLI's check of output paths (tools/cli.py)
OUTPUTS = {"out": "the parameter file", "plots": "figures"}


#: steering thresholds --steering-threshold may set (numbers only)
_STEERING_FIELDS = {
    f.name for f in fields(SteeringIdConfig) if f.type in ("float", "int", float, int)
}


def _threshold(text: str) -> tuple[str, float]:
    """``NAME=VALUE`` -> (name, value) for a numeric field of SteeringIdConfig."""
    name, sep, value = text.partition("=")
    name = name.strip()
    if not sep or name not in _STEERING_FIELDS:
        raise argparse.ArgumentTypeError(
            f"expected NAME=VALUE with NAME one of {', '.join(sorted(_STEERING_FIELDS))}, "
            f"got {text!r}"
        )
    try:
        v = float(value)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{name}: expected a number, got {value!r}") from None
    if not math.isfinite(v):
        raise argparse.ArgumentTypeError(f"{name}: expected a finite number, got {value!r}")
    return name, v


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
        "--out",
        required=True,
        metavar="PARAMS.yaml",
        help="parameter file to write (the keys of docs/conventions.md plus optional ones)",
    )
    p.add_argument("--plots", metavar="DIR", help="write figures like the report's Figs. 2-5")
    p.add_argument("--json", metavar="FILE", help="write every figure (stable keys, SI units)")
    p.add_argument(
        "--zones",
        type=_zones,
        metavar="NAME:VMIN:VMAX,...",
        help="speed zones [m/s] (default idle:0:2,low:2:5,high:5:20, scaled by "
        "sqrt(wheelbase / 2.65 m) for a shorter vehicle)",
    )
    p.add_argument(
        "--accel-source",
        choices=ACCEL_SOURCES,
        default="auto",
        help="measured acceleration: auto (chosen by held-out evidence among the "
        "sources the recording has), wheel_speeds, speed, gps_speed, accel_x "
        "(default auto)",
    )
    p.add_argument(
        "--hysteresis",
        type=_nonneg,
        default=0.0,
        metavar="MPS",
        help="zone hysteresis when assigning samples [m/s] (default 0: sharp "
        "boundaries as in the report)",
    )
    p.add_argument(
        "--steering-threshold",
        type=_threshold,
        action="append",
        default=[],
        metavar="NAME=VALUE",
        help="set one steering threshold (SteeringIdConfig field, SI units; "
        "repeatable), e.g. v_min_mps=0.5 or sw_rate_max_radps=3 (default: "
        "scaled to the vehicle's wheelbase)",
    )
    g = p.add_argument_group("raw log input (the options of `hmpc ingest`)")
    add_ingest_options(g, log_required=False)


_progress = progress_printer("identify")


def summary_lines(res) -> list[str]:
    """Human-readable summary for stdout: the answer first (the model, eq. 7 and eq. 8 per
    zone, with intervals and identifiable flags), then what was not identified, then the
    evidence. Angles in deg (the JSON and the parameter file keep rad)."""
    ni = res.report.get("not_identified") or res.params.not_identified
    out = []
    if res.steering is not None:
        out += _steering_model(res)
    if res.longitudinal is not None:
        out += _longitudinal_model(res)
    # the report's list: every part, and every zone value copied or taken from a prior
    out += [f"not identified: {part}: {why}" for part, why in ni.items()]
    ev = []
    if res.steering is not None:
        ev += _steering_evidence(res)
    if res.longitudinal is not None:
        ev += _longitudinal_evidence(res)
    if ev:
        out += ["evidence:"] + ev
    return out


def _deg(rad: float, signed: bool = True) -> str:
    return f"{math.degrees(rad):{'+' if signed else ''}.3f}"


def _flag(ok) -> str:
    return "identifiable" if ok else "NOT identifiable"


def _steering_model(res) -> list[str]:
    st, sr = res.params.steering, res.report["steering"]
    o_lo, o_hi = st.offset_ci95_rad
    s_lo, s_hi = st.scale_ci95
    what = (
        "steering_cmd (the command: no steering measurement)"
        if st.input == "steering_cmd"
        else "steering-wheel angle"
    )
    return [
        f"steering (eq. 7): road-wheel angle = {_deg(st.offset_rad)} deg + {st.scale:.5f} * "
        f"{what}   {_flag(st.identifiable)}",
        f"  95% intervals: offset [{_deg(o_lo)}, {_deg(o_hi)}] deg, scale [{s_lo:.5f}, "
        f"{s_hi:.5f}]; fit {sr['method']}; dead time "
        f"{_steering_dead_time(sr['dead_time'])}",
        f"  note: {st.note}",
    ]


def _steering_dead_time(dt: dict) -> str:
    """The steering dead time with its held-out interval, or why it is not determined."""
    lo, hi = dt.get("interval_s") or (None, None)
    if dt.get("used") and lo is not None and hi is not None:
        return f"{dt['estimate_s']:.3f} s (held-out interval [{lo:.3f}, {hi:.3f}] s)"
    return "not determined (0 s used: no lag predicts held-out data better than none)"


def _pair(ci, fmt: str) -> str:
    return "n/a" if ci is None else f"[{ci[0]:{fmt}}, {ci[1]:{fmt}}]"


def _command_model(res) -> list[str]:
    """The zones of a command-driven car (``longitudinal.input: accel_cmd | speed_cmd``)."""
    p, lo = res.params, res.report["longitudinal"]
    key = lo["gain_key"]
    unit = "1/s" if key.endswith("_ps") else "1"
    term = "accel_cmd" if p.command_input == "accel_cmd" else "(speed_cmd - v)"
    out = [
        f"longitudinal (per speed zone; no accelerator pedal, input {p.command_input}: "
        f"{lo['equation']}; acceleration from {lo['selection']['chosen']}):"
    ]
    for z in p.command_zones:
        gain = getattr(z, key)
        ci = z.accel_cmd_gain_ci95 if key == "accel_cmd_gain" else z.speed_cmd_gain_ci95_ps
        tc = (
            f" (time constant {1.0 / gain:.2f} s)"
            if key == "speed_cmd_gain_ps" and gain > 0
            else ""
        )
        out.append(
            f"  {z.name} ({z.v_min_mps:g}, {z.v_max_mps:g}] m/s: a = {z.offset_mps2:+.3f} "
            f"+ {gain:.3f} * {term} [m/s^2]{tc}   {_flag(z.identifiable)}"
        )
        out.append(
            f"      95% intervals: offset {_pair(z.offset_ci95_mps2, '+.3f')} m/s^2, "
            f"{key} {_pair(ci, '.3f')} {unit}"
        )
        if z.note:
            out.append(f"      note: {z.note}")
    return out


def _longitudinal_model(res) -> list[str]:
    p, lo = res.params, res.report["longitudinal"]
    if p.command_zones:
        return _command_model(res)
    out = [
        f"longitudinal (eq. 8 + brake, per speed zone; pedals 0..1, acceleration from "
        f"{lo['selection']['chosen'] if lo.get('selection') else lo['accel_source']}):"
    ]
    for z in p.zones:
        out.append(
            f"  {z.name} ({z.v_min_mps:g}, {z.v_max_mps:g}] m/s: a = {z.offset_mps2:+.3f} "
            f"+ {z.scale_mps2:.3f} * accel_pedal - {z.brake_scale_mps2:.3f} * "
            f"brake_pedal [m/s^2]   {_flag(z.identifiable)}"
        )
        out.append(
            f"      95% intervals: offset {_pair(z.offset_ci95_mps2, '+.3f')}, "
            f"accel_pedal {_pair(z.scale_ci95_mps2, '.3f')}, brake_pedal "
            f"{_pair(z.brake_scale_ci95_mps2, '.3f')} m/s^2"
        )
        if z.note:
            out.append(f"      note: {z.note}")
    return out


def _steering_evidence(res) -> list[str]:
    sr = res.report["steering"]
    smp = sr["samples"]
    dropped = smp.get("dropped") or []
    out = [
        f"  steering: {smp['trustworthy']} trustworthy samples of {smp['total']}"
        + (
            ""
            if not dropped
            else "; dropped "
            + "; ".join(
                f"{d['samples']} {d['text']}" for d in sorted(dropped, key=lambda d: -d["samples"])
            )
        )
    ]
    for k, f in sr["fits"].items():
        out.append(
            f"  steering: fit {k:22s} offset {_deg(f['offset_rad'])} "
            f"[{_deg(f['offset_ci95_rad'][0])}, {_deg(f['offset_ci95_rad'][1])}] deg  "
            f"scale {f['scale']:.5f} [{f['scale_ci95'][0]:.5f}, {f['scale_ci95'][1]:.5f}]"
            + ("" if f.get("trusted", True) else "  (not trusted)")
        )
    sel = sr.get("selection")
    if sel:
        out.append(f"  steering: chosen {sel['chosen']} ({sel['because']})")
        out += [f"  steering: skipped {k}: {why}" for k, why in sel.get("skipped", {}).items()]
        out += [
            f"  steering: not trusted {k}: {why}"
            for k, why in sel.get("untrusted", {}).items()
            if k in sr["fits"]
        ]
        sens = sel.get("sensors")
        if sens:
            head = SENSOR_HEADLINE.get(sens["verdict"])
            out.append(f"  steering: {head + ': ' if head else ''}{sens['note']}")
    ag = sr.get("agreement_a_b")
    if ag:
        out.append(
            f"  steering: (a) wheel speeds vs (b) yaw rate: rms difference "
            f"{math.degrees(ag['rms_difference_rad']):.3f} deg, correlation "
            f"{ag['correlation']:.3f}"
        )
    out.append(
        f"  steering: rms error {math.degrees(res.steering.rms_error_rad):.3f} deg"
        if math.isfinite(res.steering.rms_error_rad)
        else "  steering: rms error n/a (no measured road-wheel angle)"
    )
    if sr.get("understeer"):
        out.append(f"  steering: {sr['understeer']['note']}")
    return out


def _longitudinal_evidence(res) -> list[str]:
    p, lo = res.params, res.report["longitudinal"]
    dci = lo.get("dead_time_ci95_s")
    out = [
        f"  longitudinal: acceleration from {lo['accel_source']}; "
        f"{'command' if p.command_zones else 'pedal'} dead time "
        f"{lo['dead_time_s']:.2f} s"
        + (
            f" ({lo['dead_time_note']})"
            if lo.get("dead_time_note")
            else f" (held-out 95% interval [{dci[0]:.2f}, {dci[1]:.2f}] s)"
            if dci
            else ""
        )
    ]
    out += ["  longitudinal:" + ln.removeprefix(" ") for ln in _source_lines(lo.get("selection"))]
    for z, zr in zip(p.zones or p.command_zones, lo["zones"]):
        nm = "n/a" if z.nmse_pct is None else f"{z.nmse_pct:.1f}%"
        sp = "n/a" if z.speed_rmse_mps is None else f"{z.speed_rmse_mps:.3f} m/s"
        line = f"  longitudinal: zone {z.name}: {zr['samples']} samples, NMSE {nm}, speed RMSE {sp}"
        if zr.get("fos"):
            fz = zr["fos"]
            nmf = "n/a" if fz.get("nmse_pct") is None else f"{fz['nmse_pct']:.1f}%"
            line += f"; FOS terms {', '.join(fz['terms'])} (NMSE {nmf})"
        out.append(line)
    ab = lo["above_last_zone"]
    out.append(
        f"  longitudinal: above the last zone (> {ab['v_max_mps']:g} m/s): "
        f"{ab['samples']} samples, {ab['seconds']:.1f} s (not fitted); standstill (< "
        f"{lo['standstill']['v_stop_mps']:g} m/s): {lo['standstill']['seconds']:.1f} s "
        "excluded"
    )
    return out


def _source_lines(sel: dict | None) -> list[str]:
    """The acceleration source chosen by held-out evidence, every score, and disagreements."""
    if not sel:
        return []

    def score(v: dict) -> str:
        signed = v.get("score_signed_mps2")
        return (
            f"{v['score_mps2']:.4f}"
            + ("" if signed is None or signed >= 0 else f" (signed {signed:+.4f})")
            + (f" (dead time {v['dead_time_s']:.2f} s)" if v["dead_time_s"] else "")
        )

    scores = ", ".join(f"{k} {score(v)}" for k, v in sel["scores"].items())
    out = [
        f"  acceleration source: {sel['chosen']} ({sel['because']})",
        f"  held-out scores [m/s^2, lower is better; a negative excess is clipped to 0, "
        f"signed shown]: {scores}",
    ]
    out += [f"  skipped {k}: {why}" for k, why in sel.get("skipped", {}).items()]
    out += [f"  DISAGREEMENT {st}" for st in sel.get("disagreements", {}).get("statements", [])]
    return out


def run(args) -> int:
    from hmpc.models.report.identification import write_plots

    vehicle = load_params(args.vehicle).vehicle
    rec, sources, ingest_summary = recording_or_log(args, _progress)
    sources["vehicle"] = args.vehicle
    lcfg = replace(
        LongitudinalIdConfig(), accel_source=args.accel_source, hysteresis_mps=args.hysteresis
    )
    types = {f.name: f.type for f in fields(SteeringIdConfig)}
    scfg = SteeringIdConfig.for_vehicle(
        vehicle,
        **{k: int(v) if types[k] in ("int", int) else v for k, v in args.steering_threshold},
    )
    res = identify(
        rec,
        vehicle,
        zones=args.zones,
        steering_config=scfg,
        longitudinal_config=lcfg,
        sources=sources,
        progress=_progress,
    )
    try:
        # checked with the loader's rules before writing, written under a temporary name
        dump_params(res.params, args.out)
    except OSError as exc:
        raise InputError(
            f"cannot write the parameter file ({exc.strerror or exc})", args.out
        ) from None
    for line in summary_lines(res):
        print(line)
    print(f"wrote {args.out}")
    payload = dict(res.report)
    payload["output"] = str(args.out)
    payload["params"] = res.params.to_dict()
    if ingest_summary is not None:
        payload["ingest"] = ingest_summary
    if args.plots:
        _progress(f"writing figures to {args.plots}")
        try:
            payload["plots"] = write_plots(res, args.plots)
        except OSError as exc:
            raise InputError(f"cannot write figures ({exc.strerror or exc})", args.plots) from None
        print(f"wrote {len(payload['plots'])} figures to {args.plots}")
    if args.json:
        try:
            write_json(args.json, payload)
        except OSError as exc:
            raise InputError(f"cannot write JSON ({exc.strerror or exc})", args.json) from None
    return 0
