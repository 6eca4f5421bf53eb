"""How the diagnosis shows numbers to people (the terminal summary and the HTML report): angles
in degrees (the JSON keeps SI: rad, rad/s), values with their intervals, and the order in which
a result is told (the answer first: the verdict and the findings; the evidence below).
"""

from __future__ import annotations

import math

DEG = 180.0 / math.pi
#: the unit of each diagnosed channel in the JSON (SI; the JSON's ``channels``)
CHANNEL_UNITS = {
    "speed": "m/s",
    "accel": "m/s^2",
    "heading": "rad",
    "road_wheel_angle": "rad",
    "position": "m",
    "speed_vs_gnss": "m/s",
    "yaw_rate": "rad/s",
    "accel_vs_speed": "m/s^2",
    "yaw_rate_vs_wheels": "rad/s",
}

#: a unit shown to people -> (the unit shown instead, factor)
_SHOWN = {"rad": ("deg", DEG), "rad/s": ("deg/s", DEG)}


def shown(value: float | None, unit: str) -> tuple[float | None, str]:
    """(value, unit) as shown to people: rad -> deg, rad/s -> deg/s; others unchanged."""
    if unit in _SHOWN:
        u, k = _SHOWN[unit]
        return (None if value is None else value * k), u
    return value, unit


def parameter(name: str) -> tuple[str, str, float]:
    """(name shown, unit shown, factor) of a catalogue parameter: ``*_rad`` in deg,
    ``*_rad_per_mps2`` in deg/(m/s^2), ``*_radps`` in deg/s; others as named (unit '')."""
    for suffix, unit in (("_rad_per_mps2", "deg/(m/s^2)"), ("_radps", "deg/s"), ("_rad", "deg")):
        if name.endswith(suffix):
            return name[: -len(suffix)], unit, DEG
    return name, "", 1.0


#: unit suffixes of catalogue parameter names (``models.params``' convention)
_SUFFIX_UNITS = (
    ("_mps2", "m/s^2"),
    ("_mps", "m/s"),
    ("_per_m", "1/m"),
    ("_per_s", "1/s"),
    ("_s", "s"),
)


def unit_of(name: str) -> str:
    """The unit a catalogue parameter is shown in (its name's suffix; angles in deg)."""
    nm, unit, _ = parameter(name)
    if unit:
        return unit
    return next((u for suffix, u in _SUFFIX_UNITS if name.endswith(suffix)), "1")


def value_with_interval(name: str, value: float, interval=None) -> str:
    """``name value [lo, hi] unit`` as shown to people (see :func:`parameter`)."""
    nm, unit, k = parameter(name)
    text = f"{nm} {value * k:.4g}"
    if interval is not None:
        text += f" [{interval[0] * k:.4g}, {interval[1] * k:.4g}]"
    return text + (f" {unit}" if unit else "")


def number(value: float | None, unit: str, fmt: str = ".4g") -> str:
    """A channel's value in the unit shown to people (``n/a`` for None)."""
    v, u = shown(value, unit)
    return "n/a" if v is None else f"{v:{fmt}} {u}"
