"""Which samples a longitudinal fit (``models.diagnose.longitudinal.fit``) may use: moving,
measured, with a finite design row, and not where the speed zone is ambiguous (near a zone
change, or at a zone boundary)."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from hmpc.models.diagnose.common import DiagnoseConfig

if TYPE_CHECKING:
    from hmpc.models.diagnose.longitudinal import LonData


def near_zone_change(zone: np.ndarray, dt: float) -> np.ndarray:
    """Samples whose derivative window spans a zone change: the measured dv/dt there mixes two
    zones' models (eq. 8 jumps at a boundary), so the fit leaves them out."""
    ch = np.concatenate([[False], zone[1:] != zone[:-1]])
    w = int(DiagnoseConfig.deriv_window_s / dt) | 1
    return np.convolve(ch.astype(float), np.ones(w), mode="same") > 0


#: [m/s] half-width of the speed band around a zone boundary whose samples the fit leaves out:
#: which zone's law acts there is not known to better than this (the recorded speed is a mean
#: of wheel speeds, the law's speed another point of the car: 2-3 % apart in turns, 0.05-0.1
#: m/s at the 2 and 5 m/s boundaries; plus the smoothing). Where the two zones' accelerations
#: have opposite signs with the pedals released (a creeping car: idle offset > 0 > low offset)
#: the car settles AT the boundary, its speed chattering between the zones, and its measured
#: acceleration there (about 0) is neither zone's law: fitted as one zone it pulls that zone's
#: offset (independent recordings, truth C: 14 s coasting at 2 m/s moved the low-zone offset
#: by 0.02 m/s^2, and a v-dependent creep term then "explained" 11-16 % of a clean replay)
ZONE_EDGE_BAND_MPS = 0.1


def at_zone_edge(d: LonData) -> np.ndarray:
    """Samples whose smoothed speed is within :data:`ZONE_EDGE_BAND_MPS` of a zone boundary."""
    edges = np.array([z[2] for z in d.zones[:-1]])
    if edges.size == 0:
        return np.zeros(d.n, bool)
    return (np.abs(d.vs[:, None] - edges[None, :]) < ZONE_EDGE_BAND_MPS).any(axis=1)


def fit_samples(d: LonData, X: np.ndarray, zone: np.ndarray) -> np.ndarray:
    """The samples a zone fit may use: moving, measured, with a finite design row, and not
    where the zone is ambiguous (near a zone change, or at a zone boundary)."""
    return usable(d, zone) & np.isfinite(X).all(axis=1)


def usable(d: LonData, zone: np.ndarray) -> np.ndarray:
    """:func:`fit_samples` before the design row's own check (the same for every fit with this
    zone per sample, so computed once)."""
    key = ("usable", zone.tobytes())
    if key not in d._memo:
        d._memo[key] = (
            d.ok
            & (d.vs > DiagnoseConfig.v_stop_mps)
            & np.isfinite(d.a)
            & ~near_zone_change(zone, d.dt)
            & ~at_zone_edge(d)
        )
    return d._memo[key]
