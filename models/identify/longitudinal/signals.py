"""What eq. 8 is fitted to: speed, zones, measured acceleration and pedals.

**Speed and zones.** The speed is eq. 1's v, the front-axle-centre speed, computed from the
front wheel speeds (``models.identify.steering.road_wheel_angle_from_front``; it differs from
the four-wheel mean in tight turns), or the ``speed`` channel when wheel speeds are absent, or
the GNSS ground speed when both are (:func:`eq1_speed`). A sample
belongs to the zone whose (v_min, v_max] holds its speed (the first zone includes 0), with
optional hysteresis as the plant's ``select_zone``. Zone boundaries: a sample is used only if
every sample of its smoothing window lies in the same zone, so no acceleration estimate mixes
two zone models. Standstill: samples below ``v_stop_mps`` (and their smoothing windows) are
excluded, because at rest the car is held (by the brake or in P) and its acceleration is
clamped at zero whatever eq. 8 says. Speeds above the last zone are counted and reported
(samples and seconds), never silently dropped; they are not fitted.

**Acceleration** (``accel_source``): the candidates are every source the recording has:
``wheel_speeds`` (the Savitzky-Golay slope, a local least-squares derivative over
``smooth_s``, of the front-axle-centre speed: exactly the quantity the plant integrates),
``speed`` (the same slope of the CAN ``speed``; a candidate only without wheel speeds, since it
comes from the same sensors), ``gps_speed`` (the slope of the GNSS ground speed) and
``accel_x`` (the recording's longitudinal acceleration: INS, IMU or the car's accelerometer).
Every regressor is smoothed with the kernel *matched* to the derivative filter
(``models.identify.stats.matched_kernels``): the derivative of a speed obeying eq. 8 then
equals eq. 8 applied to the smoothed pedals exactly, so smoothing biases nothing (the plain
Savitzky-Golay smoother would bias the brake scale at pedal steps); ``accel_x`` is smoothed
with the same matched kernel. Which candidate is used is decided in ``sources``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from hmpc.models.errors import InputError
from hmpc.models.params import Vehicle
from hmpc.models.zones import zones_of_speed, zones_with_hysteresis
from hmpc.models.logs.recording import Recording
from hmpc.models.identify.stats import apply_kernel, dilate, half_sample_kernels, matched_kernels
from hmpc.models.identify.steering import delayed, road_wheel_angle_from_front
from hmpc.models.identify.longitudinal.config import _SOURCE_CHANNEL, LongitudinalIdConfig


@dataclass
class LongitudinalSignals:
    """What eq. 8 is fitted to: speed, measured acceleration and the raw pedals.

    Attributes:
        v: eq. 1's speed [m/s]; speed_src: where it came from (text).
        a_meas: measured acceleration [m/s^2]; accel_desc: how it was obtained (text).
        d_ker, g_ker: the matched derivative and smoothing kernels (``models.identify.stats``).
        ap_raw, bp_raw: accelerator and brake pedal [0..1] (brake zeros when absent).
        has_brake: the recording has ``brake_pedal``; dt_s: sample interval [s].
        source: the source of ``a_meas`` (a key of :data:`SOURCE_ORDER`).
        candidates: every candidate source -> (acceleration [m/s^2], description).
        skipped: the sources that are not candidates -> why.
    """

    v: np.ndarray
    speed_src: str
    a_meas: np.ndarray
    accel_desc: str
    d_ker: np.ndarray
    g_ker: np.ndarray
    ap_raw: np.ndarray
    bp_raw: np.ndarray
    has_brake: bool
    dt_s: float
    source: str = ""
    candidates: dict = field(default_factory=dict, repr=False)
    skipped: dict = field(default_factory=dict)

    def use(self, source: str) -> None:
        """Make ``source`` the measured acceleration."""
        self.source = source
        self.a_meas, self.accel_desc = self.candidates[source]

    def smooth(self, x) -> np.ndarray:
        """``x`` smoothed with the kernel matched to the derivative filter."""
        return apply_kernel(x, self.g_ker)


@dataclass
class ZoneMasks:
    """Zone of each sample and which samples the fits may use (module doc).

    Attributes:
        zid: zone index per sample (-1: none); standstill: below ``v_stop_mps``;
        above: faster than the last zone; boundary: within a smoothing window of a zone change;
        base_bad: not finite, standing or in no zone; bad: excluded from the fits (``base_bad``
            dilated by the smoothing window, or ``boundary``; pedals not finite after the delay).
    """

    zid: np.ndarray
    standstill: np.ndarray
    above: np.ndarray
    boundary: np.ndarray
    base_bad: np.ndarray
    bad: np.ndarray


@dataclass
class Pedals:
    """The pedals at the dead time (``ap``, ``bp``) and smoothed (``aps``, ``bps``) [0..1];
    ``alt``: the smoothed pair read half a sample earlier and later (``half_sample_kernels``)."""

    ap: np.ndarray
    bp: np.ndarray
    aps: np.ndarray
    bps: np.ndarray
    alt: tuple = ()


def assign_zones(v_mps: np.ndarray, zones, hysteresis_mps: float = 0.0) -> np.ndarray:
    """Zone index per sample: (v_min, v_max], first zone includes 0; -1 above the last zone
    and for NaN. With hysteresis h, a sample stays in the previous sample's zone while v is
    within [v_min - h, v_max + h]. The zone rule is the plant's (``models.plant``), without
    its clamp: above the last zone is no zone here."""
    vmin = [z[1] for z in zones]
    vmax = [z[2] for z in zones]
    if hysteresis_mps <= 0:
        return zones_of_speed(v_mps, vmax)
    return zones_with_hysteresis(v_mps, vmin, vmax, hysteresis_mps)


def _pedals(sig: LongitudinalSignals, tau_s: float) -> Pedals:
    """The pedals delayed by ``tau_s`` [s], smoothed with the matched kernel and with the two
    half-sample readings (``stats.half_sample_kernels``)."""
    dt = sig.dt_s
    ap, bp = delayed(sig.ap_raw, tau_s, dt), delayed(sig.bp_raw, tau_s, dt)
    alt = tuple(
        (apply_kernel(ap, g), apply_kernel(bp, g)) for g in half_sample_kernels(sig.d_ker, dt)
    )
    return Pedals(ap, bp, sig.smooth(ap), sig.smooth(bp), alt)


def eq1_speed(rec: Recording, vehicle: Vehicle) -> tuple[np.ndarray, str]:
    """Eq. 1's speed v [m/s] and where it came from: the front-axle-centre speed from the front
    wheel speeds, else the CAN ``speed`` channel, else the GNSS ground speed.

    Raises:
        InputError: none of them is in the recording (naming ``wheel_speed_fl``).
    """
    if "wheel_speed_fl" in rec and "wheel_speed_fr" in rec:
        _, v = road_wheel_angle_from_front(
            rec["wheel_speed_fl"], rec["wheel_speed_fr"], vehicle.wheelbase_m, vehicle.track_front_m
        )
        return v, "front-axle-centre speed from the CAN front wheel speeds"
    if "speed" in rec:
        return np.asarray(rec["speed"], dtype=float), "CAN 'speed' channel"
    if "gps_speed" in rec:
        return np.asarray(rec["gps_speed"], dtype=float), "GNSS ground speed ('gps_speed')"
    raise InputError(
        "no speed channel (front wheel speeds, 'speed' or 'gps_speed'): cannot assign speed zones",
        rec.meta.get("path"),
        channel="wheel_speed_fl",
    )


def accel_candidates(
    rec: Recording, v: np.ndarray, d_ker: np.ndarray, g_ker: np.ndarray, dt: float
) -> tuple[dict, dict]:
    """The measured accelerations the recording offers (module doc, "Acceleration"), each with
    its smoother: ``({source: (a [m/s^2], description)}, {source: why it is not a candidate})``
    in :data:`SOURCE_ORDER`."""
    sg = (
        f"Savitzky-Golay slope over {len(d_ker)} samples ({len(d_ker) * dt:.2f} s); "
        "regressors smoothed with the matched kernel"
    )
    cands: dict[str, tuple[np.ndarray, str]] = {}
    skipped: dict[str, str] = {}
    has_wheels = "wheel_speed_fl" in rec and "wheel_speed_fr" in rec
    if has_wheels:
        cands["wheel_speeds"] = (
            apply_kernel(v, d_ker),
            f"d/dt of the front-axle-centre speed from the CAN front wheel speeds ({sg})",
        )
    else:
        skipped["wheel_speeds"] = "no 'wheel_speed_fl'/'wheel_speed_fr' channel"
    if "speed" in rec and not has_wheels:
        cands["speed"] = (
            apply_kernel(np.asarray(rec["speed"], dtype=float), d_ker),
            f"d/dt of the 'speed' channel ({sg})",
        )
    else:
        skipped["speed"] = (
            "the CAN 'speed' comes from the same wheel sensors as the wheel "
            "speeds (not an independent source)"
            if has_wheels
            else "no 'speed' channel"
        )
    if "gps_speed" in rec:
        cands["gps_speed"] = (
            apply_kernel(np.asarray(rec["gps_speed"], dtype=float), d_ker),
            f"d/dt of the GNSS ground speed ({sg})",
        )
    else:
        skipped["gps_speed"] = "no 'gps_speed' channel"
    if "accel_x" in rec:
        cands["accel_x"] = (
            apply_kernel(np.asarray(rec["accel_x"], dtype=float), g_ker),
            "accel_x channel (INS/IMU or the car's accelerometer, as ingested), "
            f"smoothed with the same kernel as the regressors "
            f"({len(g_ker) * dt:.2f} s)",
        )
    else:
        skipped["accel_x"] = "no 'accel_x' channel"
    return cands, skipped


def longitudinal_signals(
    rec: Recording, vehicle: Vehicle, cfg: LongitudinalIdConfig
) -> LongitudinalSignals:
    """Speed (eq. 1's v), every candidate measured acceleration with its smoother, and the raw
    pedals (module doc). ``a_meas`` is set to the configured source, or to the first candidate
    until :func:`choose_accel_source` decides. Raises InputError for an absent channel."""
    has_brake = "brake_pedal" in rec
    ap_raw = np.asarray(rec["accel_pedal"], dtype=float)
    bp_raw = np.asarray(rec["brake_pedal"], dtype=float) if has_brake else np.zeros(len(rec))
    return signals_with_inputs(
        rec,
        vehicle,
        cfg,
        ap_raw,
        bp_raw,
        has_brake,
        no_source=(
            "no acceleration source (wheel speeds, 'speed', 'gps_speed' or 'accel_x')",
            "wheel_speed_fl",
        ),
    )


def signals_with_inputs(
    rec: Recording,
    vehicle: Vehicle,
    cfg: LongitudinalIdConfig,
    ap_raw: np.ndarray,
    bp_raw: np.ndarray,
    has_brake: bool,
    *,
    no_source: tuple[str, str],
) -> LongitudinalSignals:
    """:class:`LongitudinalSignals` for the given raw inputs (the pedals, or a command in
    ``ap_raw`` with no brake term): speed, the candidate accelerations the configuration
    allows, the first of them as ``a_meas``. ``no_source``: the error text and channel named
    when the recording has no acceleration source."""
    dt = 1.0 / rec.rate_hz
    v, speed_src = eq1_speed(rec, vehicle)
    d_ker, g_ker = matched_kernels(dt, cfg.smooth_s)
    cands, skipped = accel_candidates(rec, v, d_ker, g_ker, dt)
    src = cfg.accel_source
    if src == "auto" and not cands:
        raise InputError(no_source[0], rec.meta.get("path"), channel=no_source[1])
    if src != "auto":
        if src not in cands:
            raise InputError(
                f"acceleration source '{src}' unavailable: {skipped[src]}",
                rec.meta.get("path"),
                channel=_SOURCE_CHANNEL[src],
            )
        cands = {src: cands[src]}
    first = next(iter(cands))
    return LongitudinalSignals(
        v,
        speed_src,
        cands[first][0],
        cands[first][1],
        d_ker,
        g_ker,
        ap_raw,
        bp_raw,
        has_brake,
        dt,
        first,
        cands,
        skipped,
    )


def zone_masks(
    sig: LongitudinalSignals, zones, cfg: LongitudinalIdConfig, accels=None
) -> ZoneMasks:
    """Zones by speed, and the samples usable for the fits: a sample is usable if its whole
    smoothing window shares its zone and is moving and finite (``sig.a_meas``, or every array
    of ``accels``)."""
    v, n = sig.v, len(sig.v)
    half = len(sig.d_ker) // 2 + 1
    zid = assign_zones(v, zones, cfg.hysteresis_mps)
    finite = np.isfinite(v) & np.isfinite(sig.ap_raw) & np.isfinite(sig.bp_raw)
    for a in [sig.a_meas] if accels is None else accels:
        finite &= np.isfinite(a)
    standstill = np.nan_to_num(v, nan=0.0) < cfg.v_stop_mps
    above = np.isfinite(v) & (v > zones[-1][2])
    change = np.zeros(n, dtype=bool)
    change[1:] = zid[1:] != zid[:-1]
    boundary = dilate(change, half, half)
    base_bad = ~finite | standstill | (zid < 0)
    bad = dilate(base_bad, half, half) | boundary
    return ZoneMasks(zid, standstill, above, boundary, base_bad, bad)


def lagged_pedals(sig: LongitudinalSignals, cfg: LongitudinalIdConfig) -> list:
    """The smoothed pedals (accelerator, brake) delayed by 0, 1, ... samples up to
    ``dead_time_max_s``: the lag grid of the dead time and the source choice."""
    dt = sig.dt_s
    return [
        (
            sig.smooth(delayed(sig.ap_raw, lag * dt, dt)),
            sig.smooth(delayed(sig.bp_raw, lag * dt, dt)),
        )
        for lag in range(int(round(cfg.dead_time_max_s / dt)) + 1)
    ]
