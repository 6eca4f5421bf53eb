"""Settings of accelerator identification (:class:`LongitudinalIdConfig`, the reason for each
number beside it), the default zones and the measured-acceleration sources, and the check of
the configured zones. Imports hmpc.models.errors only.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from hmpc.models.errors import InputError


#: default zones: the report's section V (name, v_min [m/s], v_max [m/s]).
DEFAULT_ZONES: tuple[tuple[str, float, float], ...] = (
    ("idle", 0.0, 2.0),
    ("low", 2.0, 5.0),
    ("high", 5.0, 20.0),
)
#: [m] the wheelbase the default zones were set for: the report's car (a passenger car).
REFERENCE_WHEELBASE_M = 2.65


def zones_for_vehicle(vehicle) -> tuple[tuple[str, float, float], ...]:
    """:data:`DEFAULT_ZONES` scaled to a vehicle shorter than :data:`REFERENCE_WHEELBASE_M`.

    By dynamic similarity (equal Froude number v^2 / (g b), as the steering thresholds of
    ``models.identify.steering.config``), a car of wheelbase b drives like the reference at
    speeds scaled by sqrt(b / 2.65 m): a 1:10 model car (0.33 m) covers the report's three
    zones between 0 and 7.1 m/s. Boundaries are rounded to two significant digits (they are a
    choice, not a measurement); a vehicle at least as long keeps the report's zones.
    """
    f = min(1.0, float(vehicle.wheelbase_m) / REFERENCE_WHEELBASE_M)
    if f >= 1.0:
        return DEFAULT_ZONES

    def two_digits(x: float) -> float:
        return float(f"{x:.2g}") if x > 0 else 0.0

    return tuple(
        (n, two_digits(lo * math.sqrt(f)), two_digits(hi * math.sqrt(f)))
        for n, lo, hi in DEFAULT_ZONES
    )


#: measured-acceleration sources, in the order of preference when held-out evidence does not
#: separate them (``sources``, "Choice of source").
SOURCE_ORDER = ("wheel_speeds", "speed", "gps_speed", "accel_x")
ACCEL_SOURCES = ("auto",) + SOURCE_ORDER
#: the channel a source needs (named when it is absent)
_SOURCE_CHANNEL = {
    "wheel_speeds": "wheel_speed_fl",
    "speed": "speed",
    "gps_speed": "gps_speed",
    "accel_x": "accel_x",
}


@dataclass(frozen=True)
class LongitudinalIdConfig:
    """Settings of accelerator identification (the reason for each number in its comment)."""

    #: zones (name, v_min_mps, v_max_mps), contiguous; the first includes 0.
    zones: tuple[tuple[str, float, float], ...] = DEFAULT_ZONES
    #: [m/s] zone hysteresis for assigning samples (0: the report's sharp boundaries; set it to
    #: the plant's value when the data came from a plant with hysteresis).
    hysteresis_mps: float = 0.0
    #: "auto" (chosen by held-out evidence) or one of :data:`SOURCE_ORDER`; see ``signals`` and
    #: ``sources``.
    accel_source: str = "auto"
    #: contiguous folds of the blocked cross-validation (source choice, dead time): 5 keeps a
    #: minute-long recording's folds above 10 s, longer than the pedal responses.
    cv_folds: int = 5
    #: sources disagree when their 95% intervals are apart by more than this: [m/s^2] offset
    #: and [1] relative scale (under half of the zone coefficients' acceptance tolerances,
    #: 0.05 m/s^2 and 5%: below, the choice does not matter to the controller).
    agree_offset_mps2: float = 0.02
    agree_scale_rel: float = 0.02
    #: [m/s^2] with no brake channel, a released accelerator with a deceleration this far below
    #: the zone's coasting offset is taken as unobserved braking (drag and engine braking are
    #: inside the offset; 0.5 m/s^2 is several times the residual of a coasting car).
    braking_evidence_mps2: float = 0.5
    #: [s] Savitzky-Golay window: 0.5 s averages the 0.01 km/h wheel-speed steps and 0.02 km/h
    #: edge jitter down to ~0.02 m/s^2 while keeping pedal responses (~1 s) intact.
    smooth_s: float = 0.5
    #: [m/s] below this the car is treated as standing (wheel-speed sensors of many cars read
    #: zero below a few tenths of a m/s, and a held car does not follow eq. 8).
    v_stop_mps: float = 0.2
    #: [s] pedal dead-time search range.
    dead_time_max_s: float = 1.0
    #: [1] a dead time is used only if it lowers the pooled residual by this fraction.
    dead_time_min_gain: float = 0.01
    #: [s] least usable data for a zone fit (100 samples at 50 Hz, 20 at 10 Hz: a duration,
    #: so that a recording's rate does not decide whether a zone is fitted; the intervals and
    #: the identifiability flags say how little that is).
    min_zone_s: float = 2.0
    #: [s] a pedal must be pressed (> ``pressed``) this long in a zone for its coefficient.
    min_pressed_s: float = 2.0
    #: [1] pedal fraction counted as pressed (above the 0.5 % quantisation step).
    pressed: float = 0.02
    #: [1] relative half-width of a pedal coefficient's 95% interval above which it is not
    #: called identifiable.
    max_rel_ci: float = 0.25
    #: [m/s^2] half-width of the offset's 95% interval above which it is not identifiable.
    max_offset_ci_mps2: float = 0.1
    #: [m/s^2] brake scale used when no zone's data exercises the brake: a full pedal stops a
    #: passenger car at about 0.8 g on dry asphalt. Always flagged as not identified.
    brake_scale_prior_mps2: float = 8.0
    #: [s] longest run integrated from one measured speed for speed_rmse_mps (the report's MPC
    #: horizon is 10-15 s).
    segment_s: float = 10.0
    #: FOS settings: most terms, hold-out block length [s].
    fos_max_terms: int = 6
    fos_block_s: float = 5.0

    def min_samples(self, dt_s: float) -> int:
        """Fewest usable samples of a zone fit at sample period ``dt_s`` [s] (``min_zone_s``,
        and never below 10: three coefficients and their intervals)."""
        return max(10, int(math.ceil(self.min_zone_s / dt_s - 1e-9)))


def _check_config(cfg: LongitudinalIdConfig, path) -> list[tuple[str, float, float]]:
    """The zones as (name, v_min, v_max), checked contiguous from 0; the accel source checked."""
    zones = [(str(n), float(lo), float(hi)) for n, lo, hi in cfg.zones]
    if not zones:
        raise InputError("no speed zones given", path)
    for i, (n, lo, hi) in enumerate(zones):
        if not hi > lo or (i and abs(lo - zones[i - 1][2]) > 1e-9) or (i == 0 and lo != 0.0):
            raise InputError(
                f"zones must be contiguous from 0 m/s with v_max > v_min (zone {n!r}: {lo}..{hi})",
                path,
            )
    if cfg.accel_source not in ACCEL_SOURCES:
        raise InputError(
            f"unknown accel source {cfg.accel_source!r} (one of {', '.join(ACCEL_SOURCES)})", path
        )
    return zones
