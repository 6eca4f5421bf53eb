"""Parameter files (``params/*.yaml``): the strict loader and writer.

The contract is ``../shared/CONVENTIONS.md``: every numeric key carries its unit as a suffix
(``_m``, ``_s``, ``_rad``, ``_mps``, ``_mps2``, ...), a file with only ``vehicle``,
``steering`` and ``longitudinal.zones`` is a complete model, and everything else is optional.
Unknown keys and keys without a unit are rejected (:class:`ParamError`), never defaulted.

Optional keys (all documented here, nowhere else):

- ``vehicle``: ``track_rear_m``, ``wheel_radius_m``, ``mass_kg``, ``cg_to_rear_axle_m``,
  ``steering_ratio`` (nominal, from the maker), ``steering_wheel_angle_max_rad``,
  ``steering_wheel_rate_max_radps``, ``source`` (text: where the numbers come from),
  ``nav_lever_arm_m`` ([x, y]: where the GNSS/INS position is taken, body axes x forward,
  y left, from the rear-axle centre; unknown when absent, not assumed zero).
- ``steering``: ``dead_time_s``, ``offset_ci95_rad``/``scale_ci95`` ([low, high]),
  ``method`` (text), ``identifiable`` (bool), ``note`` (text), ``rms_error_rad``.
- ``longitudinal``: ``dead_time_s``, ``hysteresis_mps``, ``accel_source`` (text); per zone
  ``*_ci95_mps2`` ([low, high]), ``nmse_pct``, ``speed_rmse_mps``, ``samples``,
  ``identifiable``, ``note``.
- ``limits``: actuator and comfort limits used by the controller (see ``VehicleLimits``).
- ``provenance``: free text/number fields (input hashes, time span, hmpc version).
"""
from __future__ import annotations

import difflib
import math
from dataclasses import dataclass, field, fields, asdict
from pathlib import Path
from typing import Any

import yaml

from hmpc.models.errors import ParamError

#: Unit suffixes a numeric key may carry.
UNIT_SUFFIXES = ("_m", "_s", "_rad", "_mps", "_mps2", "_mps3", "_radps", "_pct", "_kg", "_hz")
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


_KIND = {float: _num, tuple: _pair, str: _text, bool: _flag}


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
                raise ParamError(f"key has no unit suffix (did you mean '{with_unit[0]}'?)", path,
                                 key=full)
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
        kinds[f.name] = (tuple if "tuple" in t else str if "str" in t else
                         bool if "bool" in t else float)
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
    identifiable: bool | None = None
    note: str | None = None
    __required__ = ("offset_rad", "scale")


@_typed
@dataclass
class Zone:
    """Eq. 8 with brake: accel [m/s^2] = offset + scale * accel_pedal - brake_scale * brake_pedal."""

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
    __required__ = ("name", "v_min_mps", "v_max_mps", "offset_mps2", "scale_mps2",
                    "brake_scale_mps2")

    def accel_mps2(self, accel_pedal: float, brake_pedal: float) -> float:
        return self.offset_mps2 + self.scale_mps2 * accel_pedal - self.brake_scale_mps2 * brake_pedal


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
    limits: VehicleLimits | None = None
    provenance: dict = field(default_factory=dict)
    #: parts a recording could not identify -> the reason (CONVENTIONS: ``not_identified:``)
    not_identified: dict = field(default_factory=dict)
    path: str | None = None

    @property
    def is_model(self) -> bool:
        return self.steering is not None and bool(self.zones)

    def zone_for(self, v_mps: float) -> int:
        """Index of the zone whose (v_min, v_max] holds v; 0 for v <= first v_max; -1 above
        all and for NaN (the zone rule of ``models.plant.zone_of_speed``)."""
        from hmpc.models.plant import zone_of_speed  # plant imports this module
        return zone_of_speed(v_mps, [z.v_max_mps for z in self.zones])

    def to_dict(self) -> dict:
        def clean(obj):
            d = asdict(obj)
            return {k: (list(v) if isinstance(v, tuple) else v) for k, v in d.items() if v is not None}
        out: dict[str, Any] = {"vehicle": clean(self.vehicle)}
        if self.steering is not None:
            out["steering"] = clean(self.steering)
        if self.zones:
            lon: dict[str, Any] = {"zones": [clean(z) for z in self.zones]}
            if self.longitudinal_dead_time_s is not None:
                lon["dead_time_s"] = self.longitudinal_dead_time_s
            if self.hysteresis_mps is not None:
                lon["hysteresis_mps"] = self.hysteresis_mps
            if self.accel_source is not None:
                lon["accel_source"] = self.accel_source
            out["longitudinal"] = lon
        if self.limits is not None:
            out["limits"] = clean(self.limits)
        if self.provenance:
            out["provenance"] = self.provenance
        if self.not_identified:
            out["not_identified"] = dict(self.not_identified)
        return out


_TOP = {"vehicle", "steering", "longitudinal", "limits", "provenance", "not_identified"}
#: the parts ``not_identified:`` may name
_PARTS = ("steering", "longitudinal")
_LONG = {"zones": None, "dead_time_s": _num, "hysteresis_mps": _num, "accel_source": _text}


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
    for k in ("wheelbase_m", "track_front_m"):
        if getattr(vehicle, k) <= 0:
            raise ParamError("must be positive", path, key=f"vehicle.{k}")
    p = Params(vehicle=vehicle, path=path)
    if "steering" in data:
        p.steering = Steering(**_check_keys(path, "steering", data["steering"], Steering))
    if "longitudinal" in data:
        lon = data["longitudinal"]
        if not isinstance(lon, dict):
            raise ParamError("section 'longitudinal' must be a mapping", path, key="longitudinal")
        for k, v in lon.items():
            if k not in _LONG:
                raise ParamError("unknown key", path, key=f"longitudinal.{k}")
        zones = lon.get("zones")
        if not isinstance(zones, list) or not zones:
            raise ParamError("expected a non-empty list of zones", path, key="longitudinal.zones")
        for i, z in enumerate(zones):
            p.zones.append(Zone(**_check_keys(path, f"longitudinal.zones[{i}]", z, Zone)))
        for i, z in enumerate(p.zones):
            if not z.v_max_mps > z.v_min_mps:
                raise ParamError("v_max_mps must exceed v_min_mps", path,
                                 key=f"longitudinal.zones[{i}].v_max_mps")
            if i and abs(z.v_min_mps - p.zones[i - 1].v_max_mps) > 1e-9:
                raise ParamError("zones must be contiguous (v_min_mps = previous v_max_mps)", path,
                                 key=f"longitudinal.zones[{i}].v_min_mps")
        if "dead_time_s" in lon:
            p.longitudinal_dead_time_s = _num(path, "longitudinal.dead_time_s", lon["dead_time_s"])
        if "hysteresis_mps" in lon:
            p.hysteresis_mps = _num(path, "longitudinal.hysteresis_mps", lon["hysteresis_mps"])
        if "accel_source" in lon:
            p.accel_source = _text(path, "longitudinal.accel_source", lon["accel_source"])
    if "limits" in data:
        p.limits = VehicleLimits(**_check_keys(path, "limits", data["limits"], VehicleLimits))
    if "provenance" in data:
        if not isinstance(data["provenance"], dict):
            raise ParamError("section 'provenance' must be a mapping", path, key="provenance")
        p.provenance = data["provenance"]
    if "not_identified" in data:
        ni = data["not_identified"]
        if not isinstance(ni, dict):
            raise ParamError("section 'not_identified' must map a part to its reason", path,
                             key="not_identified")
        for k, v in ni.items():
            if k not in _PARTS:
                raise ParamError(f"unknown part (one of {', '.join(_PARTS)})", path,
                                 key=f"not_identified.{k}")
            if not isinstance(v, str) or not v.strip():
                raise ParamError("expected the reason as text", path, key=f"not_identified.{k}")
            if k in data:
                raise ParamError(f"'{k}' is both given and listed as not identified", path,
                                 key=f"not_identified.{k}")
        p.not_identified = dict(ni)
    if require_model and not p.is_model:
        missing = "steering" if p.steering is None else "longitudinal"
        why = p.not_identified.get(missing)
        raise ParamError("this command needs a complete model; section is missing"
                         + (f" (not identified: {why})" if why else ""), path, key=missing)
    return p


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
        raise ParamError(f"not valid YAML ({getattr(exc, 'problem', exc)})", path, line=line) from None
    except (OSError, UnicodeDecodeError) as exc:
        raise ParamError(f"cannot read ({exc.__class__.__name__})", path) from None
    return parse_params(data, path, require_model=require_model)


def dump_params(params: Params, path: str | Path) -> None:
    """Write ``params`` as YAML (keys in CONVENTIONS order)."""
    with open(path, "w", encoding="utf-8") as fh:
        yaml.safe_dump(params.to_dict(), fh, sort_keys=False, default_flow_style=None)
