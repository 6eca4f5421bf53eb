"""The longitudinal channels of a recording on its grid (:class:`LonData`), and which of their
samples a longitudinal fit (``models.diagnose.longitudinal.fit``) may use: moving, measured,
with a finite design row, and not where the speed zone is ambiguous (near a zone change, or at
a zone boundary)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.signal import lfilter

from hmpc.models.constants import G_MPS2
from hmpc.models.diagnose.common import DiagnoseConfig
from hmpc.models.diagnose.lon_inputs import COMMANDS


@dataclass
class LonData:
    """Longitudinal channels on the recording grid (NaN where missing)."""

    t: np.ndarray
    dt: float
    v: np.ndarray  #: measured speed [m/s]
    vs: np.ndarray  #: smoothed speed [m/s]
    a: np.ndarray  #: measured dv/dt [m/s^2]
    U: np.ndarray  #: inputs [n, m]
    input_names: list[str]
    idle: np.ndarray  #: throttle released (bool)
    grade: np.ndarray | None  #: measured grade [rad]
    grade_source: str
    zones: tuple
    segs: list[tuple[int, int]]
    ok: np.ndarray  #: samples inside a usable segment
    _grade_cache: dict = field(default_factory=dict, repr=False)
    #: [s] the inputs' timing against the speed applied to ``U`` (:func:`input_alignment`)
    input_shift_s: float = 0.0
    #: input channels the recording does not hold (``lon_inputs.choose_inputs``)
    absent_inputs: list = field(default_factory=list)
    input_notes: list = field(default_factory=list)
    #: gear index per sample (-1: unknown) and the gears found (``models.diagnose.gears``)
    gear: np.ndarray | None = None
    gear_info: dict = field(default_factory=dict)
    #: what depends on the fields above alone, computed once (a copy made with
    #: ``dataclasses.replace`` starts empty)
    _memo: dict = field(default_factory=dict, init=False, repr=False, compare=False)

    @property
    def commanded(self) -> bool:
        """The car follows a command (an ACC's acceleration request or a by-wire speed
        command: a controller of its own closes the loop)."""
        return any(c in self.input_names for c in COMMANDS)

    @property
    def tracking(self) -> np.ndarray:
        """Per input column: a speed command (regressor ``speed_cmd - v``)."""
        return np.array([nm == "speed_cmd" for nm in self.input_names], bool)

    @property
    def command_cols(self) -> np.ndarray:
        """Per input column: a command (what ``actuator_saturation`` clips)."""
        return np.array([nm in COMMANDS for nm in self.input_names], bool)

    def grade_accel(self, rate_per_s: float) -> np.ndarray:
        """g sin(theta) [m/s^2] the car has not compensated: all of it (``rate_per_s`` 0), or
        what a compensation F = 1 / (T s + 1), T = 1 / rate, has not yet caught up with (per
        segment, starting compensated)."""
        key = round(float(rate_per_s), 6)
        if key not in self._grade_cache:
            assert self.grade is not None  # asked for only with a grade
            gs = G_MPS2 * np.sin(self.grade)
            if key > 0:
                al = 1.0 - np.exp(-self.dt * key)
                out = np.full_like(gs, np.nan)
                for a, b in self.segs:
                    x = gs[a:b]
                    out[a:b] = x - lfilter([al], [1.0, al - 1.0], x, zi=[(1.0 - al) * x[0]])[0]
                gs = out
            self._grade_cache[key] = gs
        return self._grade_cache[key]

    @property
    def n(self) -> int:
        return len(self.t)


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
