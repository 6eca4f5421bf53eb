"""UTM grid coordinates to hmpc's local ENU frame (WGS84).

A UTM easting/northing is a transverse-Mercator grid position: its grid north differs from true
north by the grid convergence angle ``gamma`` (zero on the zone's central meridian, about
``dlon * sin(lat)`` off it), and a grid distance is the true distance times the point scale
factor ``k`` (0.9996 on the central meridian, up to about 1.001 at a zone's edge). Over a drive
of a few kilometres both are constant to better than 1e-6 of their value, so hmpc makes a
topic's UTM positions local ENU by subtracting the first fix, rotating by ``gamma`` at that fix
and dividing by ``k`` there (:func:`grid_to_local`); a heading measured on the grid (from grid
east) becomes an ENU heading by subtracting ``gamma``.

:func:`utm_to_geodetic` is Krueger's series for the inverse transverse Mercator projection to
third order in the third flattening ``n`` (C. F. F. Karney, "Transverse Mercator with an
accuracy of a few nanometers", J. Geodesy 85 (2011), eqs. 7-11 and 13-14 reduced to n^3):
better than a millimetre within a zone. It also gives ``gamma`` and ``k`` at the point.
"""
from __future__ import annotations

import math
import re
from dataclasses import dataclass

import numpy as np

#: WGS84 semi-major axis [m] and flattening (the GNSS datum)
WGS84_A_M = 6378137.0
WGS84_F = 1.0 / 298.257223563
#: UTM: scale on the central meridian, false easting [m], false northing south of the equator [m]
UTM_K0 = 0.9996
UTM_FALSE_EASTING_M = 500000.0
UTM_FALSE_NORTHING_SOUTH_M = 10000000.0

_N = WGS84_F / (2.0 - WGS84_F)
#: rectifying radius [m]
_A_RECT_M = WGS84_A_M / (1.0 + _N) * (1.0 + _N ** 2 / 4.0 + _N ** 4 / 64.0)
_BETA = (_N / 2.0 - 2.0 * _N ** 2 / 3.0 + 37.0 * _N ** 3 / 96.0,
         _N ** 2 / 48.0 + _N ** 3 / 15.0,
         17.0 * _N ** 3 / 480.0)
_DELTA = (2.0 * _N - 2.0 * _N ** 2 / 3.0 - 2.0 * _N ** 3,
          7.0 * _N ** 2 / 3.0 - 8.0 * _N ** 3 / 5.0,
          56.0 * _N ** 3 / 15.0)

_ZONE_RE = re.compile(r"^\s*utm\s*(\d{1,2})\s*([NS])\s*$", re.IGNORECASE)


@dataclass(frozen=True)
class UtmZone:
    """A UTM zone: number 1..60 and hemisphere."""

    number: int
    north: bool

    @property
    def central_meridian_deg(self) -> float:
        return -183.0 + 6.0 * self.number

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


@dataclass(frozen=True)
class GridPoint:
    """A UTM point as geodetic coordinates, with the grid's convergence and scale there."""

    lat_deg: float
    lon_deg: float
    convergence_rad: float   # grid north minus true north, positive clockwise (east of the meridian, north)
    scale: float             # grid distance / true distance


def utm_to_geodetic(easting_m: float, northing_m: float, zone: UtmZone) -> GridPoint:
    """Latitude, longitude, grid convergence and point scale of a UTM position (WGS84)."""
    xi = (northing_m - (0.0 if zone.north else UTM_FALSE_NORTHING_SOUTH_M)) / (UTM_K0 * _A_RECT_M)
    eta = (easting_m - UTM_FALSE_EASTING_M) / (UTM_K0 * _A_RECT_M)
    xi1, eta1, sigma1, tau1 = xi, eta, 1.0, 0.0
    for j, b in enumerate(_BETA, start=1):
        xi1 -= b * math.sin(2 * j * xi) * math.cosh(2 * j * eta)
        eta1 -= b * math.cos(2 * j * xi) * math.sinh(2 * j * eta)
        sigma1 -= 2 * j * b * math.cos(2 * j * xi) * math.cosh(2 * j * eta)
        tau1 += 2 * j * b * math.sin(2 * j * xi) * math.sinh(2 * j * eta)
    chi = math.asin(math.sin(xi1) / math.cosh(eta1))
    lat = chi + sum(d * math.sin(2 * j * chi) for j, d in enumerate(_DELTA, start=1))
    lon = math.radians(zone.central_meridian_deg) + math.atan2(math.sinh(eta1), math.cos(xi1))
    # Karney (2011) eqs. 13-14 for the inverse series' convergence and scale
    tt = math.tan(xi1) * math.tanh(eta1)
    gamma = math.atan2(tau1 + sigma1 * tt, sigma1 - tau1 * tt)
    e2 = WGS84_F * (2.0 - WGS84_F)
    k = (UTM_K0 * _A_RECT_M / WGS84_A_M
         * math.sqrt((1.0 - e2 * math.sin(lat) ** 2)
                     * (math.cos(xi1) ** 2 + math.sinh(eta1) ** 2)
                     / (math.cos(lat) ** 2 * (sigma1 ** 2 + tau1 ** 2))))
    return GridPoint(math.degrees(lat), math.degrees(lon), gamma, k)


def grid_to_local(easting_m, northing_m, origin: GridPoint, origin_en: tuple[float, float]
                  ) -> tuple[np.ndarray, np.ndarray]:
    """UTM positions [m] to local ENU [m] at ``origin`` (see the module docstring).

    Args:
        easting_m, northing_m: arrays of grid positions.
        origin: :func:`utm_to_geodetic` of the first fix.
        origin_en: that fix's (easting, northing) [m].

    Returns:
        (east, north) [m] from the first fix.
    """
    de = (np.asarray(easting_m, float) - origin_en[0]) / origin.scale
    dn = (np.asarray(northing_m, float) - origin_en[1]) / origin.scale
    # grid north is `convergence` clockwise of true north: turn the grid vector clockwise by it
    c, s = math.cos(origin.convergence_rad), math.sin(origin.convergence_rad)
    return c * de + s * dn, -s * de + c * dn
