"""``hmpc drive``: the real-time actuation loop on a CAN bus (controller/actuation/drive.py).

    hmpc drive --params P.yaml --actuation A.yaml [--bus virtual|socketcan:CHANNEL]
               [--vehicle-sim [--plant-params P2.yaml]] (--scenario NAME | --reference REF.csv)
               [--controller mpc|nmpc|pid] [--duration S] [--fault NAME@T_S ...]
               --candump RUN.log [--json OUT.json]

JSON keys: ``steps``, ``loop_period_ms`` {p50, p99, max}, ``deadline_misses``, ``frames_sent``
per message, ``frames_rejected_by_vehicle``, ``limit_clips``, ``limit_violations``,
``engaged_s``, ``stop`` {reason, t_s, detected_t_s, standstill_t_s}, and the ``hmpc simulate``
KPIs (``speed_error_rms_mps``, ``lateral_error_rms_m``, ``pedal_switches_per_min``,
``zone_transitions_per_min``, ``solve_time_ms``, ``failures``), whether the car did what was
asked (``followed``, ``not_followed``, ``limits``, ``stalls``: a run that did not exits 1) and,
with ``--adapt``, ``adaptation`` as ``hmpc simulate``'s.
"""

from __future__ import annotations

import sys

from hmpc.models.errors import InputError
from hmpc.controller.build import make_controller
from hmpc.models.reference import load_reference
from hmpc.tools.common import (
    CONTROLLERS,
    STOP_WHY,
    add_adapt_arguments,
    add_bus_arguments,
    adapter_for_profile,
    bus_kwargs,
    finish_adapter,
    load_model_params,
    report_not_followed,
    stop_times,
    write_json,
)


def add_arguments(p) -> None:
    p.add_argument("--params", required=True, metavar="P.yaml", help="the controller's model")
    p.add_argument(
        "--actuation",
        required=True,
        metavar="A.yaml",
        help="actuation profile (params/*.actuation.yaml)",
    )
    add_bus_arguments(p)
    what = p.add_mutually_exclusive_group(required=True)
    what.add_argument(
        "--scenario", metavar="NAME", help="a named reference (figure8, ramp_sequence, ...)"
    )
    what.add_argument(
        "--reference",
        metavar="REF.csv",
        help="a reference CSV (time, x, y, speed[, heading]) or a canonical "
        "recording, whose driven path and speed are followed",
    )
    p.add_argument(
        "--controller",
        choices=CONTROLLERS,
        default="mpc",
        help="the controller (default mpc: the hybrid MPC, OSQP; nmpc: CasADi/IPOPT; "
        "pid: the baseline)",
    )
    p.add_argument(
        "--duration",
        type=float,
        metavar="S",
        help="run time after engagement before the run's own controlled stop; "
        "without it the run lasts until Ctrl-C or the end of the reference "
        "(there is nothing left to follow), whichever comes first",
    )
    p.add_argument(
        "--fault",
        action="append",
        default=[],
        metavar="NAME@T_S",
        help="inject a fault at T_S seconds of run time: feedback_loss, clock_freeze, "
        "solver_failure, bus_error, driver_override, vehicle_rejects",
    )
    p.add_argument(
        "--candump",
        required=True,
        metavar="RUN.log",
        help="write every frame sent and received here (candump -L)",
    )
    p.add_argument("--json", metavar="FILE", help="write the run's figures as JSON")
    add_adapt_arguments(p)


def run(args) -> int:
    from hmpc.controller.actuation.candump import audit_candump
    from hmpc.controller.actuation.drive import DriveLoop
    from hmpc.controller.actuation.faults import parse_fault
    from hmpc.controller.actuation.profiles import load_profile
    from hmpc.controller.actuation.vehicle_node import VehicleNode
    from hmpc.models.sim.scenarios import make_scenario

    params = load_model_params(args.params, args, "drive")
    profile = load_profile(args.actuation)
    faults = [parse_fault(f) for f in args.fault]
    if args.plant_params and not args.vehicle_sim:
        raise InputError("--plant-params belongs to --vehicle-sim")
    if args.duration is not None and not args.duration > 0:
        raise InputError("--duration must be > 0")
    truth = load_model_params(args.plant_params, args, "drive") if args.plant_params else params
    ref = (
        make_scenario(args.scenario, params)
        if args.scenario is not None
        else load_reference(args.reference, params)
    )
    kw = bus_kwargs(args.bus)
    node = None
    if args.vehicle_sim:
        node = VehicleNode(profile, truth, kw, start_state=ref.initial_state(truth))
    ctl = make_controller(args.controller, params, accept_unidentifiable=args.accept_unidentifiable)
    duration = args.duration if args.duration is not None else ref.duration_s
    print(
        f"hmpc drive: {args.controller} on {ref.name} via {profile.name} "
        f"({args.bus}{', vehicle sim' if node else ''}), {duration:.1f} s",
        file=sys.stderr,
    )
    adapter = adapter_for_profile(args, params, profile, "drive")
    loop = DriveLoop(
        profile,
        params,
        ctl,
        ref,
        kw,
        args.candump,
        duration_s=duration,
        faults=faults,
        node=node,
        adapter=adapter,
    )
    import signal

    old = signal.signal(signal.SIGINT, lambda *_: loop.request_stop("interrupted"))
    try:
        res = loop.run()  # Ctrl-C: a controlled stop, as on a lost link
    finally:
        signal.signal(signal.SIGINT, old)
    out = res.summary
    audit = audit_candump(profile, params, args.candump)
    out["limit_violations"] = audit["limit_violations"]
    out["limit_audit"] = audit
    out["faults"] = [{"name": f.name, "t_s": f.t_s} for f in faults]
    st = out["stop"]
    lp = out["loop_period_ms"]
    print(
        f"steps {out['steps']}, loop period p50/p99/max {lp['p50']:.1f}/{lp['p99']:.1f}/"
        f"{lp['max']:.1f} ms, deadline misses {out['deadline_misses']}, frames sent "
        f"{out['frames_sent']}, rejected by vehicle {out['frames_rejected_by_vehicle']}, "
        f"limit violations {out['limit_violations']}, stop {st['reason']} "
        f"({stop_times(st)})"
    )
    if out["speed_error_rms_mps"] is not None:
        print(
            f"speed error RMS {out['speed_error_rms_mps']:.3f} m/s, lateral error RMS "
            f"{out['lateral_error_rms_m']:.3f} m"
        )
    if st["reason"] not in ("duration", "interrupted", "no_feedback", "car_not_accepting"):
        # the run stopped the car by itself: the figures above cover a shorter run
        at = "" if st["detected_t_s"] is None else f" at {st['detected_t_s']:.2f} s"
        print(
            f"hmpc drive: warning: the run stopped the car by itself ({st['reason']}{at}"
            f" of {duration:.1f} s asked; {STOP_WHY.get(st['reason'], 'see stop in the JSON')})",
            file=sys.stderr,
        )
    finish_adapter(args, adapter, "drive", float(out["engaged_s"]))
    write_json(args.json, out)
    if st["reason"] in ("no_feedback", "car_not_accepting"):
        raise InputError(
            f"bus {args.bus}: never engaged: "
            + (
                "no wheel speeds on the bus (is the car, or --vehicle-sim, there?)"
                if st["reason"] == "no_feedback"
                else "the car's status never accepted commands"
            )
        )
    return report_not_followed(out, "drive")
