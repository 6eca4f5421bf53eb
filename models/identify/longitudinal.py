"""Accelerator models per speed zone: eq. 8 plus a brake term, chosen and fitted from a recording.

Per zone z (default idle [0, 2], low (2, 5], high (5, 20] m/s, the report's section V)::

    dv/dt = offset_z + scale_z * accel_pedal(t - tau) - brake_scale_z * brake_pedal(t - tau)

**Speed and zones.** The speed is eq. 1's v, the front-axle-centre speed, computed from the
front wheel speeds (``models.steering_id.road_wheel_angle_from_front``; it differs from the
four-wheel mean in tight turns), or the ``speed`` channel when wheel speeds are absent, or the
GNSS ground speed when both are (:func:`eq1_speed`). A sample
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
(``models.stats.matched_kernels``): the derivative of a speed obeying eq. 8 then equals eq. 8
applied to the smoothed pedals exactly, so smoothing biases nothing (the plain Savitzky-Golay
smoother would bias the brake scale by 2-6% at pedal steps: measured on the simulator);
``accel_x`` is smoothed with the same matched kernel.

**Choice of source** (:func:`choose_accel_source`, ``accel_source="auto"``): blocked
cross-validation over ``cv_folds`` contiguous folds. Each source gets its own pedal dead time
(a sensor latency shows there), and its zone fits, made without the fold, predict the
held-out acceleration measured by every other source; the score is the RMS of that error
beyond the other source's own fit [m/s^2]: how far its model is from the others'. A source
corrupted in a way the others are not (a wrong tyre radius, GNSS latency, an accelerometer's
pitch or lever arm) is far from the rest and scores worst. Among the sources whose
fold-paired excess over the best score is within fold-to-fold noise, the first of
:data:`SOURCE_ORDER` is chosen (wheel speeds first: they measure eq. 1's own speed; the GNSS
speed and ``accel_x`` are taken at their antenna or sensor point). Every other source is then
fitted like the chosen one and compared term by term (:func:`source_disagreements`): a zone on
which a source disagrees beyond the 95% intervals says so with the likely cause; it stays
identifiable only when another source corroborates the chosen one. Choice, scores and
disagreements are in ``report['selection']``.

**Dead time** (:func:`pedal_dead_time_cv`): blocked cross-validation of the zone fits over a
one-sample grid of pedal delays; a delay is used only when no delay predicts the held-out data
worse beyond fold-to-fold noise, and it is reported with its 95% held-out interval; otherwise
"not determined" and 0 is used.

**Term selection**: Fast Orthogonal Search (``models.fos``) chooses, per zone, among the
candidates 1, accel_pedal, brake_pedal (at the dead time), the pedals delayed a further
0.25 s and 0.5 s, v, v^2, accel_pedal * v, and ``accel_cmd`` when the recording has one (an
ACC request is not a pedal, but when it explains what the pedals do not, the report says so).
The selected terms, their error reductions and the FOS model's NMSE are reported; the written
eq. 8 keys come from ordinary least squares on [1, accel_pedal, brake_pedal] with 95%
intervals from ``models.stats.ols_hac`` (correlated residuals) widened by the pedal timing
bound (:func:`ols_timed`: when within a sample a pedal moved is not recorded).

**Metrics** (the report's section V-C): ``nmse_pct = 100 * MSE / variance of the measured
acceleration`` over the zone's samples, and ``speed_rmse_mps``, the RMS error of the speed
reconstructed by integrating the model from the measured speed at the start of every run of
zone samples (runs cut at ``segment_s``, the MPC horizon scale of the report).

**Identifiability**: a coefficient whose input is never exercised in a zone (pedal pressed for
less than ``min_pressed_s``) is not fitted; it is copied from the nearest zone that identified
it, or (brake only) set to ``brake_scale_prior_mps2``, and the zone is marked
``identifiable: false`` with a note. A zone with less than ``min_zone_s`` of usable samples is copied
from the nearest fitted zone and marked the same way. Without brake data (no channel, or the
pedal never pressed), a zone whose released-accelerator samples still decelerate beyond
coasting (:func:`braking_evidence`) says that the offset and scale absorb unobserved braking.
Every written value that the zone's own data did not determine (copied from another zone, the
prior, or absorbing unobserved braking) is listed with its reason, naming the zone it was copied
from, in ``report['not_identified']`` (``zones.<name>.<key>``), whether the zone was fitted or
not; ``models.identify.pipeline`` names them under the top-level ``not_identified``.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from hmpc.models.errors import InputError
from hmpc.models.identify.fos import fos
from hmpc.models.params import Vehicle, Zone
from hmpc.models.zones import zones_of_speed, zones_with_hysteresis
from hmpc.models.logs.recording import Recording
from hmpc.models.identify.stats import (apply_kernel, contiguous_fold_ids, dilate,
                                        half_sample_kernels, heldout_sse, matched_kernels,
                                        not_worse_than_best, ols_hac)
from hmpc.models.identify.steering import delayed, road_wheel_angle_from_front

#: default zones: the report's section V (name, v_min [m/s], v_max [m/s]).
DEFAULT_ZONES: tuple[tuple[str, float, float], ...] = (
    ("idle", 0.0, 2.0), ("low", 2.0, 5.0), ("high", 5.0, 20.0))
#: measured-acceleration sources, in the order of preference when held-out evidence does not
#: separate them (module doc, "Acceleration").
SOURCE_ORDER = ("wheel_speeds", "speed", "gps_speed", "accel_x")
ACCEL_SOURCES = ("auto",) + SOURCE_ORDER
#: the channel a source needs (named when it is absent)
_SOURCE_CHANNEL = {"wheel_speeds": "wheel_speed_fl", "speed": "speed", "gps_speed": "gps_speed",
                   "accel_x": "accel_x"}


@dataclass(frozen=True)
class LongitudinalIdConfig:
    """Settings of accelerator identification (the reason for each number in its comment)."""

    #: zones (name, v_min_mps, v_max_mps), contiguous; the first includes 0.
    zones: tuple[tuple[str, float, float], ...] = DEFAULT_ZONES
    #: [m/s] zone hysteresis for assigning samples (0: the report's sharp boundaries; set it to
    #: the plant's value when the data came from a plant with hysteresis).
    hysteresis_mps: float = 0.0
    #: "auto" (chosen by held-out evidence) or one of :data:`SOURCE_ORDER`; see the module doc.
    accel_source: str = "auto"
    #: contiguous folds of the blocked cross-validation (source choice, dead time): 5 keeps a
    #: minute-long recording's folds above 10 s, longer than the pedal responses.
    cv_folds: int = 5
    #: sources disagree when their 95% intervals are apart by more than this: [m/s^2] offset
    #: and [1] relative scale (under half of issue 3's 0.05 m/s^2 and 5%: below, the choice
    #: does not matter to the controller).
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


@dataclass
class ZoneFit:
    """Eq. 8 fit of one zone, its metrics and term selection."""

    zone: Zone
    fitted: bool
    report: dict
    a_model: np.ndarray = field(repr=False, default=None)


@dataclass
class LongitudinalResult:
    """Outcome of :func:`identify_longitudinal`: zones (``params.Zone``), dead time, report."""

    zones: list[Zone]
    dead_time_s: float
    accel_source: str
    report: dict
    series: dict = field(default_factory=dict, repr=False)


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


def _runs(mask: np.ndarray, max_len: int):
    idx = np.flatnonzero(np.diff(np.concatenate([[0], mask.astype(np.int8), [0]])))
    for s, e in zip(idx[::2], idx[1::2]):
        for a in range(s, e, max_len):
            yield a, min(a + max_len, e)


def speed_rmse(v_meas: np.ndarray, a_model: np.ndarray, mask: np.ndarray, dt_s: float,
               segment_s: float) -> float:
    """RMS error [m/s] of the speed integrated from ``a_model`` over runs of ``mask``.

    Each run (cut at ``segment_s``) starts from the measured speed; the integrated speed never
    goes below zero (no rolling backwards).
    """
    err = []
    n = max(int(round(segment_s / dt_s)), 2)
    for s, e in _runs(mask, n):
        if e - s < 2:
            continue
        a = a_model[s:e]
        v = v_meas[s] + np.concatenate([[0.0], np.cumsum(0.5 * dt_s * (a[1:] + a[:-1]))])
        v = np.maximum(v, 0.0)
        err.append(v - v_meas[s:e])
    if not err:
        return float("nan")
    e = np.concatenate(err)
    return float(np.sqrt(np.mean(e ** 2)))


def _pair(ci) -> tuple[float, float] | None:
    return None if ci is None else (float(ci[0]), float(ci[1]))


def _opt(x) -> float | None:
    """A finite Python float, or None (a parameter file holds no NaN)."""
    return float(x) if x is not None and np.isfinite(x) else None


def _nearest(i: int, candidates: list[int]) -> int | None:
    if not candidates:
        return None
    return min(candidates, key=lambda j: (abs(j - i), j))


def _nearest_fitted(i: int, fits, key: str) -> int | None:
    """The zone nearest to ``i`` whose fit produced ``key`` (a zone's value is copied from it)."""
    return _nearest(i, [k for k, g in enumerate(fits) if g.fitted and g.report[key] is not None])


def _rel_half_width(value: float, ci) -> float:
    """Half-width of the 95% interval relative to the value (inf for a zero value)."""
    return abs(0.5 * (ci[1] - ci[0]) / value) if value != 0 else float("inf")


@dataclass
class LongitudinalSignals:
    """What eq. 8 is fitted to: speed, measured acceleration and the raw pedals.

    Attributes:
        v: eq. 1's speed [m/s]; speed_src: where it came from (text).
        a_meas: measured acceleration [m/s^2]; accel_desc: how it was obtained (text).
        d_ker, g_ker: the matched derivative and smoothing kernels (``models.stats``).
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
class PedalDeadTime:
    """Pedal dead time: ``tau_s`` used [s], the held-out best ``estimate_s`` [s], its held-out
    residual reduction against no delay ``gain`` [1], ``note`` saying why 0 is used (None when
    the estimate is), the 95% held-out ``interval_s`` [s] (None: not determined) and the
    cross-validation figures ``cv``."""

    tau_s: float
    estimate_s: float
    gain: float
    note: str | None
    interval_s: tuple | None = None
    cv: dict = field(default_factory=dict)


@dataclass
class Pedals:
    """The pedals at the dead time (``ap``, ``bp``) and smoothed (``aps``, ``bps``) [0..1];
    ``alt``: the smoothed pair read half a sample earlier and later (``half_sample_kernels``)."""

    ap: np.ndarray
    bp: np.ndarray
    aps: np.ndarray
    bps: np.ndarray
    alt: tuple = ()


def identify_longitudinal(rec: Recording, vehicle: Vehicle,
                          config: LongitudinalIdConfig | None = None,
                          progress=None) -> LongitudinalResult:
    """Fit eq. 8 with brake per zone (see the module doc).

    Needs ``accel_pedal`` and a speed (front wheel speeds or ``speed``); ``brake_pedal`` when
    present (absent: brake terms are not identified).

    Raises:
        InputError: a required channel is absent, the accel source is unavailable, the zones
            are malformed, or no zone has enough samples.
    """
    cfg = config or LongitudinalIdConfig()
    say = progress or (lambda msg: None)
    zones = _check_config(cfg, rec.meta.get("path"))
    rec.require("accel_pedal")
    sig = longitudinal_signals(rec, vehicle, cfg)
    say("longitudinal: choosing the acceleration source by blocked cross-validation")
    lagged = lagged_pedals(sig, cfg)
    common = zone_masks(sig, zones, cfg, [a for a, _ in sig.candidates.values()])
    selection = choose_accel_source(sig, ~common.bad, common.zid, len(zones), lagged, cfg)
    deads = selection.pop("dead_times")
    sig.use(selection["chosen"])
    masks = zone_masks(sig, zones, cfg)
    dead = deads[sig.source] if np.array_equal(masks.bad, common.bad) else pedal_dead_time_cv(
        sig.a_meas, ~masks.bad, masks.zid, len(zones), lagged, cfg, sig.dt_s)
    ped = _pedals(sig, dead.tau_s)
    masks.bad |= ~(np.isfinite(ped.aps) & np.isfinite(ped.bps))
    say(f"longitudinal: acceleration from {sig.source} ({selection['because']}); pedal dead "
        f"time {dead.tau_s:.2f} s")
    names, P_all = fos_candidates(rec, sig, ped)
    fits = [fit_zone(zi, zone, sig, masks, ped, names, P_all, cfg)
            for zi, zone in enumerate(zones)]
    fitted = [i for i, f in enumerate(fits) if f.fitted]
    if not fitted:
        raise InputError("no speed zone has enough usable samples (moving, finite, inside one "
                         f"zone; need {cfg.min_zone_s:g} s per zone): cannot identify eq. 8",
                         rec.meta.get("path"), channel="accel_pedal")
    selection["disagreements"] = source_disagreements(sig, masks, fits, deads, cfg)
    for zi, f in enumerate(fits):
        if f.fitted:
            f.report["braking"] = braking_evidence(sig, masks, zi, f, cfg)
    out_zones = [zone_from_fit(i, fits, zones, cfg, sig.has_brake, rec.meta.get("path"),
                               selection["disagreements"])
                 for i in range(len(fits))]
    report = _report(sig, masks, dead, fits, zones, names, cfg)
    report["selection"] = selection
    report["not_identified"] = {f"zones.{f.report['name']}.{k}": why for f in fits
                                for k, why in f.report.get("not_identified", {}).items()}
    series = {"time": rec.time, "v_mps": sig.v, "a_meas_mps2": sig.a_meas,
              "accel_pedal": sig.ap_raw, "brake_pedal": sig.bp_raw if sig.has_brake else None,
              "zone": masks.zid, "used": ~masks.bad,
              "a_model_mps2": {zones[i][0]: f.a_model for i, f in enumerate(fits) if f.fitted}}
    return LongitudinalResult(out_zones, dead.tau_s, sig.accel_desc, report, series)


def _pedals(sig: LongitudinalSignals, tau_s: float) -> Pedals:
    """The pedals delayed by ``tau_s`` [s], smoothed with the matched kernel and with the two
    half-sample readings (``stats.half_sample_kernels``)."""
    dt = sig.dt_s
    ap, bp = delayed(sig.ap_raw, tau_s, dt), delayed(sig.bp_raw, tau_s, dt)
    alt = tuple((apply_kernel(ap, g), apply_kernel(bp, g))
                for g in half_sample_kernels(sig.d_ker, dt))
    return Pedals(ap, bp, sig.smooth(ap), sig.smooth(bp), alt)


def _check_config(cfg: LongitudinalIdConfig, path) -> list[tuple[str, float, float]]:
    """The zones as (name, v_min, v_max), checked contiguous from 0; the accel source checked."""
    zones = [(str(n), float(lo), float(hi)) for n, lo, hi in cfg.zones]
    if not zones:
        raise InputError("no speed zones given", path)
    for i, (n, lo, hi) in enumerate(zones):
        if not hi > lo or (i and abs(lo - zones[i - 1][2]) > 1e-9) or (i == 0 and lo != 0.0):
            raise InputError(f"zones must be contiguous from 0 m/s with v_max > v_min "
                             f"(zone {n!r}: {lo}..{hi})", path)
    if cfg.accel_source not in ACCEL_SOURCES:
        raise InputError(f"unknown accel source {cfg.accel_source!r} (one of "
                         f"{', '.join(ACCEL_SOURCES)})", path)
    return zones


def eq1_speed(rec: Recording, vehicle: Vehicle) -> tuple[np.ndarray, str]:
    """Eq. 1's speed v [m/s] and where it came from: the front-axle-centre speed from the front
    wheel speeds, else the CAN ``speed`` channel, else the GNSS ground speed.

    Raises:
        InputError: none of them is in the recording (naming ``wheel_speed_fl``).
    """
    if "wheel_speed_fl" in rec and "wheel_speed_fr" in rec:
        _, v = road_wheel_angle_from_front(rec["wheel_speed_fl"], rec["wheel_speed_fr"],
                                           vehicle.wheelbase_m, vehicle.track_front_m)
        return v, "front-axle-centre speed from the CAN front wheel speeds"
    if "speed" in rec:
        return np.asarray(rec["speed"], dtype=float), "CAN 'speed' channel"
    if "gps_speed" in rec:
        return np.asarray(rec["gps_speed"], dtype=float), "GNSS ground speed ('gps_speed')"
    raise InputError("no speed channel (front wheel speeds, 'speed' or 'gps_speed'): cannot "
                     "assign speed zones", rec.meta.get("path"), channel="wheel_speed_fl")


def accel_candidates(rec: Recording, v: np.ndarray, d_ker: np.ndarray, g_ker: np.ndarray,
                     dt: float) -> tuple[dict, dict]:
    """The measured accelerations the recording offers (module doc, "Acceleration"), each with
    its smoother: ``({source: (a [m/s^2], description)}, {source: why it is not a candidate})``
    in :data:`SOURCE_ORDER`."""
    sg = (f"Savitzky-Golay slope over {len(d_ker)} samples ({len(d_ker) * dt:.2f} s); "
          "regressors smoothed with the matched kernel")
    cands: dict[str, tuple[np.ndarray, str]] = {}
    skipped: dict[str, str] = {}
    has_wheels = "wheel_speed_fl" in rec and "wheel_speed_fr" in rec
    if has_wheels:
        cands["wheel_speeds"] = (apply_kernel(v, d_ker), "d/dt of the front-axle-centre speed "
                                 f"from the CAN front wheel speeds ({sg})")
    else:
        skipped["wheel_speeds"] = "no 'wheel_speed_fl'/'wheel_speed_fr' channel"
    if "speed" in rec and not has_wheels:
        cands["speed"] = (apply_kernel(np.asarray(rec["speed"], dtype=float), d_ker),
                          f"d/dt of the CAN 'speed' channel ({sg})")
    else:
        skipped["speed"] = ("the CAN 'speed' comes from the same wheel sensors as the wheel "
                            "speeds (not an independent source)" if has_wheels
                            else "no 'speed' channel")
    if "gps_speed" in rec:
        cands["gps_speed"] = (apply_kernel(np.asarray(rec["gps_speed"], dtype=float), d_ker),
                              f"d/dt of the GNSS ground speed ({sg})")
    else:
        skipped["gps_speed"] = "no 'gps_speed' channel"
    if "accel_x" in rec:
        cands["accel_x"] = (apply_kernel(np.asarray(rec["accel_x"], dtype=float), g_ker),
                            "accel_x channel (INS/IMU or the car's accelerometer, as ingested), "
                            f"smoothed with the same kernel as the regressors "
                            f"({len(g_ker) * dt:.2f} s)")
    else:
        skipped["accel_x"] = "no 'accel_x' channel"
    return cands, skipped


def longitudinal_signals(rec: Recording, vehicle: Vehicle,
                         cfg: LongitudinalIdConfig) -> LongitudinalSignals:
    """Speed (eq. 1's v), every candidate measured acceleration with its smoother, and the raw
    pedals (module doc). ``a_meas`` is set to the configured source, or to the first candidate
    until :func:`choose_accel_source` decides. Raises InputError for an absent channel."""
    dt = 1.0 / rec.rate_hz
    v, speed_src = eq1_speed(rec, vehicle)
    d_ker, g_ker = matched_kernels(dt, cfg.smooth_s)
    cands, skipped = accel_candidates(rec, v, d_ker, g_ker, dt)
    src = cfg.accel_source
    if src == "auto" and not cands:
        raise InputError("no acceleration source (wheel speeds, 'speed', 'gps_speed' or "
                         "'accel_x')", rec.meta.get("path"), channel="wheel_speed_fl")
    if src != "auto":
        if src not in cands:
            raise InputError(f"acceleration source '{src}' unavailable: {skipped[src]}",
                             rec.meta.get("path"), channel=_SOURCE_CHANNEL[src])
        cands = {src: cands[src]}
    first = next(iter(cands))
    has_brake = "brake_pedal" in rec
    ap_raw = np.asarray(rec["accel_pedal"], dtype=float)
    bp_raw = np.asarray(rec["brake_pedal"], dtype=float) if has_brake else np.zeros(len(rec))
    return LongitudinalSignals(v, speed_src, cands[first][0], cands[first][1], d_ker, g_ker,
                               ap_raw, bp_raw, has_brake, dt, first, cands, skipped)


def zone_masks(sig: LongitudinalSignals, zones, cfg: LongitudinalIdConfig,
               accels=None) -> ZoneMasks:
    """Zones by speed, and the samples usable for the fits: a sample is usable if its whole
    smoothing window shares its zone and is moving and finite (``sig.a_meas``, or every array
    of ``accels``)."""
    v, n = sig.v, len(sig.v)
    half = len(sig.d_ker) // 2 + 1
    zid = assign_zones(v, zones, cfg.hysteresis_mps)
    finite = np.isfinite(v) & np.isfinite(sig.ap_raw) & np.isfinite(sig.bp_raw)
    for a in ([sig.a_meas] if accels is None else accels):
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
    return [(sig.smooth(delayed(sig.ap_raw, lag * dt, dt)),
             sig.smooth(delayed(sig.bp_raw, lag * dt, dt)))
            for lag in range(int(round(cfg.dead_time_max_s / dt)) + 1)]


def _heldout_by_zone(pair, Y: np.ndarray, ok: np.ndarray, zid: np.ndarray,
                     n_zones: int, fold: np.ndarray, k: int, fit_col: int,
                     min_samples: int) -> np.ndarray:
    """Held-out SSE [k, columns of Y] of per-zone eq. 8 fits to the smoothed pedal ``pair``
    (``stats.heldout_sse``), summed over the zones with at least ``min_samples`` samples in
    ``ok``."""
    E = np.zeros((k, Y.shape[1]))
    for zi in range(n_zones):
        idx = np.flatnonzero(ok & (zid == zi))
        if len(idx) >= min_samples:
            X = np.column_stack([np.ones(len(idx)), pair[0][idx], -pair[1][idx]])
            E += heldout_sse(X, Y[idx], fold[idx], k, fit_col)[0]
    return E


def pedal_dead_time_cv(a_meas: np.ndarray, ok: np.ndarray, zid: np.ndarray, n_zones: int,
                       lagged: list, cfg: LongitudinalIdConfig, dt_s: float) -> PedalDeadTime:
    """The pedal dead time by blocked cross-validation over the one-sample lag grid.

    For each lag the zone fits are made on all but one of ``cv_folds`` contiguous folds and
    scored by the squared error on the held-out fold (the same samples ``ok`` for every lag).
    Against the best lag, each lag's fold-paired excess is tested (``stats.not_worse_than_best``):
    the 95% interval is the run of lags around the best not worse beyond that noise (half a
    sample wider at each end: the grid's resolution). A delay is used only when no delay is
    outside that run, the best lag is inside the grid, and it lowers the held-out error by at
    least ``dead_time_min_gain``; otherwise 0 is used and the note says why.
    """
    nan = float("nan")
    for pair in lagged:
        ok = ok & np.isfinite(pair[0]) & np.isfinite(pair[1])
    ok = ok & np.isfinite(a_meas)
    K = max(3, int(cfg.cv_folds))
    fold = contiguous_fold_ids(len(a_meas), K)
    y = np.where(ok, a_meas, 0.0)[:, None]
    E = np.array([_heldout_by_zone(p, y, ok, zid, n_zones, fold, K, 0,
                                   cfg.min_samples(dt_s))[:, 0] for p in lagged])
    keep = E.sum(axis=0) > 0
    if keep.sum() < 3:
        return PedalDeadTime(0.0, nan, 0.0, "no zone had enough samples to estimate it: "
                             "not determined, 0 used")
    E = E[:, keep]
    jb, within, crit = not_worse_than_best(E)
    lo = hi = jb
    while lo > 0 and within[lo - 1]:
        lo -= 1
    while hi < len(lagged) - 1 and within[hi + 1]:
        hi += 1
    mean = E.mean(axis=1)
    best = float(jb)
    if 0 < jb < len(lagged) - 1:
        den = mean[jb - 1] - 2 * mean[jb] + mean[jb + 1]
        if den > 0:
            best += 0.5 * (mean[jb - 1] - mean[jb + 1]) / den
    gain = float(1.0 - mean[jb] / mean[0]) if mean[0] > 0 else 0.0
    interval = ((lo - 0.5) * dt_s, (hi + 0.5) * dt_s)
    cv = {"folds": int(E.shape[1]), "samples": int(ok.sum()), "t_critical": crit,
          "heldout_rms_at_zero_mps2": float(np.sqrt(E[0].sum() / max(ok.sum(), 1))),
          "heldout_rms_at_best_mps2": float(np.sqrt(E[jb].sum() / max(ok.sum(), 1)))}
    tau = best * dt_s
    note = None
    if jb == len(lagged) - 1:
        note = (f"held-out error still falling at the search limit {cfg.dead_time_max_s:g} s: "
                "not determined, 0 used")
        interval = None
    elif within[0]:
        note = (f"no delay improves the held-out prediction beyond fold-to-fold noise (best "
                f"{tau:.2f} s, 95% interval {max(interval[0], 0.0):.2f}-{interval[1]:.2f} s "
                "includes 0): not determined, 0 used")
    elif gain < cfg.dead_time_min_gain:
        note = (f"a dead time of {tau:.2f} s lowers the held-out error by only "
                f"{100 * gain:.1f}% (< {100 * cfg.dead_time_min_gain:g}%): not determined, 0 used")
    return PedalDeadTime(0.0 if note else tau, tau, gain, note, interval, cv)


def choose_accel_source(sig: LongitudinalSignals, ok: np.ndarray, zid: np.ndarray,
                        n_zones: int, lagged: list, cfg: LongitudinalIdConfig) -> dict:
    """Score every candidate acceleration on held-out data and choose (module doc).

    Each candidate gets its own pedal dead time (:func:`pedal_dead_time_cv`; a sensor latency
    shows there). Over ``cv_folds`` contiguous folds, each candidate's zone fits, made without
    the fold, predict the held-out acceleration measured by every OTHER candidate (its own
    when it is alone); each channel's held-out RMS error is divided by that of the channel's
    own fit (its noise floor), and the score is the mean ratio (1 = as good as the channel's
    own model; lower is better). The chosen source is the first of :data:`SOURCE_ORDER` whose
    fold-paired excess over the best score is within fold-to-fold noise
    (``stats.not_worse_than_best``). Returns the selection report (JSON-ready) with
    ``dead_times`` ({source: :class:`PedalDeadTime`}) for the caller.
    """
    names = list(sig.candidates)
    Y = np.column_stack([sig.candidates[c][0] for c in names])
    ok = ok & np.all(np.isfinite(Y), axis=1)
    deads = {c: pedal_dead_time_cv(Y[:, j], ok, zid, n_zones, lagged, cfg, sig.dt_s)
             for j, c in enumerate(names)}
    for pair in lagged:
        ok = ok & np.isfinite(pair[0]) & np.isfinite(pair[1])
    K = max(3, int(cfg.cv_folds))
    fold = contiguous_fold_ids(len(Y), K)
    Yf = np.where(ok[:, None], Y, 0.0)
    E = {}
    for j, c in enumerate(names):
        lag = int(round(deads[c].tau_s / sig.dt_s))
        E[c] = _heldout_by_zone(lagged[lag], Yf, ok, zid, n_zones, fold, K, j,
                                cfg.min_samples(sig.dt_s))
    floor = {c: E[c][:, j] for j, c in enumerate(names)}
    cnt = np.maximum(np.bincount(fold[ok], minlength=K).astype(float), 1.0)
    scores, per_fold = {}, []
    for j, c in enumerate(names):
        others = [i for i, o in enumerate(names) if o != c] or [j]
        # excess held-out MSE over each other channel's own fit [(m/s^2)^2 per fold]
        ex = {names[i]: (E[c][:, i] - floor[names[i]]) / cnt for i in range(len(names))}
        per_fold.append(np.mean([ex[names[i]] for i in others], axis=0))
        mean_ex = float(per_fold[-1].mean())
        # the score clips a negative excess (this source's model predicts the others better
        # than their own fits do) to 0; the signed figure, sign(excess) * sqrt(|excess|),
        # still orders two sources that both clip
        scores[c] = {"score_mps2": float(np.sqrt(max(mean_ex, 0.0))),
                     "score_signed_mps2": float(math.copysign(math.sqrt(abs(mean_ex)), mean_ex))
                     if math.isfinite(mean_ex) else None,
                     "excess_rms_mps2": {o: float(np.sqrt(max(e.mean(), 0.0)))
                                         for o, e in ex.items()},
                     "dead_time_s": deads[c].tau_s, "dead_time_note": deads[c].note}
    n_ok = max(int(ok.sum()), 1)
    sel = {"candidates": names, "skipped": dict(sig.skipped), "folds": K, "samples": n_ok,
           "scores": scores,
           "noise_floor_rms_mps2": {c: float(np.sqrt(floor[c].sum() / n_ok)) for c in names},
           "method": (f"blocked cross-validation over {K} contiguous folds: each source's zone "
                      "fits (its own pedal dead time), made without the fold, predict the "
                      "held-out acceleration measured by every other source; score = RMS of "
                      "the held-out error beyond that source's own fit's error, averaged over "
                      "the other sources [m/s^2] (how far its model is from theirs; lower is "
                      "better, 0 = indistinguishable)"),
           "dead_times": deads}
    if len(names) == 1:
        forced = cfg.accel_source != "auto"
        sel.update(chosen=names[0], because=("set by the configuration (--accel-source)"
                                             if forced else "the only source in the recording"))
        return sel
    pf = np.array(per_fold)
    keep = np.all(np.isfinite(pf), axis=0)
    judged = keep.sum() >= 2
    jb, within, _ = not_worse_than_best(pf[:, keep]) if judged else (
        int(np.argmin([_key_signed(scores, c) for c in names])), None, 0.0)
    if within is None:
        within = np.arange(len(names)) == jb
    chosen = next(c for c in SOURCE_ORDER if c in names and within[names.index(c)])
    best = names[jb]
    tied = [c for c in SOURCE_ORDER if c in names and within[names.index(c)]]
    sel.update(chosen=chosen, because=_choice_because(chosen, best, tied, scores, judged),
               not_worse_than_best=[c for i, c in enumerate(names) if within[i]],
               tie=tied if len(tied) > 1 else [],
               tie_broken_by=("the order of preference (" + ", ".join(SOURCE_ORDER) + ")"
                              if len(tied) > 1 else None))
    return sel


def _key_signed(scores: dict, c: str) -> float:
    """Sort key: a source's signed held-out score (inf when there is none)."""
    x = scores[c].get("score_signed_mps2")
    return math.inf if x is None else x


def _signed(scores: dict, c: str) -> str:
    """A source's signed held-out score, with enough digits to tell two apart [m/s^2]."""
    x = scores[c].get("score_signed_mps2")
    return "n/a" if x is None else f"{x:+.4f}"


def _choice_because(chosen: str, best: str, tied: list[str], scores: dict,
                    judged: bool = True) -> str:
    """Why ``chosen`` was chosen: alone ahead of the rest beyond fold-to-fold noise, or a tie
    within noise broken by :data:`SOURCE_ORDER` (then every tied source and its signed score
    is named, so equal printed scores never pass for a decision)."""
    if len(tied) <= 1:
        others = sorted((c for c in scores if c != chosen), key=lambda c: _key_signed(scores, c))
        nxt = "" if not others else (
            f"; next {others[0]} {_signed(scores, others[0])} m/s^2, "
            + ("worse beyond fold-to-fold noise" if judged else
               "too few folds to judge fold-to-fold noise"))
        return f"lowest held-out score (signed {_signed(scores, chosen)} m/s^2{nxt})"
    listed = ", ".join(f"{c} {_signed(scores, c)}" for c in tied)
    lowest = ("it also has the lowest mean" if chosen == best else
              f"the lowest mean is {best}'s")
    return (f"tie within fold-to-fold noise between {listed} m/s^2 (signed held-out scores; "
            f"negative: predicts the other sources better than their own fits); broken by the "
            f"order of preference ({', '.join(SOURCE_ORDER)}): {chosen} is first, {lowest}")


def fos_candidates(rec: Recording, sig: LongitudinalSignals,
                   ped: Pedals) -> tuple[list[str], np.ndarray]:
    """The FOS candidate terms (module doc), smoothed: their names and matrix [N, M]."""
    n, dt, smooth = len(sig.v), sig.dt_s, sig.smooth
    cand = {"1": np.ones(n), "accel_pedal": ped.aps, "brake_pedal": ped.bps}
    for extra in (0.25, 0.5):
        cand[f"accel_pedal(t-{extra:g}s)"] = smooth(delayed(ped.ap, extra, dt))
        cand[f"brake_pedal(t-{extra:g}s)"] = smooth(delayed(ped.bp, extra, dt))
    cand["v"] = smooth(sig.v)
    cand["v^2"] = smooth(sig.v * sig.v)
    cand["accel_pedal*v"] = smooth(ped.ap * sig.v)
    if "accel_cmd" in rec:
        cand["accel_cmd"] = smooth(np.asarray(rec["accel_cmd"], dtype=float))
    names = list(cand)
    return names, np.column_stack([cand[k] for k in names])


def _zone_design(aps: np.ndarray, bps: np.ndarray, use_a: bool, use_b: bool) -> np.ndarray:
    """Eq. 8's columns [1, accel_pedal (if used), -brake_pedal (if used)]."""
    return np.column_stack([np.ones(len(aps))] + ([aps] if use_a else [])
                           + ([-bps] if use_b else []))


def ols_timed(X: np.ndarray, alt_X: list, y: np.ndarray, m: np.ndarray):
    """OLS with 95% intervals = the HAC interval (``stats.ols_hac``) widened by the pedal
    timing bound: the largest coefficient change when the pedal columns are read half a sample
    earlier or later (``alt_X``; ``stats.half_sample_kernels``). The recording does not say
    when within a sample a pedal moved; on hmpc's simulator (pedal held at 100 Hz, recorded at
    50 Hz) that ambiguity alone moved the idle-zone scale by 0.2-0.4%, more than its HAC
    half-width, so intervals without it missed the truth. Returns (``OlsResult``, intervals
    [(low, high)], statistical half-widths, timing half-widths)."""
    r = ols_hac(X, y, m)
    sys_hw = np.zeros(len(r.coef))
    for Xa in alt_X:
        ma = m & np.all(np.isfinite(Xa), axis=1) & np.isfinite(y)
        if ma.sum() > 2 * X.shape[1]:
            ca = np.linalg.lstsq(Xa[ma], y[ma], rcond=None)[0]
            sys_hw = np.maximum(sys_hw, np.abs(ca - r.coef))
    stat_hw = r.crit * r.se
    ci = [(float(c - h1 - h2), float(c + h1 + h2)) for c, h1, h2 in zip(r.coef, stat_hw, sys_hw)]
    return r, ci, stat_hw, sys_hw


def fit_zone(zi: int, zone, sig: LongitudinalSignals, masks: ZoneMasks, ped: Pedals,
             names: list[str], P_all: np.ndarray, cfg: LongitudinalIdConfig) -> ZoneFit:
    """Eq. 8 by OLS with HAC intervals on one zone's usable samples, its metrics and the FOS
    term selection; a pedal term only when the pedal was pressed ``min_pressed_s`` in the zone.
    Not fitted (``fitted`` False) with less than ``min_zone_s`` of usable samples."""
    zname, lo, hi = zone
    dt, v, a_meas, n = sig.dt_s, sig.v, sig.a_meas, len(sig.v)
    m = ~masks.bad & (masks.zid == zi)
    nz = int(m.sum())
    in_zone = np.isfinite(v) & (masks.zid == zi) & ~masks.standstill
    rep: dict = {"name": zname, "v_min_mps": lo, "v_max_mps": hi, "samples": nz,
                 "seconds_in_zone": float(in_zone.sum() * dt),
                 "samples_excluded": int(in_zone.sum() - nz)}
    if nz < cfg.min_samples(dt):
        rep["not_fitted_because"] = (f"no usable data ({nz} samples, {nz * dt:.1f} s; "
                                     f"{cfg.min_zone_s:g} s needed)")
        rep["note"] = f"{rep['not_fitted_because']}: not identified"
        return ZoneFit(None, False, rep)
    pressed_a = float(np.sum(m & (ped.ap > cfg.pressed)) * dt)
    pressed_b = float(np.sum(m & (ped.bp > cfg.pressed)) * dt)
    rep["accel_pedal_pressed_s"], rep["brake_pedal_pressed_s"] = pressed_a, pressed_b
    use_a = pressed_a >= cfg.min_pressed_s
    use_b = sig.has_brake and pressed_b >= cfg.min_pressed_s
    X = _zone_design(ped.aps, ped.bps, use_a, use_b)
    r, ci, stat_hw, sys_hw = ols_timed(X, [_zone_design(a, b, use_a, use_b) for a, b in ped.alt],
                                       a_meas, m)
    coef, ci = list(r.coef), list(ci)
    off, off_ci = coef.pop(0), ci.pop(0)
    sc, sc_ci = (coef.pop(0), ci.pop(0)) if use_a else (None, None)
    br, br_ci = (coef.pop(0), ci.pop(0)) if use_b else (None, None)
    a_fit = X @ r.coef
    resid = a_meas[m] - a_fit[m]
    var = float(np.var(a_meas[m]))
    nmse = 100.0 * float(np.mean(resid ** 2)) / var if var > 0 else float("nan")
    # model acceleration from the unsmoothed (delayed) pedals, for the speed reconstruction
    a_raw = off + (sc or 0.0) * np.nan_to_num(ped.ap) - (br or 0.0) * np.nan_to_num(ped.bp)
    srmse = speed_rmse(v, a_raw, m, dt, cfg.segment_s)
    rep.update({
        "offset_mps2": off, "offset_ci95_mps2": list(off_ci),
        "scale_mps2": sc, "scale_ci95_mps2": None if sc_ci is None else list(sc_ci),
        "brake_scale_mps2": br,
        "brake_scale_ci95_mps2": None if br_ci is None else list(br_ci),
        "nmse_pct": nmse, "speed_rmse_mps": srmse,
        "accel_rms_mps2": float(np.sqrt(np.mean(a_meas[m] ** 2))),
        "residual_rms_mps2": float(np.sqrt(np.mean(resid ** 2))),
        "ci_method": r.method + " + half-sample pedal timing bound",
        "ci_statistical_half_width": [float(x) for x in stat_hw],
        "ci_timing_half_width": [float(x) for x in sys_hw],
        "fos": _fos_report(m, a_meas, names, P_all, dt, cfg),
    })
    return ZoneFit(None, True, rep, a_fit)


def _fos_report(m: np.ndarray, a_meas: np.ndarray, names: list[str], P_all: np.ndarray,
                dt: float, cfg: LongitudinalIdConfig) -> dict | None:
    """FOS term selection on a zone's samples ``m`` (None with fewer than 20 complete rows).

    Candidates missing on more than 10% of the zone's samples are left out (e.g. an ACC
    request that is only sent while the ACC is engaged), then rows with a gap.
    """
    fin = np.isfinite(P_all[m])
    keep = [j for j in range(len(names)) if fin[:, j].mean() >= 0.9]
    mf = m & np.all(np.isfinite(P_all[:, keep]), axis=1)
    if mf.sum() < 20:
        return None
    # hold-out blocks of fos_block_s, shortened so that even a short zone keeps some
    block = max(min(int(round(cfg.fos_block_s / dt)), int(mf.sum()) // 8), 5)
    Pz = P_all[np.ix_(mf, keep)]
    fr = fos(Pz, a_meas[mf], [names[j] for j in keep], force=["1"],
             max_terms=cfg.fos_max_terms, block_len=block)
    var_f = float(np.var(a_meas[mf]))
    return {**fr.to_dict(), "samples": int(mf.sum()),
            "nmse_pct": 100.0 * float(np.mean((a_meas[mf] - fr.predict(Pz)) ** 2))
            / var_f if var_f > 0 else None,
            "candidates_left_out": [names[j] for j in range(len(names)) if j not in keep]}


def zone_from_fit(i: int, fits: list[ZoneFit], zones, cfg: LongitudinalIdConfig,
                  has_brake: bool, path, disagreements: dict | None = None) -> Zone:
    """Zone ``i``'s written ``params.Zone``, with fallbacks for what its data did not exercise
    (module doc); sets ``fits[i].zone`` and the report's identifiable, note and written keys.

    Raises:
        InputError: the accelerator was never pressed long enough in any zone.
    """
    f, (zname, lo, hi) = fits[i], zones[i]
    rep = f.report
    fitted = [k for k, g in enumerate(fits) if g.fitted]
    notes = []
    ident = f.fitted
    # every written value that the zone's own data did not determine (copied from another
    # zone, or the prior) is named here with its reason, fitted zone or not (CONVENTIONS:
    # ``not_identified:``; ``identify_longitudinal`` collects them)
    rep.setdefault("not_identified", {})
    if not f.fitted:
        j = _nearest(i, fitted)
        off = fits[j].report["offset_mps2"]
        why = f"{rep['not_fitted_because']}: copied from zone '{zones[j][0]}'"
        rep["not_identified"]["offset_mps2"] = why
        notes.append(f"{rep['not_fitted_because']}: offset copied from zone '{zones[j][0]}'")
        rep_off_ci = None
    else:
        off = rep["offset_mps2"]
        rep_off_ci = rep["offset_ci95_mps2"]
        if 0.5 * (rep_off_ci[1] - rep_off_ci[0]) > cfg.max_offset_ci_mps2:
            ident = False
            notes.append(f"offset known only to +-{0.5 * (rep_off_ci[1] - rep_off_ci[0]):.2f} "
                         "m/s^2")
    sc, sc_ci, sc_ok = _zone_scale(i, fits, zones, cfg, path, notes)
    br, br_ci, br_ok = _zone_brake_scale(i, fits, zones, cfg, has_brake, notes)
    ident = ident and sc_ok and br_ok
    dis = (disagreements or {}).get("zones", {}).get(zname)
    if dis and dis["disagree"]:
        if dis["corroborated_by"]:
            notes.append(f"{', '.join(dis['disagree'])} disagree(s) with {dis['chosen']} beyond "
                         f"the intervals ({dis['likely_cause']}); {dis['chosen']} is "
                         f"corroborated by {', '.join(dis['corroborated_by'])}")
        else:
            ident = False
            notes.append(f"NOT identifiable: the acceleration sources disagree beyond their "
                         f"intervals ({dis['chosen']} against {', '.join(dis['disagree'])}; "
                         f"likely cause: {dis['likely_cause']})")
    note = "; ".join(notes) if notes else None
    z = Zone(name=zname, v_min_mps=float(lo), v_max_mps=float(hi), offset_mps2=float(off),
             scale_mps2=float(sc), brake_scale_mps2=float(br),
             offset_ci95_mps2=_pair(rep_off_ci), scale_ci95_mps2=_pair(sc_ci),
             brake_scale_ci95_mps2=_pair(br_ci), nmse_pct=_opt(rep.get("nmse_pct")),
             speed_rmse_mps=_opt(rep.get("speed_rmse_mps")),
             samples=float(rep["samples"]), identifiable=bool(ident), note=note)
    f.zone = z
    rep["identifiable"] = bool(ident)
    rep["note"] = note
    rep["written"] = {"offset_mps2": z.offset_mps2, "scale_mps2": z.scale_mps2,
                      "brake_scale_mps2": z.brake_scale_mps2}
    return z


def source_disagreements(sig: LongitudinalSignals, masks: ZoneMasks, fits: list[ZoneFit],
                         deads: dict, cfg: LongitudinalIdConfig) -> dict:
    """Each other candidate source fitted like the chosen one (same zones, samples and terms,
    its own dead time) and compared term by term: two sources disagree on a term when their
    95% intervals are apart by more than ``agree_offset_mps2`` (offset) or ``agree_scale_rel``
    of the chosen value (scales). Per zone: the disagreeing sources, the corroborating ones
    (no term apart), and the likely cause (:func:`_likely_cause`). JSON-ready."""
    out: dict = {"zones": {}, "statements": []}
    chosen = sig.source
    for c in [c for c in sig.candidates if c != chosen]:
        a_c = sig.candidates[c][0]
        ped = _pedals(sig, deads[c].tau_s)
        for zi, f in enumerate(fits):
            if not f.fitted:
                continue
            rep = f.report
            use_a, use_b = rep["scale_mps2"] is not None, rep["brake_scale_mps2"] is not None
            m = ~masks.bad & (masks.zid == zi) & np.isfinite(a_c)
            m &= np.isfinite(ped.aps) & np.isfinite(ped.bps)
            if m.sum() < cfg.min_samples(sig.dt_s):
                continue
            X = _zone_design(ped.aps, ped.bps, use_a, use_b)
            r, ci, _, _ = ols_timed(X, [_zone_design(a, b, use_a, use_b) for a, b in ped.alt],
                                    a_c, m)
            terms = ["offset_mps2"] + (["scale_mps2"] if use_a else []) + \
                (["brake_scale_mps2"] if use_b else [])
            apart = {}
            for k, term in enumerate(terms):
                ref, ref_ci = rep[term], rep[term.replace("_mps2", "_ci95_mps2")]
                gap = max(ci[k][0] - ref_ci[1], ref_ci[0] - ci[k][1], 0.0)
                tol = cfg.agree_offset_mps2 if k == 0 else cfg.agree_scale_rel * abs(ref)
                if gap > tol:
                    apart[term] = {chosen: [ref, list(ref_ci)], c: [float(r.coef[k]), list(ci[k])]}
            z = out["zones"].setdefault(rep["name"], {"chosen": chosen, "disagree": [],
                                                      "corroborated_by": [], "terms": {},
                                                      "likely_cause": ""})
            if apart:
                z["disagree"].append(c)
                z["terms"][c] = apart
                cause = _likely_cause(chosen, c, deads, apart, sig.dt_s)
                z["likely_cause"] = "; ".join(x for x in (z["likely_cause"], cause) if x)
                out["statements"].append(
                    f"zone {rep['name']}: {c} disagrees with {chosen} on "
                    f"{', '.join(apart)} beyond the 95% intervals; likely cause: {cause}")
            else:
                z["corroborated_by"].append(c)
    return out


def _likely_cause(chosen: str, other: str, deads: dict, apart: dict, dt_s: float) -> str:
    """The physical reason two acceleration sources most plausibly differ, from the pattern
    of their difference (a delay, a common scale ratio, an offset)."""
    causes = []
    d_tau = deads[other].tau_s - deads[chosen].tau_s
    if abs(d_tau) >= 2 * dt_s:
        late = other if d_tau > 0 else chosen
        causes.append(f"{late} lags by {abs(d_tau):.2f} s (sensor latency)")
    pair = {chosen, other}
    ratios = [v[other][0] / v[chosen][0] for t, v in apart.items()
              if t != "offset_mps2" and v[chosen][0]]
    if ratios and pair & {"wheel_speeds", "speed"}:
        causes.append(f"a speed scale error (tyre radius or wheel-speed calibration: scale "
                      f"ratio {other}/{chosen} {np.mean(ratios):.3f})")
    if "accel_x" in pair:
        causes.append("accel_x is the INS/IMU point's acceleration: sensor pitch or road grade "
                      "shifts its offset, and a point away from the front axle adds "
                      "centripetal acceleration in turns")
    if "gps_speed" in pair and not causes:
        causes.append("the GNSS speed is the antenna point's speed (it differs from the "
                      "front-axle speed in turns) and lags by its latency")
    return "; ".join(causes) or "unknown (the sources differ beyond their intervals)"


def braking_evidence(sig: LongitudinalSignals, masks: ZoneMasks, zi: int, f: ZoneFit,
                     cfg: LongitudinalIdConfig) -> dict:
    """Seconds in zone ``zi`` with the accelerator released and a deceleration more than
    ``braking_evidence_mps2`` below the zone's fitted offset (coasting): braking that eq. 8
    must explain, observed or not."""
    m = ~masks.bad & (masks.zid == zi) & (np.nan_to_num(sig.ap_raw) < cfg.pressed)
    off = f.report["offset_mps2"]
    decel = m & (sig.a_meas < off - cfg.braking_evidence_mps2)
    return {"released_s": float(m.sum() * sig.dt_s),
            "decel_beyond_coasting_s": float(decel.sum() * sig.dt_s),
            "threshold_mps2": cfg.braking_evidence_mps2}


def _zone_scale(i: int, fits: list[ZoneFit], zones, cfg: LongitudinalIdConfig, path,
                notes: list[str]):
    """Zone ``i``'s throttle scale, its interval and whether it is identified; a zone that did
    not fit it copies the nearest zone's. Appends the reason to ``notes``."""
    f = fits[i]
    rep = f.report
    sc = rep.get("scale_mps2") if f.fitted else None
    sc_ci = rep.get("scale_ci95_mps2") if f.fitted else None
    if sc is None:
        j = _nearest_fitted(i, fits, "scale_mps2")
        if j is None:
            raise InputError("the accelerator pedal is never pressed long enough in any zone "
                             f"(need {cfg.min_pressed_s} s): cannot identify eq. 8",
                             path, channel="accel_pedal")
        sc = fits[j].report["scale_mps2"]
        why = (f"accelerator pressed only {rep['accel_pedal_pressed_s']:.1f} s "
               f"({cfg.min_pressed_s:g} s needed)" if f.fitted else rep["not_fitted_because"])
        rep["not_identified"]["scale_mps2"] = f"{why}: copied from zone '{zones[j][0]}'"
        notes.append(f"{why}: scale copied from zone '{zones[j][0]}'" if f.fitted else
                     f"scale copied from zone '{zones[j][0]}'")
        return sc, sc_ci, False
    if _rel_half_width(sc, sc_ci) > cfg.max_rel_ci:
        notes.append(f"scale known only to +-{100 * _rel_half_width(sc, sc_ci):.0f}%"
                     if sc != 0 else "scale is zero")
        return sc, sc_ci, False
    return sc, sc_ci, True


def _zone_brake_scale(i: int, fits: list[ZoneFit], zones, cfg: LongitudinalIdConfig,
                      has_brake: bool, notes: list[str]):
    """Zone ``i``'s brake scale, its interval and whether it is identified; a zone that did not
    fit it copies the nearest zone's, or the prior when none did. Appends the reason to
    ``notes``."""
    f = fits[i]
    rep = f.report
    br = rep.get("brake_scale_mps2") if f.fitted else None
    br_ci = rep.get("brake_scale_ci95_mps2") if f.fitted else None
    if br is None:
        j = _nearest_fitted(i, fits, "brake_scale_mps2")
        why = ("no brake_pedal channel" if not has_brake else
               f"brake pressed only {rep['brake_pedal_pressed_s']:.1f} s" if f.fitted else
               rep["not_fitted_because"])
        ni = rep["not_identified"]
        ev = rep.get("braking") or {}
        if ev.get("decel_beyond_coasting_s", 0.0) >= cfg.min_pressed_s:
            absorbed = (f"the car decelerated {ev['decel_beyond_coasting_s']:.1f} s more than "
                        f"{ev['threshold_mps2']:g} m/s^2 below coasting with the accelerator "
                        "released: braking (pedal or ACC) that no channel observes, which the "
                        "offset and scale absorb")
            ni["offset_mps2"] = ni["scale_mps2"] = f"{why}: {absorbed}"
            why = f"{why}, yet {absorbed}"
        if j is not None:
            br = fits[j].report["brake_scale_mps2"]
            ni["brake_scale_mps2"] = f"{why}: copied from zone '{zones[j][0]}'"
            notes.append(f"{why + ': ' if f.fitted else ''}brake scale copied from zone "
                         f"'{zones[j][0]}'")
        else:
            br = cfg.brake_scale_prior_mps2
            ni["brake_scale_mps2"] = (f"{why}; no zone identified it: the prior "
                                      f"{cfg.brake_scale_prior_mps2:g} m/s^2")
            notes.append(f"{why + ' (in every zone): ' if f.fitted else ''}brake scale is the "
                         f"prior {cfg.brake_scale_prior_mps2:g} m/s^2, not identified"
                         + ("" if f.fitted else " in any zone"))
        return br, br_ci, False
    if _rel_half_width(br, br_ci) > cfg.max_rel_ci:
        notes.append(f"brake scale known only to +-{100 * _rel_half_width(br, br_ci):.0f}%"
                     if br != 0 else "brake scale is zero")
        return br, br_ci, False
    return br, br_ci, True


def _report(sig: LongitudinalSignals, masks: ZoneMasks, dead: PedalDeadTime,
            fits: list[ZoneFit], zones, names: list[str], cfg: LongitudinalIdConfig) -> dict:
    """The JSON-ready report of :func:`identify_longitudinal`."""
    dt, v = sig.dt_s, sig.v
    n_above = int(masks.above.sum())
    standing = masks.standstill & np.isfinite(v)
    return {
        "accel_source": sig.accel_desc,
        "speed_source": sig.speed_src,
        "dead_time_s": dead.tau_s,
        "dead_time_method": (f"blocked cross-validation ({cfg.cv_folds} folds) over a "
                             "one-sample lag grid; used only when no delay is worse beyond "
                             "fold-to-fold noise"),
        "dead_time_estimate_s": dead.estimate_s,
        "dead_time_ci95_s": None if dead.interval_s is None else list(dead.interval_s),
        "dead_time_residual_reduction": dead.gain,
        "dead_time_note": dead.note,
        "dead_time_cv": dead.cv,
        "zones": [f.report for f in fits],
        "above_last_zone": {"samples": n_above, "seconds": float(n_above * dt),
                            "v_max_mps": zones[-1][2],
                            "note": "not fitted (no zone model above the last zone)"},
        "standstill": {"samples": int(np.sum(standing)),
                       "seconds": float(np.sum(standing) * dt),
                       "v_stop_mps": cfg.v_stop_mps,
                       "note": "excluded: the car is held, acceleration clamped at zero"},
        "boundary_samples_excluded": int(np.sum(masks.boundary & ~masks.base_bad)),
        "hysteresis_mps": cfg.hysteresis_mps,
        "smooth_s": cfg.smooth_s,
        "fos_candidates": names,
    }
