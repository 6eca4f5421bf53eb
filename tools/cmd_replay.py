"""``hmpc replay``: offline closed-loop replay of a recorded drive (controller/replay.py).

    hmpc replay REC|LOG --params P.yaml [--mode reference|log] [ingest options]
                [--actuation A.yaml] [--controller mpc|nmpc|pid] [--plots DIR] --json OUT

- ``--mode reference`` (default): the recorded path and speed become the reference; the
  controller drives the identified plant over it; compared with the car and its driver.
- ``--mode log``: the log's feedback frames go through the drive loop (``--actuation``'s
  profile) on a simulated clock with no plant; the commands hmpc would have sent are compared
  with those on the log, and a sha256 over them is reported (the same input gives the same
  bytes).

JSON keys: ``mode``, ``controller``, ``input``, ``kpis`` (reference mode: ``controller`` and
``car``), ``differences`` (per signal: ``rms_difference``, ``max_abs_difference``,
``mean_difference``, ``correlation``, ``samples``), ``windows`` (per signal, the
``window_s`` windows where the two differ most: ``t0_s``, ``t1_s``, ``rms``, ``max_abs``),
``compared`` (what was compared, in words), ``hash`` (log mode: ``sha256``, ``frames``),
``engaged_s`` (log mode), ``limit_violations`` (log mode), ``plots``.
"""

from __future__ import annotations

from pathlib import Path

from hmpc.models.errors import InputError
from hmpc.controller.build import make_controller
from hmpc.models.report.closed_loop import plot_log_replay, plot_reference_replay
from hmpc.tools.common import (
    CONTROLLERS,
    adapter_for_profile,
    adapter_from_args,
    add_accept_unidentifiable,
    add_adapt_arguments,
    add_ingest_options,
    finish_adapter,
    load_model_params,
    progress_printer,
    recording_or_log,
    write_json,
)


def add_arguments(p) -> None:

    p.add_argument(
        "recording",
        metavar="REC|LOG",
        help="canonical recording (reference mode), or a raw CAN log with the ingest "
        "options (--dbc and --signals; in log mode they default to the "
        "actuation profile's)",
    )
    p.add_argument("--params", required=True, metavar="P.yaml", help="the controller's model")
    p.add_argument(
        "--mode",
        choices=("reference", "log"),
        default="reference",
        help="reference: the controller drives the identified plant along the "
        "recorded drive; log: the log's frames through the drive loop "
        "(default reference)",
    )
    p.add_argument(
        "--controller",
        choices=CONTROLLERS,
        default="mpc",
        help="the controller (default mpc: the hybrid MPC, OSQP; nmpc: CasADi/IPOPT; "
        "pid: the baseline)",
    )
    add_accept_unidentifiable(p)
    p.add_argument(
        "--actuation",
        metavar="A.yaml",
        help="log mode: the actuation profile (params/*.actuation.yaml)",
    )
    p.add_argument(
        "--reference-source",
        choices=("auto", "nav", "can"),
        default=None,
        help="the recorded path: nav (GNSS/INS x, y, heading), can (dead reckoning "
        "from wheel speeds and steering angle) or auto (nav when present); "
        "default auto in reference mode, can in log mode (the loop's own "
        "estimate is dead reckoning)",
    )
    p.add_argument(
        "--control-period",
        type=float,
        default=0.1,
        metavar="S",
        help="reference mode: controller period [s] (default 0.1; the drive loop "
        "runs the controller at 50 Hz)",
    )
    p.add_argument(
        "--seed",
        type=int,
        default=0,
        help="reference mode: seed of the simulated sensors' noise (default 0)",
    )
    p.add_argument(
        "--window",
        type=float,
        default=5.0,
        metavar="S",
        help="width of the windows where car and controller differ most [s] (default 5)",
    )
    p.add_argument(
        "--candump", metavar="RUN.log", help="log mode: write the drive loop's frames (candump -L)"
    )
    p.add_argument("--plots", metavar="DIR", help="write labelled PNG plots into DIR")
    p.add_argument("--json", metavar="FILE", help="write the figures as JSON")
    add_adapt_arguments(p)
    g = p.add_argument_group("raw log input (the options of `hmpc ingest`)")
    add_ingest_options(g, log_required=False)


_progress = progress_printer("replay")


def run(args) -> int:
    from dataclasses import replace

    from hmpc.controller.replay import ReplayConfig

    if not getattr(args, "topics", None) and not Path(args.recording).is_file():
        # (a ROS recording read with --topics may be a bag folder or a CSV export's folder)
        raise InputError(
            "not a file (a folder)" if Path(args.recording).is_dir() else "no such file",
            args.recording,
        )
    if args.mode == "log" and not args.actuation:
        raise InputError(
            "--mode log needs --actuation A.yaml (the profile whose messages the "
            "drive loop sends and reads)"
        )
    if args.mode == "reference" and (args.actuation or args.candump):
        raise InputError("--actuation and --candump belong to --mode log")
    if not args.window > 0:
        raise InputError("--window must be > 0")
    if not args.control_period > 0:
        raise InputError("--control-period must be > 0")
    params = load_model_params(args.params, args, "replay")
    ctl = make_controller(args.controller, params, accept_unidentifiable=args.accept_unidentifiable)
    cfg = replace(ReplayConfig(), window_s=args.window)
    if args.mode == "log":
        out, plots_of = _run_log(args, params, ctl, cfg)
    else:
        out, plots_of = _run_reference(args, params, ctl, cfg)
    out = {"mode": args.mode, "controller": args.controller, "params": str(args.params), **out}
    if args.plots:
        try:
            out["plots"] = plots_of(args.plots)
        except OSError as exc:
            raise InputError(f"cannot write figures ({exc.strerror or exc})", args.plots) from None
    _print_summary(out)
    try:
        write_json(args.json, out)
    except OSError as exc:
        raise InputError(f"cannot write JSON ({exc.strerror or exc})", args.json) from None
    return 0


def _run_reference(args, params, ctl, cfg):
    from hmpc.controller.replay import reference_replay

    rec, sources, ingest_summary = recording_or_log(args, _progress)
    rec.meta.setdefault("path", str(args.recording))
    _progress(f"reference replay: {args.controller} on the identified plant along {args.recording}")

    def progress(fraction: float, t_s: float) -> None:
        _progress(f"closed loop {100 * fraction:3.0f}% (t = {t_s:.1f} s)")

    adapter = adapter_from_args(args, params, args.control_period, "replay")
    rr = reference_replay(
        rec,
        params,
        ctl,
        control_period_s=args.control_period,
        seed=args.seed,
        reference_source=args.reference_source or "auto",
        config=cfg,
        progress=progress,
        adapter=adapter,
    )
    finish_adapter(args, adapter, "replay", float(rr.run.metrics["duration_s"]))
    out = dict(rr.summary)
    out.pop("mode", None)
    out["input"] = sources
    if ingest_summary is not None:
        out["ingest"] = {
            "duration_s": ingest_summary.get("duration_s"),
            "channels": sorted(ingest_summary.get("channels", {})),
        }
    zones = [(z.name, z.v_min_mps, z.v_max_mps) for z in params.zones]

    def plots(d):
        files = plot_reference_replay(rr, d, args.controller, zones)
        if adapter is not None:  # the learned parameters against time
            from pathlib import Path

            from hmpc.models.report.adaptation import plot_adaptation

            t, v, sg = adapter.history.arrays()
            files.append(
                plot_adaptation(
                    t - (adapter.t0_s or 0.0),
                    adapter.keys,
                    v,
                    sg,
                    Path(d) / "adaptation.png",
                    title="learned parameters (estimate, 95 % interval)",
                )
            )
        return files

    return out, plots


def _run_log(args, params, ctl, cfg):
    from hmpc.controller.actuation.profiles import load_profile
    from hmpc.controller.replay import check_log, log_replay
    from hmpc.models.reference import recording_reference
    from hmpc.models.errors import Problems
    from hmpc.models.logs.canlog import read_log

    if getattr(args, "topics", None):
        raise InputError(
            "--mode log replays a CAN log's frames; replay a ROS recording read "
            "with --topics in --mode reference",
            args.recording,
        )
    profile = load_profile(args.actuation)
    if not (args.dbc or args.signals):  # the profile's own DBC and signal map
        args.dbc, args.signals = profile.dbc_path, str(profile.signal_map.path)
    frames = read_log(args.recording, Problems())
    if len(frames) == 0:
        raise InputError("no CAN frames in the log", args.recording)
    check_log(frames, profile)  # the feedback frames the loop needs, before ingesting
    rec, sources, _ = recording_or_log(args, _progress)
    rec.meta.setdefault("path", str(args.recording))
    ref = recording_reference(
        rec, params, source=args.reference_source or "can", name=str(args.recording)
    )
    shift = float(rec.channels["time"][0] - frames.t_s.min())
    if abs(shift) > 0.5:
        raise InputError(
            f"the recording starts {shift:+.2f} s from the log's first frame: "
            "log mode needs the raw log itself (not a canonical recording)",
            args.recording,
        )
    _progress(
        f"log replay: the frames of {args.recording} through the drive loop "
        f"({profile.name}, {args.controller}) on a simulated clock"
    )

    def progress(fraction: float, t_s: float) -> None:
        _progress(f"log {100 * fraction:3.0f}% (t = {t_s:.1f} s of the log)")

    adapter = adapter_for_profile(args, params, profile, "replay")
    lr = log_replay(
        frames,
        profile,
        params,
        ctl,
        ref,
        candump=args.candump,
        config=cfg,
        progress=progress,
        adapter=adapter,
    )
    finish_adapter(args, adapter, "replay", float(lr.drive.summary["engaged_s"]))
    out = dict(lr.summary)
    out.pop("mode", None)
    out["input"] = {
        **sources,
        "actuation": args.actuation,
        "reference_source": args.reference_source or "can",
    }
    return out, lambda d: plot_log_replay(lr, d, args.controller)


def _print_summary(out: dict) -> None:
    if out["mode"] == "reference":
        c, car = out["kpis"]["controller"], out["kpis"]["car"]
        print(
            f"reference replay, {out['controller']}: speed error RMS "
            f"{c['speed_error_rms_mps']:.3f} m/s, lateral error RMS "
            f"{c['lateral_error_rms_m']:.3f} m, "
            f"pedal switches {c['pedal_switches_per_min']:.1f}/min (car "
            f"{car['pedal_switches_per_min']:.1f}), zone transitions "
            f"{c['zone_transitions_per_min']:.1f}/min "
            f"(car {car['zone_transitions_per_min']:.1f}), "
            f"{c['failures']} failures"
        )
    else:
        h = out["hash"]
        print(
            f"log replay, {out['controller']}: {h['frames']} frames sent, sha256 {h['sha256']}, "
            f"limit violations {out['limit_violations']}"
        )
    for name, d in out["differences"].items():
        if not isinstance(d, dict) or d.get("rms_difference") is None:
            continue
        corr = "n/a" if d["correlation"] is None else f"{d['correlation']:+.3f}"
        print(
            f"  {name}: RMS difference {d['rms_difference']:.4g}, "
            f"max {d['max_abs_difference']:.4g}, "
            f"correlation {corr} ({d['samples']} samples)"
        )
    for name, ws in out["windows"].items():
        if ws:
            w = ws[0]
            print(
                f"  {name}: largest difference {w['t0_s']:.1f}-{w['t1_s']:.1f} s "
                f"(RMS {w['rms']:.4g})"
            )
