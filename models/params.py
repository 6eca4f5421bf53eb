"""Parameter files (``params/*.yaml``): the strict loader and writer.

The contract is ``docs/conventions.md``: every numeric key carries its unit as a suffix
(``_m``, ``_s``, ``_rad``, ``_mps``, ``_mps2``, ...), a file with only ``vehicle``,
``steering`` and ``longitudinal.zones`` is a complete model, and everything else is optional.
Unknown keys and keys without a unit are rejected (:class:`ParamError`), never defaulted; so is
a geometry no road vehicle has (a wheelbase in millimetres; :mod:`hmpc.models.geometry`), and
:func:`dump_params` never writes a file the loader would refuse.

Optional keys (all documented here, nowhere else):

- ``vehicle``: ``track_rear_m``, ``wheel_radius_m``, ``mass_kg``, ``cg_to_rear_axle_m``,
  ``steering_ratio`` (nominal, from the maker), ``steering_wheel_angle_max_rad``,
  ``steering_wheel_rate_max_radps``, ``source`` (text: where the numbers come from),
  ``nav_lever_arm_m`` ([x, y]: where the GNSS/INS position is taken, body axes x forward,
  y left, from the rear-axle centre; unknown when absent, not assumed zero).
- ``steering``: ``dead_time_s``, ``offset_ci95_rad``/``scale_ci95`` ([low, high]),
  ``method`` (text: the fit chosen by held-out evidence), ``method_scores`` (mapping method ->
  held-out score, lower is better; ``models.identify.steering.cross_validate``),
  ``dead_time_ci95_s`` ([low, high] [s]; absent when the dead time is not determined),
  ``identifiable`` (bool), ``note`` (text), ``rms_error_rad``, ``input`` (text: the channel
  the map reads, ``steering_wheel_angle`` when absent, or ``steering_cmd`` for a car without
  a steering measurement: road-wheel angle = offset + scale * steering_cmd, the servo
  included; an Ackermann angle command has a scale near 1).
- ``longitudinal``: ``dead_time_s``, ``hysteresis_mps``, ``accel_source`` (text: how the
  measured acceleration was obtained), ``accel_source_chosen`` (text: the source chosen by
  held-out evidence, one of ``wheel_speeds``, ``speed``, ``gps_speed``, ``accel_x``),
  ``accel_source_scores_mps2`` (mapping source -> held-out score [m/s^2], lower is better;
  ``models.identify.longitudinal.choose_accel_source``); per zone
  ``*_ci95_mps2`` ([low, high]), ``nmse_pct``, ``speed_rmse_mps``, ``samples``,
  ``identifiable``, ``note``.
- ``longitudinal.input`` (text, :data:`LONGITUDINAL_INPUTS`): ``accel_pedal`` (the default:
  eq. 8 as above) or, for a car driven by a command and without an accelerator pedal channel,
  ``accel_cmd`` or ``speed_cmd``. Its zones (:class:`CommandZone`) hold ``name``,
  ``v_min_mps``, ``v_max_mps``, ``offset_mps2`` and one gain instead of ``scale_mps2`` and
  ``brake_scale_mps2``: ``accel_cmd_gain`` [1] (acceleration = offset_mps2 + accel_cmd_gain *
  accel_cmd(t - dead_time_s)) or ``speed_cmd_gain_ps`` [1/s] (acceleration = offset_mps2 +
  speed_cmd_gain_ps * (speed_cmd(t - dead_time_s) - speed): a first-order speed response with
  time constant 1 / speed_cmd_gain_ps), >= 0; optional ``offset_ci95_mps2``,
  ``accel_cmd_gain_ci95`` / ``speed_cmd_gain_ci95_ps``, ``nmse_pct``, ``speed_rmse_mps``,
  ``samples``, ``identifiable``, ``note``. A tool that needs the pedal model (``simulate``,
  ``drive``, ``teleop``, ``replay``: ``load_params(require_model=True)``) refuses such a file
  in one line naming the gain key.
- ``limits``: actuator and comfort limits used by the controller (see ``VehicleLimits``).
- ``provenance``: free text/number fields (input hashes, time span, hmpc version).
- ``extensions``: physics ``hmpc diagnose`` added to the report's model, by catalogue id
  (``models.catalogue``, whose ids are part of the contract) and subsystem:
  ``extensions: {aero_drag: {longitudinal: {coeff_per_m: 1.5e-3, intervals: {coeff_per_m:
  [1.3e-3, 1.7e-3]}, equation: "..."}}}``. Each entry holds only its catalogue parameters
  (numbers), ``intervals`` ({parameter: [low, high]}), ``base`` (the coefficients it was
  fitted jointly with: ``{offset_rad, scale}`` for steering, ``{zones: [{name, offset_mps2,
  scale_mps2, brake_scale_mps2 | accel_cmd_gain | speed_cmd_gain_ps,
  engine_braking_per_krpm_mps2}]}`` for longitudinal; the conventions' keys
  of the file are what a tool that ignores the section should use, see ``hmpc diagnose``) and
  the text keys ``catalogue.EXTENSION_TEXT_KEYS``; ``on_top_of`` names another id of the
  same section.
  Unknown ids, subsystems or parameters are rejected like unknown keys.
- ``not_identified``: besides the conventions' parts (``steering``, ``longitudinal``), one zone
  value the recording did not determine, ``longitudinal.zones.<zone>.<offset_mps2 |
  scale_mps2 | brake_scale_mps2 | accel_cmd_gain | speed_cmd_gain_ps>``: "copied from zone
  'high'", "the prior 8 m/s^2". The zone is still written (the controller needs a model at
  every speed) and must be flagged ``identifiable: false``, so a tool refuses it unless told
  to accept it.
"""

from __future__ import annotations

import difflib
import math
import os
from dataclasses import dataclass, field, fields, asdict
from pathlib import Path
from collections.abc import Sequence
from typing import Any

import yaml

from hmpc.models.errors import ParamError
from hmpc.models.geometry import check_geometry
from hmpc.models.catalogue import CATALOGUE, EXTENSION_TEXT_KEYS
from hmpc.models.zones import zone_of_speed

#: Unit suffixes a numeric key may carry (``_ps``: per second, 1/s).
UNIT_SUFFIXES = (
    "_m",
    "_s",
    "_rad",
    "_mps",
    "_mps2",
    "_mps3",
    "_radps",
    "_pct",
    "_kg",
    "_hz",
    "_ps",
)
#: Dimensionless keys (ratios, counts) need no suffix: scale, scale_ci95, steering_ratio, samples.


def _num(path, key, v) -> float:
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(float(v)):
        raise ParamError(f"expected a finite number, got {v!r}", path, key=key)
    return float(v)


def _pair(path, key, v) -> tuple[float, float]:
    if not isinstance(v, (list, tuple)) or len(v) != 2:
        what = "[x, y]" if key.endswith("nav_lever_arm_m") else "[low, high]"
        raise ParamError(f"expected {what}, got {v!r}", path, key=key)
    return (_num(path, key, v[0]), _num(path, key, v[1]))


def _text(path, key, v) -> str:
    if not isinstance(v, (str, int, float)) or isinstance(v, bool):
        raise ParamError(f"expected text, got {v!r}", path, key=key)
    return str(v)


def _flag(path, key, v) -> bool:
    if not isinstance(v, bool):
        raise ParamError(f"expected true or false, got {v!r}", path, key=key)
    return v


_KIND = {
    float: _num,
    tuple: _pair,
    str: _text,
    bool: _flag,
    dict: lambda path, key, v: _scores(path, key, v),
}


def _check_keys(path: str, section: str, data: Any, cls) -> dict:
    """Reject a non-mapping, unknown keys and keys that lack their unit suffix."""
    if not isinstance(data, dict):
        raise ParamError(f"section '{section}' must be a mapping", path, key=section)
    known = {f.name for f in fields(cls)}
    out = {}
    for k, v in data.items():
        full = f"{section}.{k}"
        if k not in known:
            stems = {n: n for n in known}
            hint = ""
            with_unit = [n for n in known if any(n == f"{k}{s}" for s in UNIT_SUFFIXES)]
            if with_unit:
                raise ParamError(
                    f"key has no unit suffix (did you mean '{with_unit[0]}'?)", path, key=full
                )
            close = difflib.get_close_matches(str(k), list(stems), n=1)
            if close:
                hint = f" (did you mean '{close[0]}'?)"
            raise ParamError(f"unknown key{hint}", path, key=full)
        ftype = cls.__annotations_types__[k]
        out[k] = _KIND[ftype](path, full, v)
    missing = [f.name for f in fields(cls) if f.name in cls.__required__ and f.name not in out]
    if missing:
        raise ParamError("required key is missing", path, key=f"{section}.{missing[0]}")
    return out


def _typed(cls):
    """Record each field's kind (float, pair, text, flag) and which fields are required."""
    kinds = {}
    for f in fields(cls):
        t = str(f.type)
        kinds[f.name] = (
            tuple
            if "tuple" in t
            else str
            if "str" in t
            else bool
            if "bool" in t
            else dict
            if "dict" in t
            else float
        )
    cls.__annotations_types__ = kinds
    return cls


@_typed
@dataclass
class Vehicle:
    """Measured geometry [m] and steering-wheel range; identification starts from this."""

    wheelbase_m: float
    track_front_m: float
    track_rear_m: float | None = None
    wheel_radius_m: float | None = None
    mass_kg: float | None = None
    cg_to_rear_axle_m: float | None = None
    steering_ratio: float | None = None
    steering_wheel_angle_max_rad: float | None = None
    steering_wheel_rate_max_radps: float | None = None
    #: where the GNSS/INS position is taken: [x, y] in body axes (x forward, y left) from the
    #: rear-axle centre (CONVENTIONS); None = unknown, never assumed zero
    nav_lever_arm_m: tuple | None = None
    source: str | None = None
    __required__ = ("wheelbase_m", "track_front_m")


@_typed
@dataclass
class Steering:
    """Eq. 7: road-wheel angle [rad] = offset_rad + scale * steering-wheel angle [rad]."""

    offset_rad: float
    scale: float
    dead_time_s: float | None = None
    offset_ci95_rad: tuple | None = None
    scale_ci95: tuple | None = None
    rms_error_rad: float | None = None
    method: str | None = None
    #: the held-out score of each method (lower is better; the report's steering.selection)
    method_scores: dict | None = None
    #: the dead time's held-out interval [s] (None: not determined)
    dead_time_ci95_s: tuple | None = None
    identifiable: bool | None = None
    note: str | None = None
    #: the map's input channel: ``steering_wheel_angle`` (absent: the report's eq. 7) or
    #: ``steering_cmd`` (the commanded angle, servo included; :data:`STEERING_INPUTS`)
    input: str | None = None
    __required__ = ("offset_rad", "scale")


@_typed
@dataclass
class Zone:
    """Eq. 8 with brake.

    accel [m/s^2] = offset + scale * accel_pedal - brake_scale * brake_pedal.
    """

    name: str
    v_min_mps: float
    v_max_mps: float
    offset_mps2: float
    scale_mps2: float
    brake_scale_mps2: float
    offset_ci95_mps2: tuple | None = None
    scale_ci95_mps2: tuple | None = None
    brake_scale_ci95_mps2: tuple | None = None
    nmse_pct: float | None = None
    speed_rmse_mps: float | None = None
    samples: float | None = None
    identifiable: bool | None = None
    note: str | None = None
    __required__ = (
        "name",
        "v_min_mps",
        "v_max_mps",
        "offset_mps2",
        "scale_mps2",
        "brake_scale_mps2",
    )

    def accel_mps2(self, accel_pedal: float, brake_pedal: float) -> float:
        return (
            self.offset_mps2 + self.scale_mps2 * accel_pedal - self.brake_scale_mps2 * brake_pedal
        )


@_typed
@dataclass
class CommandZone:
    """A zone of a command-driven car (``longitudinal.input: accel_cmd | speed_cmd``), one gain:

    - ``accel_cmd``: accel [m/s^2] = offset_mps2 + accel_cmd_gain * accel_cmd(t - dead_time);
    - ``speed_cmd``: accel [m/s^2] = offset_mps2 + speed_cmd_gain_ps * (speed_cmd(t - dead_time)
      - speed), a first-order speed response with time constant 1 / speed_cmd_gain_ps [s].
    """

    name: str
    v_min_mps: float
    v_max_mps: float
    offset_mps2: float
    accel_cmd_gain: float | None = None
    speed_cmd_gain_ps: float | None = None
    offset_ci95_mps2: tuple | None = None
    accel_cmd_gain_ci95: tuple | None = None
    speed_cmd_gain_ci95_ps: tuple | None = None
    nmse_pct: float | None = None
    speed_rmse_mps: float | None = None
    samples: float | None = None
    identifiable: bool | None = None
    note: str | None = None
    __required__ = ("name", "v_min_mps", "v_max_mps", "offset_mps2")


#: ``longitudinal.input``: the input of the zone models -> the gain key each zone must hold
#: (``accel_pedal``: eq. 8's ``scale_mps2`` with ``brake_scale_mps2``, the default)
COMMAND_GAIN_KEYS = {"accel_cmd": "accel_cmd_gain", "speed_cmd": "speed_cmd_gain_ps"}
LONGITUDINAL_INPUTS = ("accel_pedal",) + tuple(COMMAND_GAIN_KEYS)
#: ``steering.input``: the channel the steering map reads
STEERING_INPUTS = ("steering_wheel_angle", "steering_cmd")


@_typed
@dataclass
class VehicleLimits:
    """The ``limits:`` section of a parameter file: the limits recorded for this vehicle, each
    optional. The controller's limits (``controller.limits.ActuatorLimits``) are its defaults
    overridden by these."""

    steering_wheel_angle_max_rad: float | None = None
    steering_wheel_rate_max_radps: float | None = None
    accel_max_mps2: float | None = None
    decel_max_mps2: float | None = None
    jerk_max_mps3: float | None = None
    speed_max_mps: float | None = None
    __required__ = ()


@dataclass
class Params:
    """A parsed parameter file. ``steering``/``zones`` are None for a geometry-only file."""

    vehicle: Vehicle
    steering: Steering | None = None
    zones: list[Zone] = field(default_factory=list)
    longitudinal_dead_time_s: float | None = None
    hysteresis_mps: float | None = None
    accel_source: str | None = None
    accel_source_chosen: str | None = None
    accel_source_scores_mps2: dict | None = None
    #: ``longitudinal.input`` of a command-driven car (``accel_cmd`` or ``speed_cmd``; None:
    #: the pedal model in ``zones``) and its zones (``zones`` is then empty)
    command_input: str | None = None
    command_zones: list[CommandZone] = field(default_factory=list)
    limits: VehicleLimits | None = None
    provenance: dict = field(default_factory=dict)
    #: parts a recording could not identify -> the reason (CONVENTIONS: ``not_identified:``)
    not_identified: dict = field(default_factory=dict)
    #: ``extensions:`` catalogue id -> subsystem -> {parameter: value, intervals, text keys}
    extensions: dict = field(default_factory=dict)
    path: str | None = None

    @property
    def is_model(self) -> bool:
        return self.steering is not None and bool(self.zones)

    def zone_for(self, v_mps: float) -> int:
        """Index of the zone whose (v_min, v_max] holds v; 0 for v <= first v_max; -1 above
        all and for NaN (the zone rule of ``models.zones.zone_of_speed``)."""
        return zone_of_speed(v_mps, [z.v_max_mps for z in self.zones])

    def to_dict(self) -> dict:
        def clean(obj):
            d = asdict(obj)
            return {
                k: (
                    list(v)
                    if isinstance(v, tuple)
                    else int(v)
                    if k == "samples" and float(v).is_integer()
                    else v
                )  # a count
                for k, v in d.items()
                if v is not None
            }

        out: dict[str, Any] = {"vehicle": clean(self.vehicle)}
        if self.steering is not None:
            out["steering"] = clean(self.steering)
        if self.zones or self.command_zones:
            lon: dict[str, Any] = {}
            if self.command_zones:
                lon["input"] = self.command_input
            lon["zones"] = [clean(z) for z in (self.zones or self.command_zones)]
            if self.longitudinal_dead_time_s is not None:
                lon["dead_time_s"] = self.longitudinal_dead_time_s
            if self.hysteresis_mps is not None:
                lon["hysteresis_mps"] = self.hysteresis_mps
            if self.accel_source is not None:
                lon["accel_source"] = self.accel_source
            if self.accel_source_chosen is not None:
                lon["accel_source_chosen"] = self.accel_source_chosen
            if self.accel_source_scores_mps2:
                lon["accel_source_scores_mps2"] = dict(self.accel_source_scores_mps2)
            out["longitudinal"] = lon
        if self.limits is not None:
            out["limits"] = clean(self.limits)
        if self.provenance:
            out["provenance"] = self.provenance
        if self.not_identified:
            out["not_identified"] = dict(self.not_identified)
        if self.extensions:
            out["extensions"] = self.extensions
        return out


_TOP = {
    "vehicle",
    "steering",
    "longitudinal",
    "limits",
    "provenance",
    "not_identified",
    "extensions",
}
#: the parts ``not_identified:`` may name
_PARTS = ("steering", "longitudinal")


def _scores(path, key, v) -> dict:
    """A mapping name -> finite number (e.g. ``accel_source_scores_mps2``)."""
    if not isinstance(v, dict) or not v:
        raise ParamError(f"expected a mapping of name to number, got {v!r}", path, key=key)
    return {str(k): _num(path, f"{key}.{k}", x) for k, x in v.items()}


#: vehicle keys that are lengths, masses, ratios or ranges: positive when given
_POSITIVE_VEHICLE = (
    "wheelbase_m",
    "track_front_m",
    "track_rear_m",
    "wheel_radius_m",
    "mass_kg",
    "steering_ratio",
    "steering_wheel_angle_max_rad",
    "steering_wheel_rate_max_radps",
)

_LONG: dict[str, Any] = {
    "zones": None,
    "input": _text,
    "dead_time_s": _num,
    "hysteresis_mps": _num,
    "accel_source": _text,
    "accel_source_chosen": _text,
    "accel_source_scores_mps2": _scores,
}


def parse_params(data: Any, path: str = "<params>", *, require_model: bool = False) -> Params:
    """Validate a parsed YAML mapping into :class:`Params` (see module doc for the keys)."""
    if not isinstance(data, dict):
        raise ParamError("a parameter file must be a YAML mapping", path)
    for k in data:
        if k not in _TOP:
            close = difflib.get_close_matches(str(k), sorted(_TOP), n=1)
            hint = f" (did you mean '{close[0]}'?)" if close else ""
            raise ParamError(f"unknown section{hint}", path, key=str(k))
    if "vehicle" not in data:
        raise ParamError("required section is missing", path, key="vehicle")
    vehicle = Vehicle(**_check_keys(path, "vehicle", data["vehicle"], Vehicle))
    for k in _POSITIVE_VEHICLE:
        v = getattr(vehicle, k)
        if v is not None and v <= 0:
            raise ParamError(f"must be positive, got {v:g}", path, key=f"vehicle.{k}")
    check_geometry(path, vehicle)
    p = Params(vehicle=vehicle, path=path)
    if "steering" in data:
        p.steering = Steering(**_check_keys(path, "steering", data["steering"], Steering))
        if not p.steering.scale > 0:
            # CONVENTIONS: a left turn is a positive steering-wheel AND road-wheel angle
            raise ParamError(
                f"must be positive (a left turn has positive steering-wheel and "
                f"road-wheel angles), got {p.steering.scale:g}",
                path,
                key="steering.scale",
            )
        if p.steering.input is not None and p.steering.input not in STEERING_INPUTS:
            raise ParamError(
                f"unknown steering input {p.steering.input!r} (one of "
                f"{', '.join(STEERING_INPUTS)})",
                path,
                key="steering.input",
            )
    if "longitudinal" in data:
        lon = data["longitudinal"]
        if not isinstance(lon, dict):
            raise ParamError("section 'longitudinal' must be a mapping", path, key="longitudinal")
        for k in lon:
            if k not in _LONG:
                raise ParamError("unknown key", path, key=f"longitudinal.{k}")
        zones = lon.get("zones")
        if not isinstance(zones, list) or not zones:
            raise ParamError("expected a non-empty list of zones", path, key="longitudinal.zones")
        _parse_zones(path, p, lon, zones)
        zone_list: Sequence[Zone | CommandZone] = p.zones or p.command_zones
        for i, z in enumerate(zone_list):
            if not z.v_max_mps > z.v_min_mps:
                raise ParamError(
                    "v_max_mps must exceed v_min_mps",
                    path,
                    key=f"longitudinal.zones[{i}].v_max_mps",
                )
            if i and abs(z.v_min_mps - zone_list[i - 1].v_max_mps) > 1e-9:
                raise ParamError(
                    "zones must be contiguous (v_min_mps = previous v_max_mps)",
                    path,
                    key=f"longitudinal.zones[{i}].v_min_mps",
                )
        if "dead_time_s" in lon:
            p.longitudinal_dead_time_s = _num(path, "longitudinal.dead_time_s", lon["dead_time_s"])
        if "hysteresis_mps" in lon:
            p.hysteresis_mps = _num(path, "longitudinal.hysteresis_mps", lon["hysteresis_mps"])
        if "accel_source" in lon:
            p.accel_source = _text(path, "longitudinal.accel_source", lon["accel_source"])
        for k in ("accel_source_chosen", "accel_source_scores_mps2"):
            if k in lon:
                setattr(p, k, _LONG[k](path, f"longitudinal.{k}", lon[k]))
    if "limits" in data:
        p.limits = VehicleLimits(**_check_keys(path, "limits", data["limits"], VehicleLimits))
    if "provenance" in data:
        if not isinstance(data["provenance"], dict):
            raise ParamError("section 'provenance' must be a mapping", path, key="provenance")
        p.provenance = data["provenance"]
    if "not_identified" in data:
        ni = data["not_identified"]
        if not isinstance(ni, dict):
            raise ParamError(
                "section 'not_identified' must map a part to its reason", path, key="not_identified"
            )
        for k, v in ni.items():
            if str(k).startswith(_ZONE_VALUE):
                _check_zone_value_named(path, p, str(k), v)
                continue
            if k not in _PARTS:
                raise ParamError(
                    f"unknown part (one of {', '.join(_PARTS)})", path, key=f"not_identified.{k}"
                )
            if not isinstance(v, str) or not v.strip():
                raise ParamError("expected the reason as text", path, key=f"not_identified.{k}")
            if k in data:
                raise ParamError(
                    f"'{k}' is both given and listed as not identified",
                    path,
                    key=f"not_identified.{k}",
                )
        p.not_identified = dict(ni)
    if "extensions" in data:
        p.extensions = _parse_extensions(path, data["extensions"])
    if require_model and p.command_zones:
        assert p.command_input is not None  # command zones come with their input
        gain = COMMAND_GAIN_KEYS[p.command_input]
        raise ParamError(
            f"this command needs the pedal model (eq. 8: scale_mps2, "
            f"brake_scale_mps2 per zone); the file holds a {p.command_input} model "
            f"(acceleration from the command, '{gain}'), which hmpc does not "
            "simulate or drive",
            path,
            key=f"longitudinal.zones[0].{gain}",
        )
    if require_model and not p.is_model:
        missing = "steering" if p.steering is None else "longitudinal"
        why = p.not_identified.get(missing)
        raise ParamError(
            "this command needs a complete model; section is missing"
            + (f" (not identified: {why})" if why else ""),
            path,
            key=missing,
        )
    return p


def _parse_zones(path: str, p: Params, lon: dict, zones: list) -> None:
    """``longitudinal.zones`` into ``p.zones`` (the pedal model, eq. 8) or, with
    ``longitudinal.input: accel_cmd | speed_cmd``, into ``p.command_zones``: every zone holds
    the input's gain key (:data:`COMMAND_GAIN_KEYS`) and no other input's; gains are >= 0."""
    inp = _text(path, "longitudinal.input", lon["input"]) if "input" in lon else "accel_pedal"
    if inp not in LONGITUDINAL_INPUTS:
        raise ParamError(
            f"unknown input {inp!r} (one of {', '.join(LONGITUDINAL_INPUTS)})",
            path,
            key="longitudinal.input",
        )
    for i, z in enumerate(zones):
        zk = f"longitudinal.zones[{i}]"
        if inp == "accel_pedal":
            if isinstance(z, dict):
                for k, cmd in ((g, c) for c, g in COMMAND_GAIN_KEYS.items()):
                    if k in z:
                        raise ParamError(
                            f"a {cmd} gain needs 'longitudinal.input: {cmd}'", path, key=f"{zk}.{k}"
                        )
            zone = Zone(**_check_keys(path, zk, z, Zone))
            for k in ("scale_mps2", "brake_scale_mps2"):
                if getattr(zone, k) < 0:
                    raise ParamError(
                        f"must be >= 0 (pressing the pedal never works against "
                        f"it; the brake term is subtracted), got "
                        f"{getattr(zone, k):g}",
                        path,
                        key=f"{zk}.{k}",
                    )
            p.zones.append(zone)
            continue
        cz = CommandZone(**_check_keys(path, zk, z, CommandZone))
        gain = COMMAND_GAIN_KEYS[inp]
        for other in COMMAND_GAIN_KEYS.values():
            if other != gain and getattr(cz, other) is not None:
                raise ParamError(
                    f"'longitudinal.input: {inp}' zones hold '{gain}', not '{other}'",
                    path,
                    key=f"{zk}.{other}",
                )
        value = getattr(cz, gain)
        if value is None:
            raise ParamError(
                f"required key is missing ('longitudinal.input: {inp}')", path, key=f"{zk}.{gain}"
            )
        if value < 0:
            raise ParamError(
                f"must be >= 0 (a larger command never slows the car), got {value:g}",
                path,
                key=f"{zk}.{gain}",
            )
        p.command_zones.append(cz)
    p.command_input = None if inp == "accel_pedal" else inp


#: ``not_identified:`` may also name one written zone value the recording did not determine
#: (copied from another zone, or a prior): ``longitudinal.zones.<name>.<key>``
_ZONE_VALUE = "longitudinal.zones."
_ZONE_VALUE_KEYS = ("offset_mps2", "scale_mps2", "brake_scale_mps2", *COMMAND_GAIN_KEYS.values())


def _check_zone_value_named(path: str, p: Params, k: str, why: Any) -> None:
    """A ``not_identified.longitudinal.zones.<name>.<key>`` entry: a reason, naming a value of
    a zone of this file that is flagged ``identifiable: false`` (a value named as not
    identified is never presented as identified)."""
    key = f"not_identified.{k}"
    if not isinstance(why, str) or not why.strip():
        raise ParamError("expected the reason as text", path, key=key)
    name, _, coef = k[len(_ZONE_VALUE) :].rpartition(".")
    zone = next((z for z in p.zones or p.command_zones if z.name == name), None)
    if zone is None or coef not in _ZONE_VALUE_KEYS:
        raise ParamError(
            f"names no zone value of this file (longitudinal.zones.<zone name>."
            f"<{'|'.join(_ZONE_VALUE_KEYS)}>)",
            path,
            key=key,
        )
    if zone.identifiable is not False:
        raise ParamError(
            f"zone '{name}' must be flagged 'identifiable: false' when a value of "
            "it is named as not identified",
            path,
            key=key,
        )


def _parse_extensions(path: str, data: Any) -> dict:
    """Validate the ``extensions:`` section against the diagnosis catalogue (module doc)."""

    def unknown(what, key, known):
        close = difflib.get_close_matches(str(key).split(".")[-1], sorted(known), n=1)
        return ParamError(
            f"unknown {what}" + (f" (did you mean '{close[0]}'?)" if close else ""), path, key=key
        )

    if not isinstance(data, dict):
        raise ParamError(
            "section 'extensions' must map catalogue ids to subsystems", path, key="extensions"
        )
    out: dict = {}
    for eid, subs in data.items():
        if eid not in CATALOGUE:
            raise unknown("catalogue id", f"extensions.{eid}", CATALOGUE)
        allowed = CATALOGUE[eid]["equation"]
        if not isinstance(subs, dict) or not subs:
            raise ParamError("expected a mapping of subsystems", path, key=f"extensions.{eid}")
        for sub, entry in subs.items():
            key = f"extensions.{eid}.{sub}"
            if sub not in allowed:
                raise unknown(f"subsystem for {eid}", key, allowed)
            if not isinstance(entry, dict):
                raise ParamError("expected a mapping of parameters", path, key=key)
            names = CATALOGUE[eid]["parameters"]
            clean: dict = {}
            for k, v in entry.items():
                if k in names:
                    clean[k] = _num(path, f"{key}.{k}", v)
                elif k == "intervals":
                    if not isinstance(v, dict):
                        raise ParamError(
                            "expected {parameter: [low, high]}", path, key=f"{key}.intervals"
                        )
                    for pk in v:
                        if pk not in names:
                            raise unknown("parameter", f"{key}.intervals.{pk}", names)
                    clean[k] = {
                        pk: list(_pair(path, f"{key}.intervals.{pk}", pv)) for pk, pv in v.items()
                    }
                elif k in EXTENSION_TEXT_KEYS:
                    clean[k] = _text(path, f"{key}.{k}", v)
                elif k == "base":
                    clean[k] = _extension_base(path, f"{key}.base", sub, v)
                else:
                    raise unknown(
                        "parameter", f"{key}.{k}", [*names, "intervals", *EXTENSION_TEXT_KEYS]
                    )
            below = clean.get("on_top_of")
            if below is not None and below not in data:
                raise ParamError(
                    f"names '{below}', which is not in the section", path, key=f"{key}.on_top_of"
                )
            out.setdefault(eid, {})[sub] = clean
    return out


#: ``base:`` of an extension entry: the coefficients it was fitted jointly with
_BASE_STEERING = ("offset_rad", "scale")
_BASE_ZONE = (
    "offset_mps2",
    "scale_mps2",
    "brake_scale_mps2",
    "accel_cmd_gain",
    "speed_cmd_gain_ps",
    "engine_braking_per_krpm_mps2",
)


def _extension_base(path: str, key: str, sub: str, v: Any) -> dict:
    """``base: {offset_rad, scale}`` (steering) or ``base: {zones: [{name, offset_mps2,
    scale_mps2, brake_scale_mps2 | accel_cmd_gain | speed_cmd_gain_ps,
    engine_braking_per_krpm_mps2}, ...]}`` (longitudinal)."""
    if not isinstance(v, dict):
        raise ParamError("expected a mapping", path, key=key)
    if sub == "steering":
        for k in v:
            if k not in _BASE_STEERING:
                raise ParamError(
                    f"unknown key (one of {', '.join(_BASE_STEERING)})", path, key=f"{key}.{k}"
                )
        return {k: _num(path, f"{key}.{k}", x) for k, x in v.items()}
    if set(v) != {"zones"} or not isinstance(v["zones"], list):
        raise ParamError("expected {zones: [...]}", path, key=key)
    out = []
    for i, z in enumerate(v["zones"]):
        zk = f"{key}.zones[{i}]"
        if not isinstance(z, dict) or "name" not in z:
            raise ParamError("expected a mapping with a name", path, key=zk)
        for k in z:
            if k != "name" and k not in _BASE_ZONE:
                raise ParamError(
                    f"unknown key (one of name, {', '.join(_BASE_ZONE)})", path, key=f"{zk}.{k}"
                )
        out.append(
            {
                k: (_text(path, f"{zk}.{k}", x) if k == "name" else _num(path, f"{zk}.{k}", x))
                for k, x in z.items()
            }
        )
    return {"zones": out}


def load_params(path: str | Path, *, require_model: bool = False) -> Params:
    """Read and validate a parameter YAML file. Raises ParamError (exit 2 in the CLI)."""
    path = str(path)
    try:
        with open(path, encoding="utf-8") as fh:
            data = yaml.safe_load(fh)
    except FileNotFoundError:
        raise ParamError("no such file", path) from None
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        line = None if mark is None else mark.line + 1
        raise ParamError(
            f"not valid YAML ({getattr(exc, 'problem', exc)})", path, line=line
        ) from None
    except (OSError, UnicodeDecodeError) as exc:
        raise ParamError(f"cannot read ({exc.__class__.__name__})", path) from None
    return parse_params(data, path, require_model=require_model)


def dump_params(params: Params, path: str | Path) -> None:
    """Write ``params`` as YAML (keys in CONVENTIONS order), never a file hmpc would refuse.

    The text is checked with the loader's own rules (:func:`parse_params`) before anything is
    written, then written to a temporary name beside ``path`` and renamed over it, so ``path``
    holds either the old file or the complete new one.

    Raises:
        ParamError: the parameters break a loader rule (nothing is written).
        OSError: the file cannot be written (nothing is left at a temporary name).
    """
    path = Path(path)
    text = yaml.safe_dump(params.to_dict(), sort_keys=False, default_flow_style=None)
    try:
        parse_params(yaml.safe_load(text), str(path))
    except ParamError as exc:
        raise ParamError(
            f"{exc.reason} (not written: hmpc would refuse the file)", exc.path, key=exc.key
        ) from None
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    try:
        with open(tmp, "w", encoding="utf-8") as fh:
            fh.write(text)
        os.replace(tmp, path)
    finally:
        if tmp.exists():
            tmp.unlink()
