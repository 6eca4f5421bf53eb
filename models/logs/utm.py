"""UTM grid coordinates to hmpc's local ENU frame (WGS84), through pyproj and pymap3d.

A UTM easting/northing is a transverse-Mercator grid position. pyproj (PROJ) inverts the
projection to latitude and longitude (:func:`utm_to_geodetic`); pymap3d turns those into
local ENU from the first fix (:func:`grid_to_local`), so distances and directions are true
ones, not grid ones. A heading measured on the grid (from grid east) becomes an ENU heading by
subtracting the grid convergence at the fix (grid north minus true north, positive clockwise),
which :func:`utm_to_geodetic` reads off the projection itself: the grid direction of a step
due north.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from functools import lru_cache

import numpy as np
import pymap3d
from pyproj import Transformer

_ZONE_RE = re.compile(r"^\s*utm\s*(\d{1,2})\s*([NS])\s*$", re.IGNORECASE)
#: latitude step [deg] of the due-north probe that reads the grid convergence: ~1 m, far
#: above the projection's round-off and far below any curvature of the grid lines
_NORTH_STEP_DEG = 1e-5


@dataclass(frozen=True)
class UtmZone:
    """A UTM zone: number 1..60 and hemisphere."""

    number: int
    north: bool

    @property
    def epsg(self) -> int:
        """EPSG code of WGS84 / UTM in this zone (326NN north, 327NN south)."""
        return (32600 if self.north else 32700) + self.number

    def __str__(self) -> str:
        return f"utm {self.number}{'N' if self.north else 'S'}"


def parse_zone(text: str) -> UtmZone:
    """``"utm 12N"`` (or ``utm12n``, ``UTM 33 S``) -> :class:`UtmZone`.

    Raises:
        ValueError: not that form, or a zone number outside 1..60.
    """
    m = _ZONE_RE.match(str(text))
    if not m:
        raise ValueError(f"expected 'utm <zone 1..60><N|S>' (e.g. 'utm 12N'), got {text!r}")
    number = int(m.group(1))
    if not 1 <= number <= 60:
        raise ValueError(f"UTM zone {number} is not in 1..60")
    return UtmZone(number, m.group(2).upper() == "N")


@lru_cache(maxsize=8)
def _transformers(zone: UtmZone) -> tuple[Transformer, Transformer]:
    """(grid -> lon/lat, lon/lat -> grid) for ``zone``, built once."""
    return (
        Transformer.from_crs(zone.epsg, 4326, always_xy=True),
        Transformer.from_crs(4326, zone.epsg, always_xy=True),
    )


@dataclass(frozen=True)
class GridPoint:
    """A UTM point as geodetic coordinates, with the grid convergence there."""

    lat_deg: float
    lon_deg: float
    #: grid north minus true north [rad], positive clockwise (east of the central meridian
    #: in the northern hemisphere)
    convergence_rad: float


def utm_to_geodetic(easting_m: float, northing_m: float, zone: UtmZone) -> GridPoint:
    """Latitude, longitude and grid convergence of a UTM position (WGS84)."""
    inverse, forward = _transformers(zone)
    lon, lat = inverse.transform(float(easting_m), float(northing_m))
    e1, n1 = forward.transform(lon, lat + _NORTH_STEP_DEG)
    # true north points at grid bearing -gamma: a step due north moves the grid position by
    # (dE, dN) with atan2(dE, dN) = -gamma
    gamma = -math.atan2(e1 - float(easting_m), n1 - float(northing_m))
    return GridPoint(float(lat), float(lon), gamma)


def grid_to_local(
    easting_m, northing_m, zone: UtmZone, origin: GridPoint
) -> tuple[np.ndarray, np.ndarray]:
    """UTM positions [m] to local ENU east, north [m] from ``origin`` (the first fix), on the
    ellipsoid (heights are not used: a drive's few metres of height change its east/north by
    well under a millimetre)."""
    inverse, _ = _transformers(zone)
    lon, lat = inverse.transform(np.asarray(easting_m, float), np.asarray(northing_m, float))
    east, north, _ = pymap3d.geodetic2enu(lat, lon, 0.0, origin.lat_deg, origin.lon_deg, 0.0)
    return np.asarray(east, float), np.asarray(north, float)
