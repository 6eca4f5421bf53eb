"""``hmpc operator``: the tele-operation station (``controller.teleop``).

    hmpc operator --key KEYFILE [--connect HOST:PORT]
        (--script OPS.csv | --experiment NAME | --keyboard | --gamepad)
        [--params P.yaml] [--seed N] [--duration S] [--json OUT] [--write-script OUT.csv]
    hmpc operator --key KEYFILE --make-key

Sends authenticated commands at 50 Hz to the vehicle side (``hmpc teleop``, default
``127.0.0.1:47700``) and shows its telemetry live. The key is read from a file only its owner
may read (``--make-key`` writes a new one with mode 0600); it is never taken from the command
line. ``--experiment`` runs one of the report's experiments as a built-in script, computed by
the ground-truth simulator's driver on ``--params`` (default: the report's parameters); the
script CSV format is in ``controller/teleop/operator.py``. JSON: ``end``, ``duration_s``,
``sent``, telemetry counts, the last ``vehicle`` state, ``link`` statistics and ``stop``.
"""

from __future__ import annotations

import os
import socket
import sys

from hmpc.models.errors import InputError
from hmpc.tools.common import write_json


def add_arguments(p) -> None:
    p.add_argument(
        "--key",
        required=True,
        metavar="KEYFILE",
        help="pre-shared key file: one line of hex, >= 32 bytes, mode 0600",
    )
    p.add_argument(
        "--make-key",
        action="store_true",
        help="write a new random key to KEYFILE (mode 0600) and exit",
    )
    p.add_argument(
        "--connect",
        default="127.0.0.1:47700",
        metavar="HOST:PORT",
        help="the vehicle side's address (default 127.0.0.1:47700)",
    )
    src = p.add_mutually_exclusive_group()
    src.add_argument("--script", metavar="OPS.csv", help="scripted operator: timed commands")
    src.add_argument(
        "--experiment",
        metavar="NAME",
        help="one of the report's experiments as a built-in script: arcs, circles, "
        "figure8, ramps, ramp_sequence, open_loop",
    )
    src.add_argument("--keyboard", action="store_true", help="keyboard operator (terminal)")
    src.add_argument("--gamepad", action="store_true", help="gamepad operator (/dev/input/js*)")
    p.add_argument(
        "--params",
        metavar="P.yaml",
        help="--experiment: the model its driver is simulated on (default: the "
        "report's parameters, params/report_2008.yaml)",
    )
    p.add_argument("--seed", type=int, default=0, help="--experiment: simulator seed (default 0)")
    p.add_argument(
        "--duration",
        type=float,
        metavar="S",
        help="end the run after S seconds (default: when the source ends)",
    )
    p.add_argument(
        "--write-script",
        metavar="OUT.csv",
        help="write the (built-in) script as CSV and exit without sending",
    )
    p.add_argument(
        "--no-tui",
        action="store_true",
        help="no live screen (default: live screen when stdout is a terminal)",
    )
    p.add_argument("--json", metavar="FILE", help="write the run's figures as JSON")


def run(args) -> int:
    from hmpc.controller.teleop import link as L
    from hmpc.controller.teleop import operator as op

    if args.make_key:
        try:
            path = L.create_key(args.key)
        except FileExistsError:
            raise InputError("key file exists already (never overwritten)", args.key) from None
        print(
            f"wrote a new {L.MIN_KEY_BYTES}-byte key to {path} (mode 0600); copy it to the "
            "vehicle side over a secure channel"
        )
        return 0
    if not (args.script or args.experiment or args.keyboard or args.gamepad):
        raise InputError("one of --script, --experiment, --keyboard, --gamepad is required")
    if args.duration is not None and not args.duration > 0:
        raise InputError(f"--duration must be positive, got {args.duration}")

    key = L.load_key(args.key)  # first: a refused key stops everything, script or not
    source, label = _source(args, op)
    if args.write_script:
        if not isinstance(source, op.Script):
            raise InputError("--write-script needs --script or --experiment")
        op.write_script(source, args.write_script)
        print(f"wrote {len(source.commands)} rows ({source.end_s:.1f} s) to {args.write_script}")
        return 0

    try:
        target = L.parse_address(args.connect)
        link = L.OperatorLink(key, target)
    except (ValueError, OSError) as exc:
        raise InputError(f"--connect {args.connect}: {exc}") from None
    try:
        summary = _run(args, op, source, label, link)
    finally:
        link.close()
    out = summary.to_dict()
    out.update(source=label, connect=args.connect)
    if isinstance(source, op.Script):
        out["script"] = {
            "name": source.name,
            "rows": len(source.commands),
            "duration_s": round(source.end_s, 3),
            **source.meta,
        }
    write_json(args.json, out)
    link_s = out["link"]
    if link_s is None:
        print(
            f"hmpc operator: {summary.end} after {summary.duration_s:.1f} s, sent "
            f"{summary.sent}; no telemetry received (is the vehicle side listening on "
            f"{args.connect}?)",
            file=sys.stderr,
        )
    else:
        stop = out["stop"]["reason"] if out["stop"] else "none"
        print(
            f"hmpc operator: {summary.end} after {summary.duration_s:.1f} s, sent "
            f"{summary.sent}, vehicle accepted {link_s['accepted']}, rejected "
            f"{sum(link_s['rejected'].values())}, latency p50 {link_s['latency_ms']['p50']} "
            f"ms p99 {link_s['latency_ms']['p99']} ms, stop {stop}",
            file=sys.stderr,
        )
    return 0


def _source(args, op):
    if args.script:
        return op.load_script(args.script), f"script {os.path.basename(args.script)}"
    if args.experiment:
        from hmpc.models.params import load_params
        from hmpc.tools.datafiles import PARAMS_DIR

        params = load_params(args.params or PARAMS_DIR / "report_2008.yaml", require_model=True)
        return (
            experiment_script(args.experiment, params, seed=args.seed),
            f"experiment {args.experiment}",
        )
    if args.keyboard:
        return op.KeyboardOperator(), "keyboard"
    return op.GamepadOperator(), "gamepad"


def _run(args, op, source, label, link):
    from hmpc.controller.teleop.tui import OperatorScreen, TerminalKeys

    use_tui = args.keyboard or (sys.stdout.isatty() and not args.no_tui)
    if args.keyboard and not sys.stdin.isatty():
        raise InputError("--keyboard needs a terminal on stdin")
    screen = (
        OperatorScreen("keyboard" if args.keyboard else label, args.connect) if use_tui else None
    )
    before = None
    keys = None
    dev_fd = None
    if args.keyboard:
        keys = TerminalKeys()

        def before():
            for k in keys.read():
                if source.handle_key(k) is not None and screen is not None:
                    screen.last_key = k
    elif args.gamepad:
        path = op.find_gamepad()  # NoGamepadError: "no gamepad found", exit 2
        try:
            dev_fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK)
        except OSError as exc:
            raise InputError(f"cannot open gamepad: {exc.strerror}", path) from None

        def before():
            source.read_events(dev_fd)

    def on_tick(t, cmd, tel):
        if screen is not None:
            screen.update(t, cmd, tel)

    try:
        if keys is not None:
            keys.__enter__()
        if screen is not None:
            screen.__enter__()
        summary = op.run_operator(
            source, link, duration_s=args.duration, on_tick=on_tick, before_tick=before
        )
        if screen is not None:
            screen.update(summary.duration_s, None, link.telemetry, force=True)
        return summary
    except socket.gaierror as exc:
        raise InputError(f"--connect {args.connect}: {exc}") from None
    finally:
        if screen is not None:
            screen.__exit__(None, None, None)
        if keys is not None:
            keys.__exit__(None, None, None)
        if dev_fd is not None:
            os.close(dev_fd)


def experiment_script(name: str, params, *, seed: int = 0, rate_hz: float | None = None):
    """One of the report's experiments (section III) as a pedals-and-steering script.

    The experiment is not written again here: ``models.sim.simulator.run_experiment`` drives its
    plan (steering steps, circles, figure eights, speed ramps) with the simulator's human-like
    driver on the model ``params``, and the script is that driver's steering-wheel angle and
    pedals (the truth inputs, no sensor noise), sampled at ``rate_hz`` (default: the
    operator's command rate).

    The pedals are open loop: on a car whose model differs from ``params`` the speeds drift
    from the plan's (the steering pattern, the pedal patterns and the zone coverage are what
    identification needs, not the exact speeds); the vehicle side's limits cap them.

    Args:
        name: an experiment of ``models.sim.simulator.EXPERIMENTS``.
        params: the model the driver is simulated on (a complete ``Params``).
        seed: the simulator's seed (plan randomness: figure-eight radii, driver dither).
        rate_hz: command rate [Hz] (a divisor of the simulator's 100 Hz is exact).
    """
    from hmpc.controller.teleop.operator import RATE_HZ, inputs_script
    from hmpc.models.sim.plans import EXPERIMENTS
    from hmpc.models.sim.simulator import run_experiment

    rate_hz = RATE_HZ if rate_hz is None else rate_hz
    if name not in EXPERIMENTS:
        raise InputError(
            f"--experiment: unknown experiment '{name}' (known: {', '.join(EXPERIMENTS)})"
        )
    run = run_experiment(name, params, seed=seed, rate_hz=rate_hz, noise="none")
    return inputs_script(
        run.recording.channels["time"],
        run.truth_on_grid("sw_rad"),
        run.truth_on_grid("accel_pedal"),
        run.truth_on_grid("brake_pedal"),
        name=f"experiment:{name}",
        rate_hz=rate_hz,
        meta={
            "experiment": name,
            "seed": int(seed),
            "rate_hz": float(rate_hz),
            "params": getattr(params, "path", None),
        },
    )
