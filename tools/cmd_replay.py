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

import sys
from pathlib import Path

from hmpc.models.errors import InputError
from hmpc.tools.cmd_simulate import add_accept_unidentifiable

CONTROLLERS = ("mpc", "nmpc", "pid")


def add_arguments(p) -> None:
    from hmpc.tools.cmd_ingest import add_ingest_options

    p.add_argument("recording", metavar="REC|LOG",
                   help="canonical recording (reference mode), or a raw CAN log with the ingest "
                        "options (--dbc and --signals; in log mode they default to the "
                        "actuation profile's)")
    p.add_argument("--params", required=True, metavar="P.yaml", help="the controller's model")
    p.add_argument("--mode", choices=("reference", "log"), default="reference",
                   help="reference: the controller drives the identified plant along the "
                        "recorded drive; log: the log's frames through the drive loop "
                        "(default reference)")
    p.add_argument("--controller", choices=CONTROLLERS, default="mpc",
                   help="the controller (default mpc: the hybrid MPC, OSQP; nmpc: CasADi/IPOPT; "
                        "pid: the baseline)")
    add_accept_unidentifiable(p)
    p.add_argument("--actuation", metavar="A.yaml",
                   help="log mode: the actuation profile (params/*.actuation.yaml)")
    p.add_argument("--reference-source", choices=("auto", "nav", "can"), default=None,
                   help="the recorded path: nav (GNSS/INS x, y, heading), can (dead reckoning "
                        "from wheel speeds and steering angle) or auto (nav when present); "
                        "default auto in reference mode, can in log mode (the loop's own "
                        "estimate is dead reckoning)")
    p.add_argument("--control-period", type=float, default=0.1, metavar="S",
                   help="reference mode: controller period [s] (default 0.1; the drive loop "
                        "runs the controller at 50 Hz)")
    p.add_argument("--seed", type=int, default=0,
                   help="reference mode: seed of the simulated sensors' noise (default 0)")
    p.add_argument("--window", type=float, default=5.0, metavar="S",
                   help="width of the windows where car and controller differ most [s] "
                        "(default 5)")
    p.add_argument("--candump", metavar="RUN.log",
                   help="log mode: write the drive loop's frames (candump -L)")
    p.add_argument("--plots", metavar="DIR", help="write labelled PNG plots into DIR")
    p.add_argument("--json", metavar="FILE", help="write the figures as JSON")
    g = p.add_argument_group("raw log input (the options of `hmpc ingest`)")
    add_ingest_options(g, log_required=False)


def _progress(msg: str) -> None:
    print(f"hmpc replay: {msg}", file=sys.stderr, flush=True)


def run(args) -> int:
    from dataclasses import replace

    from hmpc.controller.replay import ReplayConfig
    from hmpc.tools.cli import write_json
    from hmpc.tools.cmd_simulate import load_model_params, make_controller

    if not Path(args.recording).is_file():
        raise InputError("not a file (a folder)" if Path(args.recording).is_dir()
                         else "no such file", args.recording)
    if args.mode == "log" and not args.actuation:
        raise InputError("--mode log needs --actuation A.yaml (the profile whose messages the "
                         "drive loop sends and reads)")
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
    from hmpc.tools.cmd_ingest import recording_or_log

    rec, sources, ingest_summary = recording_or_log(args, _progress)
    rec.meta.setdefault("path", str(args.recording))
    _progress(f"reference replay: {args.controller} on the identified plant along "
              f"{args.recording}")

    def progress(fraction: float, t_s: float) -> None:
        _progress(f"closed loop {100 * fraction:3.0f}% (t = {t_s:.1f} s)")
    rr = reference_replay(rec, params, ctl, control_period_s=args.control_period, seed=args.seed,
                          reference_source=args.reference_source or "auto", config=cfg,
                          progress=progress)
    out = dict(rr.summary)
    out.pop("mode", None)
    out["input"] = sources
    if ingest_summary is not None:
        out["ingest"] = {"duration_s": ingest_summary.get("duration_s"),
                         "channels": sorted(ingest_summary.get("channels", {}))}
    zones = [(z.name, z.v_min_mps, z.v_max_mps) for z in params.zones]
    return out, lambda d: _reference_plots(rr, d, args.controller, zones)


def _run_log(args, params, ctl, cfg):
    from hmpc.controller.actuation.profiles import load_profile
    from hmpc.controller.replay import check_log, log_replay, recording_reference
    from hmpc.models.errors import Problems
    from hmpc.models.logs.canlog import read_log
    from hmpc.tools.cmd_ingest import recording_or_log

    profile = load_profile(args.actuation)
    if not (args.dbc or args.signals):   # the profile's own DBC and signal map
        args.dbc, args.signals = profile.dbc_path, str(profile.signal_map.path)
    frames = read_log(args.recording, Problems())
    if len(frames) == 0:
        raise InputError("no CAN frames in the log", args.recording)
    check_log(frames, profile)   # the feedback frames the loop needs, before ingesting
    rec, sources, _ = recording_or_log(args, _progress)
    rec.meta.setdefault("path", str(args.recording))
    ref = recording_reference(rec, params, source=args.reference_source or "can",
                              name=str(args.recording))
    shift = float(rec.channels["time"][0] - frames.t_s.min())
    if abs(shift) > 0.5:
        raise InputError(f"the recording starts {shift:+.2f} s from the log's first frame: "
                         "log mode needs the raw log itself (not a canonical recording)",
                         args.recording)
    _progress(f"log replay: the frames of {args.recording} through the drive loop "
              f"({profile.name}, {args.controller}) on a simulated clock")

    def progress(fraction: float, t_s: float) -> None:
        _progress(f"log {100 * fraction:3.0f}% (t = {t_s:.1f} s of the log)")
    lr = log_replay(frames, profile, params, ctl, ref, candump=args.candump, config=cfg,
                    progress=progress)
    out = dict(lr.summary)
    out.pop("mode", None)
    out["input"] = {**sources, "actuation": args.actuation,
                    "reference_source": args.reference_source or "can"}
    return out, lambda d: _log_plots(lr, d, args.controller)


def _print_summary(out: dict) -> None:
    if out["mode"] == "reference":
        c, car = out["kpis"]["controller"], out["kpis"]["car"]
        print(f"reference replay, {out['controller']}: speed error RMS "
              f"{c['speed_error_rms_mps']:.3f} m/s, lateral error RMS {c['lateral_error_rms_m']:.3f} m, "
              f"pedal switches {c['pedal_switches_per_min']:.1f}/min (car "
              f"{car['pedal_switches_per_min']:.1f}), zone transitions "
              f"{c['zone_transitions_per_min']:.1f}/min (car {car['zone_transitions_per_min']:.1f}), "
              f"{c['failures']} failures")
    else:
        h = out["hash"]
        print(f"log replay, {out['controller']}: {h['frames']} frames sent, sha256 {h['sha256']}, "
              f"limit violations {out['limit_violations']}")
    for name, d in out["differences"].items():
        if not isinstance(d, dict) or d.get("rms_difference") is None:
            continue
        corr = "n/a" if d["correlation"] is None else f"{d['correlation']:+.3f}"
        print(f"  {name}: RMS difference {d['rms_difference']:.4g}, max {d['max_abs_difference']:.4g}, "
              f"correlation {corr} ({d['samples']} samples)")
    for name, ws in out["windows"].items():
        if ws:
            w = ws[0]
            print(f"  {name}: largest difference {w['t0_s']:.1f}-{w['t1_s']:.1f} s "
                  f"(RMS {w['rms']:.4g})")


def _shade(ax, windows, color="C3") -> None:
    """Shade the windows where the two differ most (the JSON's ``windows``)."""
    for i, w in enumerate(windows):
        ax.axvspan(w["t0_s"], w["t1_s"], color=color, alpha=0.12,
                   label="largest differences" if i == 0 else None)


def _figure(rows: int):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    return plt, *plt.subplots(rows, 1, figsize=(10, 2.6 * rows), sharex=True)


def _reference_plots(rr, out_dir: str, controller: str, zones=()) -> list[str]:
    """Controller on the plant against the car: speed, distance from the driven path,
    steering-wheel angle, pedals, zones (labelled PNGs, units on every axis; ``zones``:
    (name, v_min, v_max) per zone index, the zone axis's tick labels)."""
    import numpy as np

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    ch, car, win = rr.run.recording.channels, rr.car, rr.summary["windows"]
    t = ch["time"]
    plt, fig, ax = _figure(5)
    ax[0].plot(t, car["speed_mps"], "k--", label="car (recorded)")
    ax[0].plot(t, ch["speed"], label=f"{controller} on the identified plant")
    _shade(ax[0], win["speed_mps"])
    ax[0].set_ylabel("speed [m/s]")
    ax[1].plot(t, rr.run.lateral_error_m, color="C1")
    _shade(ax[1], win["lateral_m"])
    ax[1].set_ylabel("distance from the\ndriven path [m]")
    ax[2].plot(t, np.degrees(car["steering_wheel_angle_rad"]), "k--", label="car (recorded)")
    ax[2].plot(t, np.degrees(ch["steering_wheel_angle"]), label=controller)
    _shade(ax[2], win["steering_wheel_angle_rad"])
    ax[2].set_ylabel("steering-wheel angle [deg]")
    ax[3].plot(t, car["accel_pedal"], "k--", label="car accelerator")
    ax[3].plot(t, ch["accel_pedal_cmd"], label=f"{controller} accelerator")
    ax[3].plot(t, ch["brake_pedal_cmd"], label=f"{controller} brake")
    ax[3].set_ylabel("pedal [0..1]")
    ax[4].step(t, car["zone"], "k--", where="post", label="car")
    ax[4].step(t, rr.run.zone, where="post", label=controller)
    ax[4].set_ylabel("speed zone")
    if zones:
        ax[4].set_yticks(range(len(zones)),
                         [f"{n} ({lo:g}-{hi:g} m/s)" for n, lo, hi in zones], fontsize=8)
    ax[4].set_xlabel("time from the recording's start [s]")
    for a in ax:
        a.legend(loc="best", fontsize=8)
    k = rr.summary["kpis"]["controller"]
    fig.suptitle(f"reference replay, {controller}: speed error RMS {k['speed_error_rms_mps']:.3f} "
                 f"m/s, lateral RMS {k['lateral_error_rms_m']:.3f} m")
    fig.tight_layout()
    files = [str(out / "replay_reference.png")]
    fig.savefig(files[0], dpi=90)
    plt.close(fig)
    fig, a = plt.subplots(figsize=(7, 7))
    a.plot(rr.reference.x_m, rr.reference.y_m, "k--", label="car (recorded path)")
    a.plot(ch["x"], ch["y"], label=controller)
    a.set_xlabel("x (east) [m]")
    a.set_ylabel("y (north) [m]")
    a.set_aspect("equal", adjustable="datalim")
    a.legend(loc="best")
    a.set_title(f"reference replay, {controller}: path")
    files.append(str(out / "replay_path.png"))
    fig.savefig(files[1], dpi=90)
    plt.close(fig)
    return files


def _log_plots(lr, out_dir: str, controller: str) -> list[str]:
    """hmpc's commands against the log's, one panel per signal, engaged spans marked."""
    import numpy as np

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    sig = lr.signals
    plt, fig, ax = _figure(len(sig) + 1)
    ax = np.atleast_1d(ax)
    for a, (name, s) in zip(ax, sig.items()):
        a.plot(s["t_s"], s["log"], "k", lw=0.8, label="log (recorded sender)")
        a.plot(s["t_s"], s["hmpc"], "C0", lw=0.8, label=f"hmpc ({controller})")
        both = s["engaged_log"] & s["engaged_hmpc"]
        a.fill_between(s["t_s"], 0, 1, where=~both, color="0.5", alpha=0.15,
                       transform=a.get_xaxis_transform(), label="not both engaged")
        _shade(a, lr.summary["windows"].get(name, []))
        a.set_ylabel(f"{name}\n[{s['unit']}]", fontsize=8)
        a.legend(loc="best", fontsize=7)
    tr = lr.drive.trace
    eng = np.asarray(tr["engaged"]) > 0.5
    t = np.asarray(tr["t_s"])
    ax[-1].plot(t[eng], np.degrees(np.asarray(tr["sw"])[eng]), "k", lw=0.8,
                label="measured (what the log's controller steered)")
    ax[-1].plot(t[eng], np.degrees(np.asarray(tr["sw_cmd"])[eng]), "C0", lw=0.8,
                label="hmpc's angle command")
    ax[-1].set_ylabel("steering-wheel\nangle [deg]")
    ax[-1].set_xlabel("time from the log's first frame [s]")
    ax[-1].legend(loc="best", fontsize=7)
    fig.suptitle(f"log replay, {controller}: sha256 {lr.summary['hash']['sha256'][:16]}...")
    fig.tight_layout()
    f = str(out / "replay_log.png")
    fig.savefig(f, dpi=90)
    plt.close(fig)
    return [f]
