"""Operator command sources and the operator station's send loop.

A source answers ``command_at(t_s)`` (t_s: run time since the start [s]) with the
``TeleopCommand`` to send in that period, or None when it has finished. Sources:

- :class:`Script`: a scripted operator, loaded from CSV (:func:`load_script`) or built from
  sampled driver inputs (:func:`inputs_script`; ``hmpc operator --experiment`` feeds it the
  simulator's driver on one of the report's experiments);
- :class:`KeyboardOperator`: keys from the terminal (``tui.TerminalKeys``);
- :class:`GamepadOperator`: a Linux joystick device (``/dev/input/js*``).

:func:`run_operator` sends one command per period (50 Hz), reads telemetry and calls back the
UI; when the source ends, the duration is up or the run is interrupted, it sends a
``disengage`` with the dead-man released for ``END_PACKETS`` periods, so the vehicle stops at
once rather than after the 200 ms link timeout.

Script CSV (``--script OPS.csv``): comma-separated with a header; lines starting with ``#``
are comments. Columns:

    t_s                        time from the start [s]; the first row at 0, strictly increasing
    mode                       pedals | references | engage | disengage | handover_mpc | take_over
    dead_man                   1 held, 0 released
    steering_wheel_angle_rad   pedals rows: steering-wheel angle [rad], left positive
    accel_pedal, brake_pedal   pedals rows: pedal fractions 0..1
    speed_mps, curvature_1pm   references rows: speed [m/s] and path curvature [1/m], left +

``t_s``, ``mode`` and ``dead_man`` are required; a value column is required when a row of its
mode exists, and its cells may be empty only in rows of other modes. Unknown columns are an
error. Each row holds until the next row's time (zero-order hold); the last row holds for
``LAST_ROW_HOLD_S`` and then the script ends. Values pass through the vehicle's limits there
(the same ``apply_limits`` as the MPC's commands); the script is not clamped here.
"""

from __future__ import annotations

import csv
import glob
import math
import os
import struct
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Protocol, cast
from collections.abc import Callable

import numpy as np

from hmpc.controller.teleop.link import Mode, OperatorLink, TeleopCommand, Telemetry
from hmpc.models.errors import InputError

#: operator send rate: 50 Hz, ten packets inside the vehicle's 200 ms link timeout
RATE_HZ = 50.0
#: the last script row is sent for this long [s] (five periods: one lost packet is harmless)
LAST_ROW_HOLD_S = 0.1
#: packets of ``disengage`` with the dead-man released sent when a run ends
END_PACKETS = 5
#: a built-in experiment starts with this much ``engage`` [s] (five packets)
ENGAGE_LEAD_S = 0.1

MODE_NAMES = {
    "pedals": Mode.PEDALS,
    "references": Mode.REFERENCES,
    "engage": Mode.ENGAGE,
    "disengage": Mode.DISENGAGE,
    "handover_mpc": Mode.HANDOVER_MPC,
    "take_over": Mode.TAKE_OVER,
}
_NAME_OF = {m: n for n, m in MODE_NAMES.items()}
_VALUE_COLS = {
    Mode.PEDALS: ("steering_wheel_angle_rad", "accel_pedal", "brake_pedal"),
    Mode.REFERENCES: ("speed_mps", "curvature_1pm"),
}
COLUMNS = (
    "t_s",
    "mode",
    "dead_man",
    "steering_wheel_angle_rad",
    "accel_pedal",
    "brake_pedal",
    "speed_mps",
    "curvature_1pm",
)
REQUIRED = ("t_s", "mode", "dead_man")


class Source(Protocol):
    """What ``run_operator`` reads commands from."""

    def command_at(self, t_s: float) -> TeleopCommand | None: ...


# ------------------------------------------------------------------------------ scripts
@dataclass
class Script:
    """Timed commands held until the next one (module docstring).

    Attributes:
        times_s: row times [s], the first 0, strictly increasing.
        commands: one ``TeleopCommand`` per row.
        name: where it came from (file name or ``experiment:NAME``).
        meta: provenance (experiment, seed, parameter file).
    """

    times_s: np.ndarray
    commands: list[TeleopCommand]
    name: str = "script"
    meta: dict = field(default_factory=dict)

    def __post_init__(self):
        t = np.asarray(self.times_s, dtype=float)
        if len(t) == 0 or len(t) != len(self.commands):
            raise ValueError("a script needs one time per command and at least one row")
        if t[0] != 0.0 or np.any(np.diff(t) <= 0) or not np.all(np.isfinite(t)):
            raise ValueError("script times must start at 0 and increase strictly")
        self.times_s = t

    @property
    def end_s(self) -> float:
        """The run time at which the script has finished [s]."""
        return float(self.times_s[-1]) + LAST_ROW_HOLD_S

    def command_at(self, t_s: float) -> TeleopCommand | None:
        if t_s >= self.end_s - 1e-9:
            return None
        i = int(np.searchsorted(self.times_s, t_s + 1e-9, side="right")) - 1
        return self.commands[max(i, 0)]


def load_script(path: str | Path) -> Script:
    """Read a script CSV (module docstring). Raises InputError naming the file and line."""
    p = str(path)
    try:
        fh = open(p, newline="", encoding="utf-8")
    except OSError as exc:
        raise InputError(f"cannot read script: {exc.strerror}", p) from None
    with fh:
        lines = [
            (i, ln)
            for i, ln in enumerate(fh, start=1)
            if ln.strip() and not ln.lstrip().startswith("#")
        ]
    if not lines:
        raise InputError("script is empty (needs a header and rows)", p)
    header_line, header = lines[0]
    cols = [c.strip() for c in next(csv.reader([header]))]
    for c in cols:
        if c not in COLUMNS:
            raise InputError(
                f"unknown column '{c}' (known: {', '.join(COLUMNS)})", p, line=header_line
            )
    for c in REQUIRED:
        if c not in cols:
            raise InputError(f"missing column '{c}'", p, line=header_line)
    if len(set(cols)) != len(cols):
        raise InputError("a column appears twice", p, line=header_line)
    times: list[float] = []
    cmds: list[TeleopCommand] = []
    for lineno, text in lines[1:]:
        cells = [c.strip() for c in next(csv.reader([text]))]
        if len(cells) != len(cols):
            raise InputError(f"{len(cells)} cells, the header has {len(cols)}", p, line=lineno)
        row = dict(zip(cols, cells))
        t = _num(row["t_s"], p, lineno, "t_s")
        mode = MODE_NAMES.get(row["mode"])
        if mode is None:
            raise InputError(
                f"unknown mode '{row['mode']}' (known: {', '.join(MODE_NAMES)})", p, line=lineno
            )
        if row["dead_man"] not in ("0", "1"):
            raise InputError(f"dead_man must be 0 or 1, got '{row['dead_man']}'", p, line=lineno)
        vals = []
        for c in _VALUE_COLS.get(mode, ()):
            if c not in row:
                raise InputError(f"a {row['mode']} row needs column '{c}'", p, line=lineno)
            vals.append(_num(row[c], p, lineno, c))
        vals = (vals + [0.0, 0.0, 0.0])[:3]
        if times and t <= times[-1]:
            raise InputError(
                f"t_s {t:g} does not increase (previous {times[-1]:g})", p, line=lineno
            )
        if not times and t != 0.0:
            raise InputError(f"the first row must be at t_s 0, got {t:g}", p, line=lineno)
        times.append(t)
        three = cast("tuple[float, float, float]", tuple(vals))  # padded to three above
        cmds.append(TeleopCommand(mode, three, row["dead_man"] == "1"))
    if not times:
        raise InputError("script has a header but no rows", p)
    return Script(np.array(times), cmds, name=os.path.basename(p))


def _num(text: str, path: str, line: int, col: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise InputError(f"column '{col}': '{text}' is not a number", path, line=line) from None
    if not math.isfinite(v):
        raise InputError(f"column '{col}': '{text}' is not finite", path, line=line)
    return v


def write_script(script: Script, path: str | Path) -> None:
    """Write ``script`` as a script CSV that :func:`load_script` reads back unchanged."""
    with open(path, "w", newline="", encoding="utf-8") as fh:
        fh.write(f"# hmpc operator script: {script.name}\n")
        w = csv.writer(fh, lineterminator="\n")
        w.writerow(COLUMNS)
        for t, c in zip(script.times_s, script.commands):
            row = {
                "t_s": repr(float(t)),
                "mode": _NAME_OF[c.mode],
                "dead_man": "1" if c.dead_man else "0",
            }
            for col, v in zip(_VALUE_COLS.get(c.mode, ()), c.values):
                row[col] = repr(float(v))
            w.writerow([row.get(col, "") for col in COLUMNS])


def inputs_script(
    time_s,
    steering_wheel_angle_rad,
    accel_pedal,
    brake_pedal,
    *,
    name: str,
    meta: dict | None = None,
    rate_hz: float = RATE_HZ,
) -> Script:
    """A pedals-and-steering script from sampled driver inputs, after ``ENGAGE_LEAD_S`` of
    ``engage`` and ending with ``disengage``.

    Args:
        time_s: sample times [s], uniform at ``rate_hz`` [Hz].
        steering_wheel_angle_rad: steering-wheel angle at those times [rad].
        accel_pedal: accelerator pedal at those times [0..1].
        brake_pedal: brake pedal at those times [0..1].
        name: the script's name.
        meta: what the script holds (echoed in its ``meta``, with its ``duration_s`` added).
        rate_hz: the script's rate [Hz].
    """
    t = np.asarray(time_s, dtype=float)
    cmds = [TeleopCommand(Mode.ENGAGE)]
    cmds += [
        TeleopCommand.pedals(a, b, c)
        for a, b, c in zip(steering_wheel_angle_rad, accel_pedal, brake_pedal)
    ]
    cmds.append(TeleopCommand(Mode.DISENGAGE))
    dt = 1.0 / rate_hz
    times = np.concatenate([[0.0], ENGAGE_LEAD_S + (t - t[0]), [ENGAGE_LEAD_S + t[-1] - t[0] + dt]])
    return Script(
        times,
        cmds,
        name=name,
        meta={**(meta or {}), "duration_s": float(times[-1] + LAST_ROW_HOLD_S)},
    )


# ----------------------------------------------------------------------------- keyboard
@dataclass(frozen=True)
class KeyboardConfig:
    """Key steps (units in the names)."""

    # 0.1 rad of steering-wheel angle per key press: with the report's scale 0.08 that is
    # 0.008 rad at the road wheel, fine enough to hold a lane at 5 m/s.
    steer_step_rad: float = 0.1
    # Steering-wheel range reachable by keys: +-7.85 rad, the report's +-2.5*pi (the vehicle
    # side clamps again with its own limits).
    steer_max_rad: float = 2.5 * math.pi
    # 5 % of pedal travel per key press: 20 presses from released to floored.
    pedal_step: float = 0.05
    # Mode packets (engage, hand over, take over, disengage) are repeated for this many
    # periods so one lost packet does not lose the request.
    mode_repeats: int = 3


class KeyboardOperator:
    """Pedals and steering from keys (``handle_key``), sent every period.

    A terminal reports key presses, never releases, so the keyboard's dead-man is a latch:
    ``e`` engages (dead-man held), space or Escape releases it (the car stops) and resets the
    pedals. Keys: up/w more throttle (or less brake), down/s more brake (or less throttle),
    left/a and right/d steer, c centre the wheel, x release both pedals, m hand over to the
    MPC, t take over, q quit (disengage).
    """

    KEYS = {
        "up": "up",
        "w": "up",
        "down": "down",
        "s": "down",
        "left": "left",
        "a": "left",
        "right": "right",
        "d": "right",
        "c": "centre",
        "x": "release",
        "e": "engage",
        " ": "dead_man_release",
        "esc": "dead_man_release",
        "m": "handover_mpc",
        "t": "take_over",
        "q": "quit",
    }

    def __init__(self, config: KeyboardConfig | None = None):
        self.config = config or KeyboardConfig()
        self.sw_rad = 0.0
        self.accel = 0.0
        self.brake = 0.0
        self.dead_man = False
        self.quit = False
        self._pending: list[TeleopCommand] = []
        self.last_action = ""

    def handle_key(self, key: str) -> str | None:
        """Apply one key (a name from ``tui.TerminalKeys``); return the action or None."""
        action = self.KEYS.get(key)
        if action is None:
            return None
        c = self.config
        if action == "up":
            if self.brake > 0:
                self.brake = max(self.brake - c.pedal_step, 0.0)
            else:
                self.accel = min(self.accel + c.pedal_step, 1.0)
        elif action == "down":
            if self.accel > 0:
                self.accel = max(self.accel - c.pedal_step, 0.0)
            else:
                self.brake = min(self.brake + c.pedal_step, 1.0)
        elif action == "left":
            self.sw_rad = min(self.sw_rad + c.steer_step_rad, c.steer_max_rad)
        elif action == "right":
            self.sw_rad = max(self.sw_rad - c.steer_step_rad, -c.steer_max_rad)
        elif action == "centre":
            self.sw_rad = 0.0
        elif action == "release":
            self.accel = self.brake = 0.0
        elif action == "engage":
            self.dead_man = True
            self.accel = self.brake = 0.0
            self._pending = [TeleopCommand(Mode.ENGAGE)] * c.mode_repeats
        elif action == "dead_man_release":
            self.dead_man = False
            self.accel = self.brake = 0.0
        elif action in ("handover_mpc", "take_over"):
            self._pending = [
                TeleopCommand(MODE_NAMES[action], dead_man=self.dead_man)
            ] * c.mode_repeats
        elif action == "quit":
            self.quit = True
        self.sw_rad = round(self.sw_rad, 9)
        self.accel, self.brake = round(self.accel, 9), round(self.brake, 9)
        self.last_action = action
        return action

    def command_at(self, t_s: float) -> TeleopCommand | None:
        if self.quit:
            return None
        if self._pending:
            return self._pending.pop()
        return TeleopCommand.pedals(self.sw_rad, self.accel, self.brake, dead_man=self.dead_man)


# ------------------------------------------------------------------------------ gamepad
class NoGamepadError(InputError):
    """No joystick device is attached."""


#: Linux joystick API event (linux/joystick.h): time [ms] u32, value s16, type u8, number u8
_JS_EVENT = struct.Struct("<IhBB")
_JS_BUTTON, _JS_AXIS, _JS_INIT = 0x01, 0x02, 0x80


def find_gamepad(pattern: str = "/dev/input/js*") -> str:
    """The first joystick device; NoGamepadError when none is attached."""
    devs = sorted(glob.glob(pattern))
    if not devs:
        raise NoGamepadError("no gamepad found (no /dev/input/js* device)")
    return devs[0]


@dataclass(frozen=True)
class GamepadConfig:
    """Mapping of an Xbox-layout pad under the Linux ``xpad`` driver (axis and button numbers)."""

    steer_axis: int = 0  # left stick x: full left = +steer_max_rad
    throttle_axis: int = 5  # right trigger, -32767 released .. 32767 pulled
    brake_axis: int = 2  # left trigger
    dead_man_button: int = 5  # right bumper: held = dead-man held (a real dead-man switch)
    engage_button: int = 7  # start
    handover_button: int = 3  # Y
    take_over_button: int = 2  # X
    # steering-wheel angle at full stick [rad]: a quarter of the report's +-2.5*pi, so the
    # stick's resolution stays useful; the vehicle side clamps to its own limits
    steer_max_rad: float = 0.625 * math.pi


class GamepadOperator:
    """Pedals and steering from a joystick device; feed it events with ``handle_event``."""

    def __init__(self, config: GamepadConfig | None = None):
        self.config = config or GamepadConfig()
        self.sw_rad = 0.0
        self.accel = 0.0
        self.brake = 0.0
        self.dead_man = False
        self._pending: list[TeleopCommand] = []

    def handle_event(self, data: bytes) -> None:
        """Apply one 8-byte ``js_event``."""
        _, value, etype, number = _JS_EVENT.unpack(data)
        etype &= ~_JS_INIT
        c = self.config
        if etype == _JS_AXIS:
            x = max(min(value / 32767.0, 1.0), -1.0)
            if number == c.steer_axis:
                self.sw_rad = -x * c.steer_max_rad  # stick right (positive) = steer right
            elif number == c.throttle_axis:
                self.accel = (x + 1.0) / 2.0
            elif number == c.brake_axis:
                self.brake = (x + 1.0) / 2.0
        elif etype == _JS_BUTTON:
            pressed = value != 0
            if number == c.dead_man_button:
                self.dead_man = pressed
            elif pressed and number == c.engage_button:
                self._pending = [TeleopCommand(Mode.ENGAGE)] * 3
            elif pressed and number == c.handover_button:
                self._pending = [TeleopCommand(Mode.HANDOVER_MPC)] * 3
            elif pressed and number == c.take_over_button:
                self._pending = [TeleopCommand(Mode.TAKE_OVER)] * 3

    def read_events(self, fd: int) -> None:
        """Apply every event waiting on the (non-blocking) device ``fd``."""
        while True:
            try:
                data = os.read(fd, _JS_EVENT.size * 64)
            except BlockingIOError:
                return
            if not data:
                return
            for i in range(0, len(data) - _JS_EVENT.size + 1, _JS_EVENT.size):
                self.handle_event(data[i : i + _JS_EVENT.size])

    def command_at(self, t_s: float) -> TeleopCommand | None:
        if self._pending and self.dead_man:
            return self._pending.pop()
        return TeleopCommand.pedals(self.sw_rad, self.accel, self.brake, dead_man=self.dead_man)


# --------------------------------------------------------------------------------- loop
@dataclass
class RunSummary:
    """What a run of the operator station did (``--json``)."""

    end: str
    duration_s: float
    sent: int
    telemetry_received: int
    telemetry_rejected: int
    last_telemetry: Telemetry | None

    def to_dict(self) -> dict:
        tel = self.last_telemetry
        out = {
            "end": self.end,
            "duration_s": round(self.duration_s, 3),
            "sent": self.sent,
            "telemetry_received": self.telemetry_received,
            "telemetry_rejected": self.telemetry_rejected,
            "vehicle": None,
            "link": None,
            "stop": None,
        }
        if tel is not None:
            v = tel.vehicle
            out["vehicle"] = {
                "speed_mps": _f(v.speed_mps),
                "steering_wheel_angle_rad": _f(v.steering_wheel_angle_rad),
                "zone": v.zone_name or None,
                "pedal_mode": v.pedal_mode or None,
                "engaged": tel.engaged,
                "mpc_in_control": tel.mpc_in_control,
            }
            out["link"] = {
                "received": tel.received,
                "accepted": tel.accepted,
                "delivered": tel.delivered,
                "rejected": tel.rejected,
                "lost": tel.lost,
                "latency_ms": {"p50": _f(tel.latency_p50_ms), "p99": _f(tel.latency_p99_ms)},
                "max_gap_ms": _f(tel.max_gap_ms),
            }
            out["stop"] = None if tel.stop is None else tel.stop.to_dict()
        return out


def _f(x: float):
    return None if x is None or not math.isfinite(x) else round(float(x), 6)


def run_operator(
    source: Source,
    link: OperatorLink,
    *,
    rate_hz: float = RATE_HZ,
    duration_s: float | None = None,
    clock: Callable[[], float] = time.monotonic,
    sleep: Callable[[float], None] = time.sleep,
    on_tick: Callable[[float, TeleopCommand, Telemetry | None], None] | None = None,
    before_tick: Callable[[], None] | None = None,
) -> RunSummary:
    """Send ``source``'s command every period until it ends, ``duration_s`` passes or the
    user interrupts; then send the end packets. Pacing uses ``clock``/``sleep`` (absolute
    deadlines, no drift; a late period is not made up). ``before_tick`` reads inputs (keys);
    ``on_tick(t_s, command, telemetry)`` updates the UI.
    """
    if not (rate_hz > 0 and math.isfinite(rate_hz)):
        raise ValueError("rate_hz must be positive")
    period = 1.0 / rate_hz
    t0 = clock()
    k = 0
    end = "source_finished"
    t = 0.0
    try:
        while True:
            t = k * period
            if duration_s is not None and t >= duration_s - 1e-9:
                end = "duration"
                break
            if before_tick is not None:
                before_tick()
            cmd = source.command_at(t)
            if cmd is None:
                if getattr(source, "quit", False):
                    end = "quit"
                break
            link.send(cmd)
            tel = link.poll_telemetry()
            if on_tick is not None:
                on_tick(t, cmd, tel)
            k += 1
            next_t = t0 + k * period
            now = clock()
            if now > next_t + period:  # fell behind: skip, never send a burst to catch up
                k = int((now - t0) / period)
                next_t = t0 + k * period
            sleep(max(next_t - clock(), 0.0))
    except KeyboardInterrupt:
        end = "interrupted"
    finally:
        stop = TeleopCommand(Mode.DISENGAGE, dead_man=False)
        for _ in range(END_PACKETS):
            link.send(stop)
            sleep(period)
        link.poll_telemetry()
    return RunSummary(
        end, t, link.sent, link.telemetry_received, link.telemetry_rejected, link.telemetry
    )
