"""`hmpc identify`: the report's steering map (eq. 7) and zone accelerator models (eq. 8) from a
canonical recording or a raw CAN log (with the `hmpc ingest` options), as a parameter file."""
from __future__ import annotations

import argparse
import math
from dataclasses import replace

from hmpc.models.errors import InputError
from hmpc.tools.common import add_ingest_options, progress_printer, recording_or_log, write_json
from hmpc.models.identify.pipeline import identify
from hmpc.models.identify.longitudinal import ACCEL_SOURCES, LongitudinalIdConfig
from hmpc.models.params import dump_params, load_params


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
            raise argparse.ArgumentTypeError(f"zone speeds must be numbers [m/s], got {part!r}") \
                from None
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


def add_arguments(p: argparse.ArgumentParser) -> None:

    p.add_argument("recording", metavar="REC",
                   help="canonical recording (.csv, .csv.gz, .parquet), or a raw CAN log when "
                        "--dbc and --signals are given")
    p.add_argument("--vehicle", required=True, metavar="GEOMETRY.yaml",
                   help="vehicle geometry (params/*.yaml; at least wheelbase_m, track_front_m)")
    p.add_argument("--out", required=True, metavar="PARAMS.yaml",
                   help="parameter file to write (the CONVENTIONS keys plus optional ones)")
    p.add_argument("--plots", metavar="DIR", help="write figures like the report's Figs. 2-5")
    p.add_argument("--json", metavar="FILE", help="write every figure (stable keys, SI units)")
    p.add_argument("--zones", type=_zones, metavar="NAME:VMIN:VMAX,...",
                   help="speed zones [m/s] (default idle:0:2,low:2:5,high:5:20)")
    p.add_argument("--accel-source", choices=ACCEL_SOURCES, default="auto",
                   help="measured acceleration: auto (chosen by held-out evidence among the "
                        "sources the recording has), wheel_speeds, speed, gps_speed, accel_x "
                        "(default auto)")
    p.add_argument("--hysteresis", type=_nonneg, default=0.0, metavar="MPS",
                   help="zone hysteresis when assigning samples [m/s] (default 0: sharp "
                        "boundaries as in the report)")
    g = p.add_argument_group("raw log input (the options of `hmpc ingest`)")
    add_ingest_options(g, log_required=False)


_progress = progress_printer("identify")


def summary_lines(res) -> list[str]:
    """Human-readable summary for stdout."""
    # the report's list: every part, and every zone value copied or taken from a prior
    ni = res.report.get("not_identified") or res.params.not_identified
    out = [f"not identified: {part}: {why}" for part, why in ni.items()]
    if res.steering is not None:
        out += _steering_lines(res)
    if res.longitudinal is not None:
        out += _longitudinal_lines(res)
    return out


def _steering_lines(res) -> list[str]:
    p, r = res.params, res.report
    st, sr = p.steering, r["steering"]
    out = [f"steering (eq. 7): road-wheel angle = {st.offset_rad:+.5f} rad + {st.scale:.5f} x "
           f"steering-wheel angle   [{sr['method']}]",
           f"  offset 95% CI [{st.offset_ci95_rad[0]:+.5f}, {st.offset_ci95_rad[1]:+.5f}] rad, "
           f"scale 95% CI [{st.scale_ci95[0]:.5f}, {st.scale_ci95[1]:.5f}]",
           f"  dead time {_steering_dead_time(sr['dead_time'])}; rms error "
           f"{st.rms_error_rad:.5f} rad; {sr['samples']['trustworthy']} trustworthy samples"]
    for k, f in sr["fits"].items():
        out.append(f"  fit {k:24s} offset {f['offset_rad']:+.5f} [{f['offset_ci95_rad'][0]:+.5f}, "
                   f"{f['offset_ci95_rad'][1]:+.5f}]  scale {f['scale']:.5f} "
                   f"[{f['scale_ci95'][0]:.5f}, {f['scale_ci95'][1]:.5f}]")
    sel = sr.get("selection")
    if sel:
        out.append(f"  chosen: {sel['chosen']} ({sel['because']})")
        out += [f"  skipped {k}: {why}" for k, why in sel.get("skipped", {}).items()]
    ag = sr.get("agreement_a_b")
    if ag:
        out.append(f"  (a) wheel speeds vs (b) yaw rate: rms difference "
                   f"{ag['rms_difference_rad']:.5f} rad, correlation {ag['correlation']:.3f}, "
                   f"scale ratio {ag['scale_ratio']:.3f}")
    out.append(f"  {st.note}")
    return out


def _steering_dead_time(dt: dict) -> str:
    """The steering dead time with its held-out interval, or why it is not determined."""
    lo, hi = dt.get("interval_s") or (None, None)
    if dt.get("used") and lo is not None and hi is not None:
        return f"{dt['estimate_s']:.3f} s (held-out interval [{lo:.3f}, {hi:.3f}] s)"
    return "not determined (0 s used: no lag predicts held-out data better than none)"


def _longitudinal_lines(res) -> list[str]:
    p, r = res.params, res.report
    out = []
    lo = r["longitudinal"]
    dci = lo.get("dead_time_ci95_s")
    out.append(f"accelerator models (eq. 8 + brake), acceleration from {lo['accel_source']}; "
               f"pedal dead time {lo['dead_time_s']:.2f} s"
               + (f" ({lo['dead_time_note']})" if lo.get("dead_time_note") else
                  f" (held-out 95% interval [{dci[0]:.2f}, {dci[1]:.2f}] s)" if dci else ""))
    out += _source_lines(lo.get("selection"))
    for z, zr in zip(p.zones, lo["zones"]):
        nm = "   n/a" if z.nmse_pct is None else f"{z.nmse_pct:6.1f}%"
        sp = "  n/a" if z.speed_rmse_mps is None else f"{z.speed_rmse_mps:.3f}"
        out.append(f"  {z.name:5s} ({z.v_min_mps:g},{z.v_max_mps:g}] m/s: a = {z.offset_mps2:+.3f}"
                   f" + {z.scale_mps2:.3f} accel - {z.brake_scale_mps2:.3f} brake  NMSE {nm}  "
                   f"speed RMSE {sp} m/s  ({zr['samples']} samples)"
                   + ("" if z.identifiable else "  NOT IDENTIFIABLE"))
        if zr.get("fos"):
            fz = zr["fos"]
            nmf = "n/a" if fz.get("nmse_pct") is None else f"{fz['nmse_pct']:.1f}%"
            out.append(f"        FOS terms: {', '.join(fz['terms'])} (NMSE {nmf})")
        if z.note:
            out.append(f"        note: {z.note}")
    ab = lo["above_last_zone"]
    out.append(f"  above the last zone (> {ab['v_max_mps']:g} m/s): {ab['samples']} samples, "
               f"{ab['seconds']:.1f} s (not fitted)")
    out.append(f"  standstill (< {lo['standstill']['v_stop_mps']:g} m/s): "
               f"{lo['standstill']['seconds']:.1f} s excluded")
    return out


def _source_lines(sel: dict | None) -> list[str]:
    """The acceleration source chosen by held-out evidence, every score, and disagreements."""
    if not sel:
        return []
    def score(v: dict) -> str:
        signed = v.get("score_signed_mps2")
        return (f"{v['score_mps2']:.4f}"
                + ("" if signed is None or signed >= 0 else f" (signed {signed:+.4f})")
                + (f" (dead time {v['dead_time_s']:.2f} s)" if v["dead_time_s"] else ""))

    scores = ", ".join(f"{k} {score(v)}" for k, v in sel["scores"].items())
    out = [f"  acceleration source: {sel['chosen']} ({sel['because']})",
           f"  held-out scores [m/s^2, lower is better; a negative excess is clipped to 0, "
           f"signed shown]: {scores}"]
    out += [f"  skipped {k}: {why}" for k, why in sel.get("skipped", {}).items()]
    out += [f"  DISAGREEMENT {st}" for st in sel.get("disagreements", {}).get("statements", [])]
    return out


def run(args) -> int:
    from hmpc.models.report.identification import write_plots

    vehicle = load_params(args.vehicle).vehicle
    rec, sources, ingest_summary = recording_or_log(args, _progress)
    sources["vehicle"] = args.vehicle
    lcfg = replace(LongitudinalIdConfig(), accel_source=args.accel_source,
                   hysteresis_mps=args.hysteresis)
    res = identify(rec, vehicle, zones=args.zones, longitudinal_config=lcfg, sources=sources,
                   progress=_progress)
    try:
        dump_params(res.params, args.out)
    except OSError as exc:
        raise InputError(f"cannot write the parameter file ({exc.strerror or exc})", args.out) \
            from None
    load_params(args.out)  # what we wrote must load strictly (absent parts named under not_identified)
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
