"""Actuation profiles (``params/*.actuation.yaml``): which frames drive a car, loaded strictly.

A profile is data only::

    profile: toyota_rav4_2017          # text (required)
    note: ...                          # text (optional)
    dbc: toyota_rav4_2017.dbc.gz       # CAN database: next to this file, else tools/data/dbc/
    signals: toyota_rav4_2017.signals.yaml   # the feedback's signal map (next to this file)
    bus: 0                             # the bus the commands go out on
    steering: torque | angle           # how the car takes steering
    limits: toyota_panda | bywire_iso11270   # frozen safety limits (safety.py)
    commands:                          # role -> outgoing message
      steer_torque:                    # roles: steer_torque, accel, steer_angle, pedals, heartbeat
        message: STEERING_LKA          # DBC message
        rate_hz: 100                   # send rate [Hz]
        values: {steer_torque: STEER_TORQUE_CMD}   # quantity -> signal
        enable: [STEER_REQUEST]        # signals set to 1 while engaged (optional)
        counter: COUNTER               # rolling counter signal (optional)
        checksum: {signal: CHECKSUM, scheme: toyota}   # optional; schemes in checksums.SCHEMES
        constants: {SET_ME_1: 1}       # other signals, fixed (optional)
    feedback:                          # what the drive loop reads besides the signal map's channels
      driver_torque: {signal: STEER_TORQUE_SENSOR.STEER_TORQUE_DRIVER}
      accepts_steer: {signal: EPS_STATUS.LKA_STATE, active: [1, 5]}
    driver_torque_threshold: 100       # |driver torque| above it disengages [DBC unit]

Every key is checked: an unknown key, a missing one, a message or signal the DBC lacks, a
counter or checksum that does not fit its signal raises :class:`ParamError` naming the file,
the YAML line and the key (``commands.steer_torque.rate_hz``). Nothing falls back to a default.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from hmpc.models.errors import InputError, ParamError
from hmpc.models.logs.dbc import load_dbc
from hmpc.models.logs.signalmap import SignalMap, _key_lines, load_signal_map

from hmpc.controller.actuation.checksums import SCHEMES

#: roles of outgoing messages and the quantities each must carry
ROLES: dict[str, tuple[str, ...]] = {
    "steer_torque": ("steer_torque",),
    "accel": ("accel_mps2",),
    "steer_angle": ("steering_wheel_angle_rad",),
    "pedals": ("accel_pedal", "brake_pedal"),
    "heartbeat": (),
}
#: roles each steering kind needs
NEEDS = {"torque": ("steer_torque", "accel"), "angle": ("steer_angle", "pedals", "heartbeat")}
#: feedback items the drive loop understands: name -> (kind, required for steering kinds)
FEEDBACK = {
    "driver_torque": "value",
    "eps_torque": "value",
    "brake_pressed": "flag",
    "gas_pressed": "flag",
    "accepts_steer": "flag",
    "accepts_long": "flag",
    "rejected_frames": "value",
}
FEEDBACK_NEEDS = {
    "torque": (
        "driver_torque",
        "eps_torque",
        "brake_pressed",
        "gas_pressed",
        "accepts_steer",
        "accepts_long",
    ),
    "angle": ("driver_torque", "brake_pressed", "gas_pressed", "accepts_steer", "accepts_long"),
}
TOP_KEYS = (
    "profile",
    "note",
    "dbc",
    "signals",
    "bus",
    "steering",
    "limits",
    "commands",
    "feedback",
    "driver_torque_threshold",
)
COMMAND_KEYS = (
    "message",
    "rate_hz",
    "values",
    "enable",
    "counter",
    "checksum",
    "constants",
    "note",
)
FEEDBACK_KEYS = ("signal", "active", "invert", "note")
LIMIT_SETS = ("toyota_panda", "bywire_iso11270")

_DBC_DIR = Path(__file__).resolve().parents[2] / "tools" / "data" / "dbc"


@dataclass(frozen=True)
class CommandSpec:
    """One outgoing message of a profile.

    Attributes:
        role: what it does (a key of :data:`ROLES`).
        message: the cantools message (frame id, length, signals).
        rate_hz: send rate [Hz].
        values: quantity -> signal name.
        enable: signals set to 1 while engaged, 0 otherwise.
        counter: rolling counter signal, or None; ``counter_modulo`` its range.
        checksum: checksum signal, or None; ``scheme`` its function name.
        constants: signal -> fixed raw value.
    """

    role: str
    message: Any
    rate_hz: float
    values: dict[str, str]
    enable: tuple[str, ...] = ()
    counter: str | None = None
    counter_modulo: int = 1
    checksum: str | None = None
    scheme: str | None = None
    constants: dict[str, float] = field(default_factory=dict)

    @property
    def period_s(self) -> float:
        return 1.0 / self.rate_hz


@dataclass(frozen=True)
class FeedbackItem:
    """A status signal: ``message.signal``; a flag is true when its value is in ``active``
    (or non-zero without ``active``), negated by ``invert``."""

    name: str
    message: str
    signal: str
    active: tuple[float, ...] | None = None
    invert: bool = False

    def flag(self, value: float) -> bool:
        on = (value in self.active) if self.active is not None else value != 0
        return bool(on) != self.invert


@dataclass(frozen=True)
class ActuationProfile:
    """A loaded, validated actuation profile (see the module docstring)."""

    path: str
    name: str
    db: Any
    dbc_path: str
    signal_map: SignalMap
    bus: int
    steering: str
    limits: str
    commands: dict[str, CommandSpec]
    feedback: dict[str, FeedbackItem]
    driver_torque_threshold: float
    note: str | None = None

    def feedback_messages(self) -> list[str]:
        """DBC messages the drive loop decodes: the signal map's and the feedback items'."""
        out = list(self.signal_map.messages())
        for f in self.feedback.values():
            if f.message not in out:
                out.append(f.message)
        return out


def load_profile(path: str | Path) -> ActuationProfile:
    """Load and validate an actuation profile.

    Raises:
        InputError: the file is missing or unreadable.
        ParamError: not YAML, unknown or missing key, bad value, or a name the DBC lacks;
            one line naming the file, the YAML line and the key.
    """
    p = Path(path)
    if not p.is_file():
        raise InputError("no such actuation profile", str(p))
    try:
        text = p.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"cannot read the profile ({exc.__class__.__name__})", str(p)) from None
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        raise ParamError(
            "not valid YAML", str(p), line=None if mark is None else mark.line + 1
        ) from None
    return parse_profile(data, p, _key_lines(text))


def parse_profile(data: Any, path: Path, lines: dict | None = None) -> ActuationProfile:
    """Validate a parsed profile document (see :func:`load_profile`)."""
    lines = lines or {}
    spath = str(path)

    def err(reason: str, *keys) -> ParamError:
        line = None
        for i in range(len(keys), 0, -1):
            line = lines.get(tuple(str(k) for k in keys[:i]))
            if line is not None:
                break
        return ParamError(
            reason, spath, line=line, key=".".join(str(k) for k in keys) if keys else None
        )

    if not isinstance(data, dict):
        raise err("an actuation profile must be a mapping")
    for k in data:
        if k not in TOP_KEYS:
            raise err(f"unknown key (expected one of {', '.join(TOP_KEYS)})", k)
    for k in TOP_KEYS:
        if k != "note" and k not in data:
            raise err("missing key", k)
    for k in ("profile", "dbc", "signals", "steering", "limits"):
        if not isinstance(data[k], str) or not data[k]:
            raise err("expected text", k)
    if data["steering"] not in NEEDS:
        raise err(f"must be one of {', '.join(NEEDS)}", "steering")
    if data["limits"] not in LIMIT_SETS:
        raise err(f"must be one of {', '.join(LIMIT_SETS)}", "limits")
    bus = data["bus"]
    if not isinstance(bus, int) or isinstance(bus, bool) or bus < 0:
        raise err("expected a bus number >= 0", "bus")
    thr = data["driver_torque_threshold"]
    if not isinstance(thr, (int, float)) or isinstance(thr, bool) or not thr > 0:
        raise err("expected a positive number", "driver_torque_threshold")

    dbc_path = _find(path.parent / data["dbc"], _DBC_DIR / data["dbc"])
    if dbc_path is None:
        raise err(f"DBC '{data['dbc']}' not found next to the profile nor in {_DBC_DIR}", "dbc")
    db = load_dbc(dbc_path)
    smap_path = path.parent / data["signals"]
    if not smap_path.is_file():
        raise err(f"signal map '{data['signals']}' not found next to the profile", "signals")
    smap = load_signal_map(smap_path, db)

    cmds_raw = data["commands"]
    if not isinstance(cmds_raw, dict) or not cmds_raw:
        raise err("expected a mapping role -> message", "commands")
    commands = {}
    for role, entry in cmds_raw.items():
        commands[str(role)] = _command(str(role), entry, db, err)
    for role in NEEDS[data["steering"]]:
        if role not in commands:
            raise err(f"steering '{data['steering']}' needs a '{role}' command", "commands")

    fb_raw = data["feedback"]
    if not isinstance(fb_raw, dict):
        raise err("expected a mapping", "feedback")
    feedback = {}
    for name, entry in fb_raw.items():
        feedback[str(name)] = _feedback(str(name), entry, db, err)
    for name in FEEDBACK_NEEDS[data["steering"]]:
        if name not in feedback:
            raise err(f"missing feedback item '{name}'", "feedback")
    note = data.get("note")
    if note is not None and not isinstance(note, str):
        raise err("expected text", "note")
    return ActuationProfile(
        spath,
        data["profile"],
        db,
        str(dbc_path),
        smap,
        int(bus),
        data["steering"],
        data["limits"],
        commands,
        feedback,
        float(thr),
        note,
    )


def _find(*candidates: Path) -> Path | None:
    for c in candidates:
        if c.is_file():
            return c
    return None


def _message(db, name, err, *keys):
    try:
        return db.get_message_by_name(str(name))
    except KeyError:
        raise err(f"message '{name}' is not in the DBC", *keys) from None


def _signal(msg, name, err, *keys):
    for s in msg.signals:
        if s.name == name:
            return s
    raise err(f"signal '{name}' is not in message {msg.name}", *keys)


def _number(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def _command(role: str, entry: Any, db, err) -> CommandSpec:
    base = ("commands", role)
    if role not in ROLES:
        raise err(f"unknown command role (expected one of {', '.join(ROLES)})", *base)
    if not isinstance(entry, dict):
        raise err("expected a mapping", *base)
    for k in entry:
        if k not in COMMAND_KEYS:
            raise err(f"unknown key (expected one of {', '.join(COMMAND_KEYS)})", *base, k)
    for k in ("message", "rate_hz", "values"):
        if k not in entry:
            raise err("missing key", *base, k)
    msg = _message(db, entry["message"], err, *base, "message")
    rate = entry["rate_hz"]
    if not _number(rate) or not 0 < rate <= 1000:
        raise err("expected a rate in (0, 1000] Hz", *base, "rate_hz")
    vals = entry["values"] or {}
    if not isinstance(vals, dict):
        raise err("expected a mapping quantity -> signal", *base, "values")
    need = ROLES[role]
    for q in vals:
        if q not in need:
            raise err(
                f"unknown quantity for role {role} (expected {', '.join(need) or 'none'})",
                *base,
                "values",
                q,
            )
    for q in need:
        if q not in vals:
            raise err(f"missing quantity '{q}'", *base, "values")
        _signal(msg, vals[q], err, *base, "values", q)
    enable = entry.get("enable", []) or []
    if not isinstance(enable, list):
        raise err("expected a list of signals", *base, "enable")
    for s in enable:
        _signal(msg, s, err, *base, "enable")
    counter, modulo = entry.get("counter"), 1
    if counter is not None:
        sig = _signal(msg, counter, err, *base, "counter")
        if sig.is_signed or sig.scale != 1 or sig.offset != 0:
            raise err("a counter must be an unsigned raw signal", *base, "counter")
        modulo = 1 << sig.length
    checksum = scheme = None
    if "checksum" in entry:
        ck = entry["checksum"]
        if not isinstance(ck, dict) or set(ck) != {"signal", "scheme"}:
            raise err("expected {signal: NAME, scheme: NAME}", *base, "checksum")
        sig = _signal(msg, ck["signal"], err, *base, "checksum", "signal")
        if ck["scheme"] not in SCHEMES:
            raise err(
                f"unknown scheme (expected one of {', '.join(SCHEMES)})",
                *base,
                "checksum",
                "scheme",
            )
        # both schemes write the last byte of the frame
        if sig.length != 8 or sig.is_signed or (msg.length - 1) * 8 != _lsb_start(sig):
            raise err(
                "the checksum must be the frame's last byte (unsigned, 8 bits)",
                *base,
                "checksum",
                "signal",
            )
        checksum, scheme = ck["signal"], ck["scheme"]
    consts = entry.get("constants", {}) or {}
    if not isinstance(consts, dict):
        raise err("expected a mapping signal -> value", *base, "constants")
    used = set(vals.values()) | set(enable) | {counter, checksum}
    for s, v in consts.items():
        _signal(msg, s, err, *base, "constants", s)
        if s in used:
            raise err("signal is already written by the builder", *base, "constants", s)
        if not _number(v):
            raise err("expected a number", *base, "constants", s)
        sig = _signal(msg, s, err, *base, "constants", s)
        lo, hi = (
            (-(1 << (sig.length - 1)), (1 << (sig.length - 1)) - 1)
            if sig.is_signed
            else (0, (1 << sig.length) - 1)
        )
        if v != int(v) or not lo <= v <= hi:
            # a constant is a raw value: it must fit the signal's bits as written
            raise err(
                f"expected a whole raw value in {lo}..{hi} (a {sig.length}-bit "
                f"{'signed' if sig.is_signed else 'unsigned'} signal), got {v!r}",
                *base,
                "constants",
                s,
            )
    return CommandSpec(
        role,
        msg,
        float(rate),
        {q: vals[q] for q in need},
        tuple(enable),
        counter,
        modulo,
        checksum,
        scheme,
        {str(k): v for k, v in consts.items()},
    )


def _lsb_start(sig) -> int:
    """Bit position (little-endian numbering) of the lowest byte's first bit of a byte-aligned
    signal: equal to (length-1)*8 when the signal is exactly the last byte."""
    if sig.byte_order == "little_endian":
        return sig.start
    return sig.start - 7  # big-endian 8-bit signal: start is the MSB of its byte


def _feedback(name: str, entry: Any, db, err) -> FeedbackItem:
    base = ("feedback", name)
    if name not in FEEDBACK:
        raise err(f"unknown feedback item (expected one of {', '.join(FEEDBACK)})", *base)
    if not isinstance(entry, dict):
        raise err("expected a mapping", *base)
    for k in entry:
        if k not in FEEDBACK_KEYS:
            raise err(f"unknown key (expected one of {', '.join(FEEDBACK_KEYS)})", *base, k)
    ref = entry.get("signal")
    if not isinstance(ref, str) or ref.count(".") != 1:
        raise err("expected MESSAGE.SIGNAL", *base, "signal")
    mname, sname = ref.split(".")
    msg = _message(db, mname, err, *base, "signal")
    _signal(msg, sname, err, *base, "signal")
    active = entry.get("active")
    if active is not None:
        if FEEDBACK[name] != "flag":
            raise err("'active' belongs to flags only", *base, "active")
        if not isinstance(active, list) or not active or not all(_number(a) for a in active):
            raise err("expected a list of numbers", *base, "active")
        active = tuple(float(a) for a in active)
    inv = entry.get("invert", False)
    if not isinstance(inv, bool):
        raise err("expected true or false", *base, "invert")
    return FeedbackItem(name, mname, sname, active, inv)
