"""Injected faults of the drive loop (``--fault NAME@T_S``): which there are, how long each
lasts, and which act on the car (the vehicle simulator node) rather than in the loop.

The loop asks :func:`fault_active` where a fault would strike (the bus send, the bus read, the
clock, the solve); the node-side faults are scheduled on the node before the run
(:func:`schedule_node_faults`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from hmpc.models.errors import InputError

#: injectable faults (``--fault NAME@T_S``)
FAULTS = (
    "feedback_loss",
    "clock_freeze",
    "solver_failure",
    "bus_error",
    "driver_override",
    "vehicle_rejects",
)
#: how long a transient injected fault lasts [s] (the controlled stop is latched)
FAULT_WINDOW_S = {
    "feedback_loss": 1.0,
    "clock_freeze": 0.5,
    "bus_error": 0.015,
    "driver_override": 1.0,
    "vehicle_rejects": 0.3,
}
#: faults that act on the car: the vehicle simulator node plays them
NODE_FAULTS = ("driver_override", "vehicle_rejects")


@dataclass(frozen=True)
class Fault:
    name: str
    t_s: float


def parse_fault(text: str) -> Fault:
    """``NAME@T_S`` -> Fault. Raises InputError naming the text."""
    name, sep, t = str(text).partition("@")
    if not sep or name not in FAULTS:
        raise InputError(
            f"--fault '{text}': expected NAME@T_S with NAME one of {', '.join(FAULTS)}"
        )
    try:
        ts = float(t)
    except ValueError:
        raise InputError(f"--fault '{text}': '{t}' is not a time in seconds") from None
    if not (math.isfinite(ts) and ts >= 0):
        raise InputError(f"--fault '{text}': time must be >= 0")
    return Fault(name, ts)


def check_node_faults(faults: list[Fault], node) -> None:
    """Raise InputError if a fault that acts on the car is asked for without the node."""
    if any(f.name in NODE_FAULTS for f in faults) and node is None:
        raise InputError(
            "faults driver_override and vehicle_rejects act on the car: they need "
            "the vehicle simulator node (--vehicle-sim)"
        )


def fault_active(faults: list[Fault], name: str, t: float) -> bool:
    """Whether fault ``name`` strikes at loop time ``t`` [s]: from its time on, for its window."""
    for f in faults:
        if (
            f.name == name
            and t >= f.t_s
            and (name not in FAULT_WINDOW_S or t < f.t_s + FAULT_WINDOW_S[name])
        ):
            return True
    return False


def fault_time(faults: list[Fault], name: str):
    """The time [s] of the first fault ``name``, or None."""
    return next((f.t_s for f in faults if f.name == name), None)


def schedule_node_faults(node, faults: list[Fault]) -> None:
    """Schedule the faults that act on the car on the (started) vehicle simulator node."""
    if fault_time(faults, "driver_override") is not None:
        node.driver_steers(fault_time(faults, "driver_override"), FAULT_WINDOW_S["driver_override"])
    if fault_time(faults, "vehicle_rejects") is not None:
        node.reject_commands(
            fault_time(faults, "vehicle_rejects"), FAULT_WINDOW_S["vehicle_rejects"]
        )
