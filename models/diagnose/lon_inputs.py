"""What drives the longitudinal model: the recorded inputs, chosen from what the recording
holds, and how a command enters eq. 8.

- An acceleration request (``accel_cmd``) or a speed command (``speed_cmd``) that moves drives
  the car when recorded (a by-wire or ACC car); a driver's pedal that moved is kept beside it.
  Else the pedals the recording holds drive it (``accel_pedal``, ``brake_pedal``: each only
  when recorded).
- An input the recording does not hold is absent (:class:`InputChoice` ``absent``): no column
  of zeros stands for it, and no model fills it in; a deceleration no recorded input explains
  is a hypothesis of its own (``unobserved_braking``, ``models.diagnose.braking``).
- A speed command enters eq. 8 as the speed error it asks to close:
  ``dv/dt = offset_z + k_z * (speed_cmd(t - d) - v)`` (:func:`regressors`), the command through
  the actuator hypotheses (dead time, lag), the speed the car's own; ``actuator_saturation``
  clips each command's regressor at a level (:func:`regressors`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from hmpc.models.errors import InputError

#: the canonical channels that can drive the longitudinal model, commands first
LON_INPUTS = ("accel_cmd", "speed_cmd", "accel_pedal", "brake_pedal")
#: commands: what a by-wire controller or an ACC follows
COMMANDS = ("accel_cmd", "speed_cmd")
#: [unit of the command] spread below which a command does not drive the recording: 0.1 m/s^2
#: of request or 0.1 m/s of speed command is below any deliberate change (a held constant)
COMMAND_MIN_STD = 0.1
#: an input whose magnitude never exceeds this is not used (pedal fractions, m/s^2 requests:
#: 0.01 is below any deliberate actuation)
INPUT_USED = 0.01


@dataclass
class InputChoice:
    """The inputs chosen for eq. 8 and what the recording does not hold."""

    U: np.ndarray  #: [n, m] inputs (brake as -brake_pedal; NaN where missing)
    names: list[str]  #: the channel of each column
    idle: np.ndarray  #: throttle released (bool; all False without accel_pedal)
    absent: list[str]  #: input channels the recording does not hold
    notes: list[str] = field(default_factory=list)

    @property
    def tracking(self) -> np.ndarray:
        """Per column: a speed command (its regressor is the speed error it asks to close)."""
        return np.array([nm == "speed_cmd" for nm in self.names], bool)


def _recorded(ch: dict, name: str) -> np.ndarray | None:
    x = ch.get(name)
    if x is None:
        return None
    x = np.asarray(x, float)
    return x if np.isfinite(x).any() else None


def _drives(x: np.ndarray | None) -> bool:
    return x is not None and np.isfinite(x).mean() > 0.5 and float(np.nanstd(x)) > COMMAND_MIN_STD


def _moved(x: np.ndarray | None) -> bool:
    return x is not None and float(np.nanmax(np.abs(x))) > INPUT_USED


def absent_inputs(ch: dict) -> list[str]:
    """The longitudinal input channels the recording does not hold (no finite sample)."""
    return [nm for nm in LON_INPUTS if _recorded(ch, nm) is None]


def choose_inputs(ch: dict) -> InputChoice:
    """The recorded inputs that drive eq. 8 (module doc).

    Raises:
        InputError: the recording holds no longitudinal input at all."""
    n = len(np.asarray(ch["time"]))
    rec: dict[str, Any] = {nm: _recorded(ch, nm) for nm in LON_INPUTS}  # None: absent
    absent = [nm for nm in LON_INPUTS if rec[nm] is None]
    notes = []
    cmd = next((nm for nm in COMMANDS if _drives(rec[nm])), None)
    if cmd is not None:
        # an ACC's request drives the car while engaged: NaN while it is off is the driver's
        # time (0 request); a speed command's gaps stay gaps (no speed is asked for there)
        cols = [np.nan_to_num(rec[cmd], nan=0.0) if cmd == "accel_cmd" else rec[cmd]]
        names = [cmd]
        for nm, sign in (("accel_pedal", 1.0), ("brake_pedal", -1.0)):
            if _moved(rec[nm]):
                x = rec[nm] if cmd == "speed_cmd" else np.nan_to_num(rec[nm], nan=0.0)
                cols.append(sign * x)
                names.append(nm)
        other = [nm for nm in COMMANDS if nm != cmd and rec[nm] is not None]
        notes += [f"{nm} recorded but not used: {cmd} drives the car" for nm in other]
        return InputChoice(np.column_stack(cols), names, np.zeros(n, bool), absent, notes)
    notes += [
        f"{nm} recorded but held constant (spread below {COMMAND_MIN_STD:g}): not used"
        for nm in COMMANDS
        if rec[nm] is not None
    ]
    cols, names = [], []
    for nm, sign in (("accel_pedal", 1.0), ("brake_pedal", -1.0)):
        if rec[nm] is not None:
            cols.append(sign * rec[nm])
            names.append(nm)
    if not names:
        raise InputError("no longitudinal input: none of " + ", ".join(LON_INPUTS) + " is recorded")
    ap = rec["accel_pedal"]
    idle = np.zeros(n, bool) if ap is None else np.nan_to_num(ap, nan=1.0) < INPUT_USED
    return InputChoice(np.column_stack(cols), names, idle, absent, notes)


def regressors(
    U: np.ndarray,
    tracking: np.ndarray,
    v: np.ndarray,
    sat_level: float = 0.0,
    commands: np.ndarray | None = None,
) -> np.ndarray:
    """The inputs as eq. 8's regressors at speed ``v``: a speed command's column becomes the
    speed error ``speed_cmd - v``; with ``sat_level`` > 0 each command's regressor
    (``commands``: per column) is clipped to +-``sat_level`` (``actuator_saturation``)."""
    if not tracking.any() and (sat_level <= 0 or commands is None or not commands.any()):
        return U
    R = np.array(U, float, copy=True)
    R[:, tracking] = R[:, tracking] - np.asarray(v, float)[:, None]
    if sat_level > 0 and commands is not None:
        R[:, commands] = np.clip(R[:, commands], -sat_level, sat_level)
    return R
