"""``hmpc teleop``: the vehicle side of tele-operation (controller/teleop/vehicle.py).

    hmpc teleop --params P.yaml --actuation A.yaml --key KEYFILE [--listen HOST:PORT]
                [--bus virtual|socketcan:CHANNEL] [--vehicle-sim [--plant-params P2.yaml]]
                [--controller mpc|nmpc|pid] [--scenario NAME | --reference REF.csv]
                [--duration S] --candump RUN.log [--json OUT.json]

``hmpc drive``'s real-time loop with the authenticated operator link as its command source:
the loop engages when the operator's ``engage`` arrives (and the car accepts commands), passes
the operator's pedals and steering-wheel angle through the same limits and encoders as the
MPC's commands, hands over to ``--controller`` on the operator's ``handover_mpc`` (following
``--scenario``/``--reference`` re-anchored on the car; default: a standstill reference, i.e.
the controller brings the car to a stop and holds it) and back on ``take_over``. A lost link
(no valid packet for 200 ms), a released dead-man or the operator's ``disengage`` end the run
with the drive loop's controlled stop. ``--duration`` ends the run after S seconds of run time
(default: until interrupted; Ctrl-C stops the car as on a lost link).

JSON: the ``hmpc drive`` keys (``stop`` {reason, t_s, detected_t_s, standstill_t_s},
``limit_violations``, ``frames_rejected_by_vehicle``, ...; the tracking KPIs are null: the
operator, not a reference, sets the course) plus ``link``: ``accepted``, ``rejected``
{reason: count}, ``rejected_total``, ``latency_ms`` {p50, p99} (operator send to vehicle read),
``gaps`` {count, max_ms, lost_packets}, ``steps`` by source, ``handovers``, ``take_overs`` and
the link's ``stop`` event on the loop's clock. Exit status: 0 (also when the operator never
engaged: ``engaged_s`` 0), 2 bad input (key file refused, address in use, no car on the bus),
1 internal failure.
"""

from __future__ import annotations

import math
import sys

import numpy as np

from hmpc.models.errors import InputError
from hmpc.controller.build import make_controller
from hmpc.models.reference import load_reference
from hmpc.tools.common import (
    CONTROLLERS,
    adapter_for_profile,
    add_adapt_arguments,
    add_bus_arguments,
    bus_kwargs,
    finish_adapter,
    load_model_params,
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
    p.add_argument(
        "--key",
        required=True,
        metavar="KEYFILE",
        help="pre-shared key file: one line of hex, >= 32 bytes, mode 0600",
    )
    p.add_argument(
        "--listen",
        default="127.0.0.1:47700",
        metavar="HOST:PORT",
        help="where the operator's packets arrive (default 127.0.0.1:47700)",
    )
    add_bus_arguments(p)
    p.add_argument(
        "--controller",
        choices=CONTROLLERS,
        default="mpc",
        help="who drives after a handover and follows reference commands (default mpc)",
    )
    what = p.add_mutually_exclusive_group()
    what.add_argument(
        "--scenario",
        metavar="NAME",
        help="the reference a handover follows (figure8, ramp_sequence, ...)",
    )
    what.add_argument(
        "--reference",
        metavar="REF.csv",
        help="a reference CSV or a canonical recording, for handovers",
    )
    p.add_argument(
        "--duration",
        type=float,
        metavar="S",
        help="end the run after S seconds of run time (default: until interrupted)",
    )
    p.add_argument(
        "--candump",
        required=True,
        metavar="RUN.log",
        help="write every frame sent and received here (candump -L)",
    )
    p.add_argument("--json", metavar="FILE", help="write the run's figures as JSON")
    add_adapt_arguments(p)


def standstill_reference():
    """The default handover reference: stand still where the car is."""
    from hmpc.models.reference import Reference

    t = np.array([0.0, 10.0])
    z = np.zeros(2)
    return Reference(t, z, z, z, z, name="standstill")


def run(args) -> int:
    from hmpc.controller.actuation.candump import audit_candump
    from hmpc.controller.actuation.drive import DriveLoop
    from hmpc.controller.actuation.profiles import load_profile
    from hmpc.controller.actuation.vehicle_node import VehicleNode
    from hmpc.controller.teleop import link as L
    from hmpc.controller.teleop.vehicle import TeleopController, handover_config
    from hmpc.models.sim.scenarios import make_scenario

    key = L.load_key(args.key)  # first: a refused key stops everything
    params = load_model_params(args.params, args, "teleop")
    profile = load_profile(args.actuation)
    if args.plant_params and not args.vehicle_sim:
        raise InputError("--plant-params belongs to --vehicle-sim")
    if args.duration is not None and not args.duration > 0:
        raise InputError("--duration must be > 0")
    truth = load_model_params(args.plant_params, args, "teleop") if args.plant_params else params
    if args.scenario is not None:
        ref = make_scenario(args.scenario, params)
    elif args.reference is not None:
        ref = load_reference(args.reference, params)
    else:
        ref = standstill_reference()
    try:
        addr = L.parse_address(args.listen)
        rx = L.LinkReceiver(key, addr)
    except (ValueError, OSError) as exc:
        raise InputError(
            f"--listen {args.listen}: cannot listen there (expected HOST:PORT of "
            f"this machine, e.g. 127.0.0.1:47700; {exc})"
        ) from None
    try:
        kw = bus_kwargs(args.bus)
        node = (
            VehicleNode(profile, truth, kw, start_state=ref.initial_state(truth))
            if args.vehicle_sim
            else None
        )
        ctl = make_controller(
            args.controller, params, accept_unidentifiable=args.accept_unidentifiable
        )
        cfg = getattr(ctl, "config", None)
        if hasattr(cfg, "cold_start_iterations"):  # MPC/NMPC: a cheaper first plan
            ctl = type(ctl)(params, handover_config(cfg))
        src = TeleopController(rx, params, ctl, run_s=args.duration)
        print(
            f"hmpc teleop: listening on {rx.address[0]}:{rx.address[1]}, {profile.name} on "
            f"{args.bus}{' (vehicle sim)' if node else ''}, handover to {args.controller} on "
            f"{ref.name}",
            file=sys.stderr,
        )
        adapter = adapter_for_profile(args, params, profile, "teleop")
        loop = DriveLoop(
            profile,
            params,
            src,
            ref,
            kw,
            args.candump,
            duration_s=math.inf,
            node=node,
            adapter=adapter,
        )
        import signal

        old = signal.signal(signal.SIGINT, lambda *_: loop.request_stop("interrupted"))
        try:
            res = loop.run()
        finally:
            signal.signal(signal.SIGINT, old)
    finally:
        rx.close()
    out = finish_summary(res.summary, src, audit_candump(profile, params, args.candump))
    finish_adapter(args, adapter, "teleop", float(out["engaged_s"]))
    write_json(args.json, out)
    st, lk = out["stop"], out["link"]
    print(
        f"hmpc teleop: engaged {out['engaged_s']:.1f} s, stop {st['reason']} "
        f"({stop_times(st)}); link "
        f"accepted {lk['accepted']}, rejected {lk['rejected_total']}, latency p50/p99 "
        f"{lk['latency_ms']['p50']}/{lk['latency_ms']['p99']} ms; frames sent "
        f"{out['frames_sent']}, limit violations {out['limit_violations']}",
        file=sys.stderr,
    )
    if st["reason"] in ("no_feedback", "car_not_accepting"):
        raise InputError(
            f"bus {args.bus}: never engaged: "
            + (
                "no wheel speeds on the bus (is the car, or --vehicle-sim, there?)"
                if st["reason"] == "no_feedback"
                else "the car's status never accepted commands"
            )
        )
    return 0


def finish_summary(summary: dict, src, audit: dict) -> dict:
    """The drive JSON of a teleop run: the candump audit, no tracking KPIs, the ``link``."""
    out = dict(summary)
    out["limit_violations"] = audit["limit_violations"]
    out["limit_audit"] = audit
    out["speed_error_rms_mps"] = None  # the operator sets the course, not the reference
    out["lateral_error_rms_m"] = None
    out["link"] = src.stats()
    return out
