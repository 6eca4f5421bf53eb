"""Signal maps: which DBC message and signals make each canonical channel of a vehicle.

One YAML file per vehicle in ``params/`` (``*.signals.yaml``)::

    vehicle: toyota_rav4_2017            # text, optional
    dbc: toyota_rav4_2017.dbc            # text, optional: the DBC the map was written for
    note: ...                            # text, optional
    channels:
      steering_wheel_angle:
        message: STEER_ANGLE_SENSOR      # DBC message name (required)
        expr: STEER_ANGLE + STEER_FRACTION   # arithmetic over that message's signals (required)
        unit: deg                        # unit of expr's value; converted to SI (required)
        sign: 1                          # optional, 1 or -1 (applied after the unit conversion)
        bus: 0                           # optional: only frames on this bus
        required: true                   # optional (default false): absent from the log -> error
        resample: linear                 # optional: linear | hold (default: per channel, see below)
        note: ...                        # optional text
      gear:
        message: GEAR_PACKET
        expr: GEAR
        gear: {0: D, 1: S, 8: N, 16: R, 32: P}   # raw value -> P/R/N/D/L/B/S/1..9 (gear only)

Channel names are those of ``models.logs.channels.CHANNELS`` (``docs/conventions.md``).
``expr`` is parsed with :mod:`ast` and checked against a whitelist: numbers, the message's
signal names, ``+ - * /``, unary ``-``/``+``, parentheses and the functions ``abs``, ``min``,
``max``. Nothing from the file is ever passed to ``eval``/``exec``.

Units (``unit:``) and the SI unit they convert to are listed in :data:`UNITS`; the converted
unit must match the channel's unit in CONVENTIONS (``km/h`` is accepted for ``speed`` but not
for ``steering_wheel_angle``). ``%`` and ``fraction`` both mean the dimensionless ``1``.

Everything is validated at load time against the DBC: an unknown top-level key, channel,
per-channel key, message, signal, unit or function raises :class:`ParamError` naming the map
file, the YAML line and the key (``channels.<channel>.<key>``) -- one line, no traceback.
"""

from __future__ import annotations

import ast
import difflib
import math
import operator
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any
from collections.abc import Callable

import numpy as np
import yaml

from hmpc.models.constants import G_MPS2
from hmpc.models.logs.channels import CHANNELS, STRING_CHANNELS, VALID_GEARS
from hmpc.models.errors import InputError, ParamError

#: source unit -> (SI unit it converts to, factor: SI value = factor * source value)
UNITS: dict[str, tuple[str, float]] = {
    "rad": ("rad", 1.0),
    "deg": ("rad", math.pi / 180.0),
    "rad/s": ("rad/s", 1.0),
    "deg/s": ("rad/s", math.pi / 180.0),
    "m/s": ("m/s", 1.0),
    "km/h": ("m/s", 1.0 / 3.6),
    "mph": ("m/s", 0.44704),  # international mile / hour, exact
    "m/s^2": ("m/s^2", 1.0),
    "g": ("m/s^2", G_MPS2),  # standard gravity
    "1": ("1", 1.0),
    "fraction": ("1", 1.0),
    "%": ("1", 0.01),
    "rpm": ("1/min", 1.0),
    "1/min": ("1/min", 1.0),
    "m": ("m", 1.0),
    "ft": ("m", 0.3048),  # international foot, exact
}

#: other spellings of those units found in DBCs in the field (opendbc writes ``kph``, other
#: makers ``km/hr``, ``deg/sec``, ``m/s2``, ``percent``) -> the spelling in :data:`UNITS`.
#: Matched exactly, after stripping surrounding blanks; an unknown spelling stays an error.
UNIT_ALIASES: dict[str, str] = {
    "kph": "km/h",
    "kmh": "km/h",
    "km/hr": "km/h",
    "kmph": "km/h",
    "kilometer/hour": "km/h",
    "degree": "deg",
    "degrees": "deg",
    "°": "deg",
    "deg/sec": "deg/s",
    "degree/s": "deg/s",
    "degrees/s": "deg/s",
    "°/s": "deg/s",
    "rad/sec": "rad/s",
    "mps": "m/s",
    "m/sec": "m/s",
    "m/s2": "m/s^2",
    "m/s²": "m/s^2",
    "m/s/s": "m/s^2",
    "mps2": "m/s^2",
    "percent": "%",
    "pct": "%",
    "rev/min": "rpm",
    "meter": "m",
    "metre": "m",
}


def canonical_unit(unit: str) -> str:
    """The :data:`UNITS` spelling of ``unit`` (an alias from :data:`UNIT_ALIASES` or itself)."""
    u = unit.strip()
    return UNIT_ALIASES.get(u, u)


#: resampling kinds a map may ask for (``models.logs.resample``).
RESAMPLE_KINDS = ("linear", "hold")

#: per-channel keys a map entry may hold
CHANNEL_KEYS = ("message", "expr", "unit", "sign", "bus", "required", "resample", "gear", "note")
#: top-level keys of a map file
TOP_KEYS = ("vehicle", "dbc", "note", "channels")

#: functions an expression may call, with how many arguments they take (min, max)
_FUNCS: dict[str, tuple[Callable, int, int]] = {
    "abs": (np.abs, 1, 1),
    "min": (np.minimum, 2, 2),
    "max": (np.maximum, 2, 2),
}
_BINOPS = {
    ast.Add: operator.add,
    ast.Sub: operator.sub,
    ast.Mult: operator.mul,
    ast.Div: operator.truediv,
}
_UNOPS: dict[type, Callable[..., Any]] = {ast.USub: operator.neg, ast.UAdd: operator.pos}
#: an expression longer than this (characters or AST nodes) is refused: no map needs more
MAX_EXPR_CHARS = 400
MAX_EXPR_NODES = 64


@dataclass(frozen=True)
class Expr:
    """A parsed, whitelisted arithmetic expression over one message's signals.

    Attributes:
        text: the expression as written in the map.
        signals: the signal names it reads, in order of first use.
    """

    text: str
    signals: tuple[str, ...]
    _fn: Callable[[dict], Any] = field(repr=False, compare=False)

    def __call__(self, values: dict[str, np.ndarray]) -> np.ndarray:
        """Evaluate on arrays of signal values (float64, same length); returns float64."""
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            out = self._fn(values)
        n = len(next(iter(values.values()))) if values else 1
        return np.broadcast_to(np.asarray(out, dtype=float), (n,)).copy()


def parse_expr(text: str, allowed: set[str] | frozenset[str]) -> Expr:
    """Parse ``text`` into an :class:`Expr` reading only names in ``allowed``.

    Raises:
        ValueError: with a one-line reason (unknown signal, forbidden construct, syntax error).
    """
    if not isinstance(text, str) or not text.strip():
        raise ValueError("expression is empty")
    if len(text) > MAX_EXPR_CHARS:
        raise ValueError(f"expression longer than {MAX_EXPR_CHARS} characters")
    try:
        with warnings.catch_warnings():  # e.g. SyntaxWarning for '1e' -- the error says enough
            warnings.simplefilter("ignore")
            tree = ast.parse(text.strip(), mode="eval")
    except SyntaxError as exc:
        raise ValueError(f"expression {text!r} is not valid arithmetic ({exc.msg})") from None
    nodes = sum(1 for _ in ast.walk(tree))
    if nodes > MAX_EXPR_NODES:
        raise ValueError(f"expression has {nodes} parts, more than {MAX_EXPR_NODES}")
    used: list[str] = []

    def build(node) -> Callable[[dict], Any]:
        if isinstance(node, ast.Expression):
            return build(node.body)
        if isinstance(node, ast.Constant):
            v = node.value
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
                raise ValueError(f"constant {v!r} is not a finite number")
            fv = float(v)
            return lambda env: fv
        if isinstance(node, ast.Name):
            name = node.id
            if name not in allowed:
                raise ValueError(f"signal '{name}' is not in the message")
            if name not in used:
                used.append(name)
            return lambda env: env[name]
        if isinstance(node, ast.BinOp) and type(node.op) in _BINOPS:
            op = _BINOPS[type(node.op)]
            a, b = build(node.left), build(node.right)
            return lambda env: op(a(env), b(env))
        if isinstance(node, ast.UnaryOp) and type(node.op) in _UNOPS:
            op = _UNOPS[type(node.op)]
            a = build(node.operand)
            return lambda env: op(a(env))
        if isinstance(node, ast.Call):
            if not isinstance(node.func, ast.Name) or node.func.id not in _FUNCS:
                what = node.func.id if isinstance(node.func, ast.Name) else "this"
                raise ValueError(f"function '{what}' is not allowed (only abs, min, max)")
            if node.keywords:
                raise ValueError("keyword arguments are not allowed")
            fn, lo, hi = _FUNCS[node.func.id]
            if not lo <= len(node.args) <= hi:
                raise ValueError(
                    f"{node.func.id}() takes {lo} argument(s)"
                    if lo == hi
                    else f"{node.func.id}() takes {lo}..{hi} arguments"
                )
            args = [build(a) for a in node.args]
            return lambda env: fn(*(a(env) for a in args))
        raise ValueError(
            f"'{ast.unparse(node)}' is not allowed in an expression "
            "(numbers, signal names, + - * /, parentheses, abs/min/max only)"
        )

    fn = build(tree)
    if not used:
        raise ValueError("expression reads no signal")
    return Expr(text.strip(), tuple(used), fn)


@dataclass(frozen=True)
class ChannelMap:
    """How one canonical channel is made from one DBC message.

    Attributes:
        channel: canonical channel name (CONVENTIONS).
        message: DBC message name.
        expr: parsed expression over the message's signals (value in ``unit``).
        unit: the expression's unit (a key of :data:`UNITS`), ``"-"`` for gear.
        factor: multiplies the expression's value to give SI (sign included).
        sign: +1 or -1 as written in the map.
        bus: only frames on this bus, or None for any bus.
        required: ingest fails (InputError) if the log has no sample of this channel.
        resample: "linear" or "hold".
        gear: raw value -> gear letter, for the ``gear`` channel only.
        line: YAML line of the channel's entry (for messages).
    """

    channel: str
    message: str
    expr: Expr
    unit: str
    factor: float
    sign: float
    bus: int | None
    required: bool
    resample: str
    gear: dict[int, str] | None = None
    note: str | None = None
    line: int | None = None

    def evaluate(self, signals: dict[str, np.ndarray]) -> np.ndarray:
        """SI values from decoded signal arrays (float64; object array of strings for gear).

        Gear values missing from the table become ``""``; numeric results that are not finite
        (e.g. a division by zero) are returned as NaN for the caller to count and drop.
        """
        raw = self.expr({k: np.asarray(signals[k], dtype=float) for k in self.expr.signals})
        if self.gear is not None:
            out = np.full(raw.shape, "", dtype=object)
            finite = np.isfinite(raw)
            keys = np.zeros(raw.shape, dtype=np.int64)
            keys[finite] = np.rint(raw[finite]).astype(np.int64)
            for k, g in self.gear.items():
                out[finite & (keys == k)] = g
            return out
        v = raw * self.factor
        v[~np.isfinite(v)] = np.nan
        return v

    def describe(self) -> str:
        bus = "" if self.bus is None else f" bus {self.bus}"
        return f"{self.message}{bus}: {self.expr.text} [{self.unit}]" + (
            " x -1" if self.sign < 0 else ""
        )


@dataclass(frozen=True)
class SignalMap:
    """A vehicle's signal map (see module docstring)."""

    path: str
    channels: dict[str, ChannelMap]
    vehicle: str | None = None
    dbc: str | None = None
    note: str | None = None

    def messages(self) -> list[str]:
        """DBC message names the map reads (each once, in map order)."""
        out: list[str] = []
        for c in self.channels.values():
            if c.message not in out:
                out.append(c.message)
        return out

    def buses(self) -> set[int] | None:
        """Buses the map reads, or None when some channel takes any bus."""
        if any(c.bus is None for c in self.channels.values()):
            return None
        return {c.bus for c in self.channels.values() if c.bus is not None}

    def required(self) -> list[str]:
        return [c.channel for c in self.channels.values() if c.required]


# --------------------------------------------------------------------------- loading
def _key_lines(text: str) -> dict[tuple, int]:
    """YAML key path -> 1-based line, for error messages (best effort)."""
    lines: dict[tuple, int] = {}
    try:
        root = yaml.compose(text, Loader=yaml.SafeLoader)
    except yaml.YAMLError:
        return lines

    def walk(node, prefix: tuple):
        if isinstance(node, yaml.MappingNode):
            for k, v in node.value:
                if isinstance(k, yaml.ScalarNode):
                    key = prefix + (k.value,)
                    lines[key] = k.start_mark.line + 1
                    walk(v, key)

    walk(root, ())
    return lines


def load_signal_map(path: str | Path, db=None) -> SignalMap:
    """Load and validate a signal map.

    Args:
        path: the ``*.signals.yaml`` file.
        db: a cantools Database to validate messages and signals against
            (``models.logs.dbc.load_dbc``).
            Without it, only the file's own structure is checked and signal names are not
            validated (``check_against_dbc`` does it later).

    Raises:
        ParamError: unknown/missing key, unknown channel, unit, message, signal or function,
            bad value; names the file, line and key.
        InputError: the file is missing or not YAML.
    """
    path = Path(path)
    if not path.is_file():
        raise InputError("no such signal map file", str(path))
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(
            f"cannot read the signal map as text ({exc.__class__.__name__})", str(path)
        ) from None
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        problem = getattr(exc, "problem", None) or exc.__class__.__name__
        raise ParamError(
            f"not valid YAML ({problem})", str(path), line=None if mark is None else mark.line + 1
        ) from None
    return parse_signal_map(data, str(path), db, _key_lines(text))


def parse_signal_map(data: Any, path: str, db=None, lines: dict | None = None) -> SignalMap:
    """Validate an already-parsed YAML document (see :func:`load_signal_map`)."""
    lines = lines or {}

    def err(reason: str, *keys: str) -> ParamError:
        line = None
        for i in range(len(keys), 0, -1):
            line = lines.get(tuple(keys[:i]))
            if line is not None:
                break
        return ParamError(reason, path, line=line, key=".".join(keys) if keys else None)

    if not isinstance(data, dict):
        raise err("a signal map must be a mapping with a 'channels' section")
    for k in data:
        if k not in TOP_KEYS:
            raise err(f"unknown key (expected one of {', '.join(TOP_KEYS)})", str(k))
    if "channels" not in data:
        raise err("the 'channels' section is missing", "channels")
    chans = data["channels"]
    if not isinstance(chans, dict) or not chans:
        raise err("'channels' must be a non-empty mapping of channel -> entry", "channels")
    texts = {}
    for k in ("vehicle", "dbc", "note"):
        if k in data:
            if not isinstance(data[k], str):
                raise err("expected text", k)
            texts[k] = data[k]
    out: dict[str, ChannelMap] = {}
    for ch, entry in chans.items():
        out[str(ch)] = _parse_channel(str(ch), entry, db, err, lines)
    return SignalMap(path, out, texts.get("vehicle"), texts.get("dbc"), texts.get("note"))


def _parse_channel(ch: str, entry: Any, db, err, lines) -> ChannelMap:
    base = ("channels", ch)
    if ch not in CHANNELS or ch == "time":
        close = difflib.get_close_matches(ch, [c for c in CHANNELS if c != "time"], n=1)
        hint = f" (did you mean '{close[0]}'?)" if close else ""
        raise err(f"unknown channel{hint}; channels are those of docs/conventions.md", *base)
    if not isinstance(entry, dict):
        raise err("entry must be a mapping with message, expr, unit", *base)
    for k in entry:
        if k not in CHANNEL_KEYS:
            raise err(f"unknown key (expected one of {', '.join(CHANNEL_KEYS)})", *base, str(k))
    for k in ("message", "expr"):
        if k not in entry:
            raise err("required key is missing", *base, k)
    is_gear = ch in STRING_CHANNELS
    message = entry["message"]
    if not isinstance(message, str) or not message:
        raise err("expected a DBC message name", *base, "message")
    expr_text = entry["expr"]
    if isinstance(expr_text, (int, float)) and not isinstance(expr_text, bool):
        expr_text = str(expr_text)
    if not isinstance(expr_text, str):
        raise err("expected an arithmetic expression (text)", *base, "expr")

    # message and signals against the DBC
    if db is not None:
        try:
            msg = db.get_message_by_name(message)
        except KeyError:
            close = difflib.get_close_matches(message, [m.name for m in db.messages], n=1)
            hint = f" (did you mean '{close[0]}'?)" if close else ""
            raise err(f"message '{message}' is not in the DBC{hint}", *base, "message") from None
        allowed = frozenset(s.name for s in msg.signals)
    else:
        allowed = None
    try:
        expr = parse_expr(expr_text, allowed if allowed is not None else _AnyName())
    except ValueError as exc:
        raise err(
            f"{exc} '{message}'" if "is not in the message" in str(exc) else str(exc), *base, "expr"
        ) from None

    # unit
    if is_gear:
        if "unit" in entry and entry["unit"] not in ("-", None):
            raise err("gear has no unit (use the 'gear' table)", *base, "unit")
        unit, factor = "-", 1.0
    else:
        if "unit" not in entry:
            raise err(
                f"required key is missing (the expression's unit; one of {', '.join(UNITS)})",
                *base,
                "unit",
            )
        unit = entry["unit"]
        if isinstance(unit, (int, float)) and not isinstance(unit, bool):
            unit = str(unit)
        if isinstance(unit, str):
            unit = canonical_unit(unit)
        if unit not in UNITS:
            raise err(f"unknown unit {unit!r} (known: {', '.join(UNITS)})", *base, "unit")
        si, factor = UNITS[unit]
        if si != CHANNELS[ch]:
            raise err(
                f"unit '{unit}' converts to {si}, but {ch} is in {CHANNELS[ch]}", *base, "unit"
            )

    sign = entry["sign"] if "sign" in entry else 1
    if isinstance(sign, bool) or sign not in (1, -1):
        raise err(f"sign must be 1 or -1, got {sign!r}", *base, "sign")
    if is_gear and sign != 1:
        raise err("gear cannot be sign-flipped", *base, "sign")

    bus = entry["bus"] if "bus" in entry else None
    if bus is not None and (isinstance(bus, bool) or not isinstance(bus, int) or bus < 0):
        raise err(f"bus must be a non-negative integer, got {bus!r}", *base, "bus")

    required = entry["required"] if "required" in entry else False
    if not isinstance(required, bool):
        raise err(f"expected true or false, got {required!r}", *base, "required")

    default_kind = "hold" if ch in HOLD_CHANNELS else "linear"
    resample = entry["resample"] if "resample" in entry else default_kind
    if resample not in RESAMPLE_KINDS:
        raise err(
            f"resample must be one of {', '.join(RESAMPLE_KINDS)}, got {resample!r}",
            *base,
            "resample",
        )
    if is_gear and resample != "hold":
        raise err("gear can only be resampled by 'hold'", *base, "resample")

    gear = None
    if is_gear:
        if "gear" not in entry:
            raise err("required key is missing (raw value -> P/R/N/D/... table)", *base, "gear")
        table = entry["gear"]
        if not isinstance(table, dict) or not table:
            raise err("expected a mapping raw value -> gear letter", *base, "gear")
        gear = {}
        for k, v in table.items():
            if isinstance(k, bool) or not isinstance(k, int):
                raise err(f"raw gear value {k!r} is not an integer", *base, "gear", str(k))
            v = str(v)
            if v not in VALID_GEARS:
                raise err(
                    f"gear {v!r} is not one of {', '.join(sorted(VALID_GEARS))}",
                    *base,
                    "gear",
                    str(k),
                )
            gear[int(k)] = v
    elif "gear" in entry:
        raise err("a 'gear' table is only allowed for the gear channel", *base, "gear")

    note = entry["note"] if "note" in entry else None
    if note is not None and not isinstance(note, str):
        raise err("expected text", *base, "note")

    return ChannelMap(
        ch,
        message,
        expr,
        unit,
        factor * sign,
        float(sign),
        bus,
        required,
        resample,
        gear,
        note,
        lines.get(base),
    )


#: channels resampled by zero-order hold unless the map says otherwise: a pedal or gear sample
#: is a held value; hold never invents values between two samples.
HOLD_CHANNELS = frozenset(
    {"gear", "accel_pedal", "brake_pedal", "accel_pedal_cmd", "brake_pedal_cmd"}
)


class _AnyName(frozenset):
    """Stand-in 'allowed' set when no DBC is given: every identifier is accepted."""

    def __contains__(self, item) -> bool:  # noqa: D401
        return isinstance(item, str)


def check_against_dbc(smap: SignalMap, db) -> SignalMap:
    """Re-validate a map loaded without a DBC against ``db`` (raises ParamError)."""
    return load_signal_map(smap.path, db)
