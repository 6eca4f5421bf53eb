"""Plausibility of a vehicle's geometry: the lengths a road vehicle has, from a 1:10 model car
to a bus, and the track-to-wheelbase ratio; a value outside is refused naming the key and the
unit it was likely given in (the parameter-file loader, :mod:`hmpc.models.params`, calls
:func:`check_geometry`)."""

from __future__ import annotations

from typing import Any

from hmpc.models.errors import ParamError

#: [m] plausible geometry of a road vehicle, from a 1:10 model car (wheelbase ~0.33 m, track
#: ~0.28 m, wheel radius ~0.05 m) to a long bus or a mining truck (wheelbase ~7 m, track
#: ~2.5 m, wheel radius ~1.8 m): a value outside is a unit mistake (mm, cm, inches), and
#: identification with it finds no trustworthy sample instead of saying so.
GEOMETRY_RANGES_M = {
    "wheelbase_m": (0.1, 10.0),
    "track_front_m": (0.1, 5.0),
    "track_rear_m": (0.1, 5.0),
    "wheel_radius_m": (0.02, 2.0),
}
#: [1] plausible track / wheelbase: ~0.3 for a truck or bus, ~0.6 for a passenger car, ~0.9
#: for a kart or a 1:10 model; outside, the two lengths are in different units or swapped.
TRACK_WHEELBASE_RATIO = (0.2, 1.5)
#: units a length is mistakenly given in, with their size [m]
_LENGTH_UNITS = (("millimetres", 1e-3), ("centimetres", 1e-2), ("inches", 0.0254), ("feet", 0.3048))


def _unit_hint(value: float, lo: float, hi: float, ratio_to: float | None = None) -> str:
    """The units in which ``value`` would be a plausible length in [lo, hi] m, as text; with
    ``ratio_to`` (the other of wheelbase and track, in range), only those that also give a
    plausible track / wheelbase when there are any."""
    fits = [(name, value * size) for name, size in _LENGTH_UNITS if lo <= value * size <= hi]
    if ratio_to is not None:
        r_lo, r_hi = TRACK_WHEELBASE_RATIO
        both = [(n, x) for n, x in fits if r_lo <= min(x, ratio_to) / max(x, ratio_to) <= r_hi]
        fits = both or fits
    named = [f"{name} ({x:.4g} m)" for name, x in fits]
    if not named:
        return ""
    return "; likely given in " + (
        named[0] if len(named) == 1 else ", ".join(named[:-1]) + " or " + named[-1]
    )


def check_geometry(path: str, vehicle: Any) -> None:
    """Refuse a geometry no road vehicle has (:data:`GEOMETRY_RANGES_M`,
    :data:`TRACK_WHEELBASE_RATIO`), naming the key and the likely unit mistake; ``vehicle`` is a
    :class:`~hmpc.models.params.Vehicle`."""

    def in_range(k):
        lo, hi = GEOMETRY_RANGES_M[k]
        v = getattr(vehicle, k)
        return v if v is not None and lo <= v <= hi else None

    for k, (lo, hi) in GEOMETRY_RANGES_M.items():
        v = getattr(vehicle, k)
        if v is not None and not lo <= v <= hi:
            other = (
                in_range("track_front_m")
                if k == "wheelbase_m"
                else in_range("wheelbase_m")
                if k.startswith("track_")
                else None
            )
            raise ParamError(
                f"{v:g} m is not a plausible length (road vehicles from 1:10 models "
                f"up have {lo:g}-{hi:g} m){_unit_hint(v, lo, hi, other)}",
                path,
                key=f"vehicle.{k}",
            )
    lo, hi = TRACK_WHEELBASE_RATIO
    for k in ("track_front_m", "track_rear_m"):
        t = getattr(vehicle, k)
        if t is not None and not lo <= t / vehicle.wheelbase_m <= hi:
            raise ParamError(
                f"{k} / wheelbase_m = {t:g} / {vehicle.wheelbase_m:g} = "
                f"{t / vehicle.wheelbase_m:.3g} is not plausible (road vehicles "
                f"have {lo:g}-{hi:g}): the two are likely in different units or "
                "swapped",
                path,
                key=f"vehicle.{k}",
            )
