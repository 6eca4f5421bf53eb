"""Accelerator models per speed zone: eq. 8 plus a brake term, chosen and fitted from a recording.

Per zone z (default idle [0, 2], low (2, 5], high (5, 20] m/s, the report's section V)::

    dv/dt = offset_z + scale_z * accel_pedal(t - tau) - brake_scale_z * brake_pedal(t - tau)

**Speed and zones.** The speed is eq. 1's v, the front-axle-centre speed, computed from the
front wheel speeds (``models.steering_id.road_wheel_angle_from_front``; it differs from the
four-wheel mean in tight turns), or the ``speed`` channel when wheel speeds are absent. A sample
belongs to the zone whose (v_min, v_max] holds its speed (the first zone includes 0), with
optional hysteresis as the plant's ``select_zone``. Zone boundaries: a sample is used only if
every sample of its smoothing window lies in the same zone, so no acceleration estimate mixes
two zone models. Standstill: samples below ``v_stop_mps`` (and their smoothing windows) are
excluded, because at rest the car is held (by the brake or in P) and its acceleration is
clamped at zero whatever eq. 8 says. Speeds above the last zone are counted and reported
(samples and seconds), never silently dropped; they are not fitted.

**Acceleration** (``accel_source``): by default the Savitzky-Golay slope (local least-squares
derivative over ``smooth_s``) of that speed: it is exactly the quantity the plant integrates,
with no gravity, grade, mount or body-pitch terms. ``"accel_x"`` uses the recording's
longitudinal acceleration (INS, IMU or the car's own accelerometer, whichever ingest chose);
``"gps_speed"`` differentiates the GNSS ground speed. Every regressor is smoothed with the
kernel *matched* to the derivative filter (``models.stats.matched_kernels``): the derivative of
a speed obeying eq. 8 then equals eq. 8 applied to the smoothed pedals exactly, so smoothing
biases nothing (the plain Savitzky-Golay smoother would bias the brake scale by 2-6% at pedal
steps: measured on the simulator). ``"accel_x"`` is smoothed with the same matched kernel.

**Dead time**: the pedal dead time tau [s] minimises the pooled residual of the zone fits over
a grid of delays (one grid step = one sample).

**Term selection**: Fast Orthogonal Search (``models.fos``) chooses, per zone, among the
candidates 1, accel_pedal, brake_pedal (at the dead time), the pedals delayed a further
0.25 s and 0.5 s, v, v^2, accel_pedal * v, and ``accel_cmd`` when the recording has one (an
ACC request is not a pedal, but when it explains what the pedals do not, the report says so).
The selected terms, their error reductions and the FOS model's NMSE are reported; the written
eq. 8 keys come from ordinary least squares on [1, accel_pedal, brake_pedal] with intervals
from ``models.stats.ols_hac`` (correlated residuals).

**Metrics** (the report's section V-C): ``nmse_pct = 100 * MSE / variance of the measured
acceleration`` over the zone's samples, and ``speed_rmse_mps``, the RMS error of the speed
reconstructed by integrating the model from the measured speed at the start of every run of
zone samples (runs cut at ``segment_s``, the MPC horizon scale of the report).

**Identifiability**: a coefficient whose input is never exercised in a zone (pedal pressed for
less than ``min_pressed_s``) is not fitted; it is copied from the nearest zone that identified
it, or (brake only) set to ``brake_scale_prior_mps2``, and the zone is marked
``identifiable: false`` with a note. A zone with fewer than ``min_samples`` samples is copied
from the nearest fitted zone and marked the same way.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from hmpc.models.errors import InputError
from hmpc.models.identify.fos import fos
from hmpc.models.params import Vehicle, Zone
from hmpc.models.plant import zones_of_speed, zones_with_hysteresis
from hmpc.models.logs.recording import Recording
from hmpc.models.identify.stats import apply_kernel, dilate, matched_kernels, ols_hac
from hmpc.models.identify.steering import delayed, road_wheel_angle_from_front

#: default zones: the report's section V (name, v_min [m/s], v_max [m/s]).
DEFAULT_ZONES: tuple[tuple[str, float, float], ...] = (
    ("idle", 0.0, 2.0), ("low", 2.0, 5.0), ("high", 5.0, 20.0))
ACCEL_SOURCES = ("auto", "speed", "accel_x", "gps_speed")


@dataclass(frozen=True)
class LongitudinalIdConfig:
    """Settings of accelerator identification (the reason for each number in its comment)."""

    #: zones (name, v_min_mps, v_max_mps), contiguous; the first includes 0.
    zones: tuple[tuple[str, float, float], ...] = DEFAULT_ZONES
    #: [m/s] zone hysteresis for assigning samples (0: the report's sharp boundaries; set it to
    #: the plant's value when the data came from a plant with hysteresis).
    hysteresis_mps: float = 0.0
    #: "auto" (= "speed"), "speed", "accel_x" or "gps_speed"; see the module doc.
    accel_source: str = "auto"
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
    #: [samples] fewest usable samples for a zone fit (2 s at 50 Hz; the intervals and the
    #: identifiability flags say how little that is).
    min_samples: int = 100
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
    """Pedal dead time: ``tau_s`` used [s], the grid search's ``estimate_s`` [s] and residual
    reduction ``gain`` [1], and ``note`` saying why 0 is used (None when the estimate is)."""

    tau_s: float
    estimate_s: float
    gain: float
    note: str | None


@dataclass
class Pedals:
    """The pedals at the dead time (``ap``, ``bp``) and smoothed (``aps``, ``bps``) [0..1]."""

    ap: np.ndarray
    bp: np.ndarray
    aps: np.ndarray
    bps: np.ndarray


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
    masks = zone_masks(sig, zones, cfg)
    say("longitudinal: estimating the pedal dead time")
    dead = estimate_pedal_dead_time(sig, masks.bad, masks.zid, len(zones), cfg)
    dt = sig.dt_s
    ap, bp = delayed(sig.ap_raw, dead.tau_s, dt), delayed(sig.bp_raw, dead.tau_s, dt)
    ped = Pedals(ap, bp, sig.smooth(ap), sig.smooth(bp))
    masks.bad |= ~(np.isfinite(ped.aps) & np.isfinite(ped.bps))
    say(f"longitudinal: pedal dead time {dead.tau_s:.2f} s; acceleration from {sig.accel_desc}")
    names, P_all = fos_candidates(rec, sig, ped)
    fits = [fit_zone(zi, zone, sig, masks, ped, names, P_all, cfg)
            for zi, zone in enumerate(zones)]
    fitted = [i for i, f in enumerate(fits) if f.fitted]
    if not fitted:
        raise InputError("no speed zone has enough usable samples (moving, finite, inside one "
                         f"zone; need {cfg.min_samples} per zone): cannot identify eq. 8",
                         rec.meta.get("path"), channel="accel_pedal")
    out_zones = [zone_from_fit(i, fits, zones, cfg, sig.has_brake, rec.meta.get("path"))
                 for i in range(len(fits))]
    report = _report(sig, masks, dead, fits, zones, names, cfg)
    series = {"time": rec.time, "v_mps": sig.v, "a_meas_mps2": sig.a_meas,
              "accel_pedal": sig.ap_raw, "brake_pedal": sig.bp_raw if sig.has_brake else None,
              "zone": masks.zid, "used": ~masks.bad,
              "a_model_mps2": {zones[i][0]: f.a_model for i, f in enumerate(fits) if f.fitted}}
    return LongitudinalResult(out_zones, dead.tau_s, sig.accel_desc, report, series)


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


def longitudinal_signals(rec: Recording, vehicle: Vehicle,
                         cfg: LongitudinalIdConfig) -> LongitudinalSignals:
    """Speed (eq. 1's v), the measured acceleration by ``cfg.accel_source`` with the matching
    smoother, and the raw pedals (module doc). Raises InputError for an absent channel."""
    dt = 1.0 / rec.rate_hz
    if "wheel_speed_fl" in rec and "wheel_speed_fr" in rec:
        _, v = road_wheel_angle_from_front(rec["wheel_speed_fl"], rec["wheel_speed_fr"],
                                           vehicle.wheelbase_m, vehicle.track_front_m)
        speed_src = "front-axle-centre speed from the CAN front wheel speeds"
    else:
        rec.require("speed")
        v = np.asarray(rec["speed"], dtype=float)
        speed_src = "CAN 'speed' channel"
    d_ker, g_ker = matched_kernels(dt, cfg.smooth_s)
    src = "speed" if cfg.accel_source == "auto" else cfg.accel_source
    sg = (f"Savitzky-Golay slope over {len(d_ker)} samples ({len(d_ker) * dt:.2f} s); "
          "regressors smoothed with the matched kernel")
    if src == "speed":
        a_meas = apply_kernel(v, d_ker)
        accel_desc = f"d/dt of the {speed_src} ({sg})"
    elif src == "accel_x":
        rec.require("accel_x")
        a_meas = apply_kernel(rec["accel_x"], g_ker)
        accel_desc = f"accel_x channel (INS/IMU or the car's accelerometer, as ingested), " \
                     f"smoothed with the same kernel as the regressors ({len(g_ker) * dt:.2f} s)"
    else:
        rec.require("gps_speed")
        a_meas = apply_kernel(rec["gps_speed"], d_ker)
        accel_desc = f"d/dt of the GNSS ground speed ({sg})"
    has_brake = "brake_pedal" in rec
    ap_raw = np.asarray(rec["accel_pedal"], dtype=float)
    bp_raw = np.asarray(rec["brake_pedal"], dtype=float) if has_brake else np.zeros(len(rec))
    return LongitudinalSignals(v, speed_src, a_meas, accel_desc, d_ker, g_ker, ap_raw, bp_raw,
                               has_brake, dt)


def zone_masks(sig: LongitudinalSignals, zones, cfg: LongitudinalIdConfig) -> ZoneMasks:
    """Zones by speed, and the samples usable for the fits: a sample is usable if its whole
    smoothing window shares its zone and is moving and finite."""
    v, n = sig.v, len(sig.v)
    half = len(sig.d_ker) // 2 + 1
    zid = assign_zones(v, zones, cfg.hysteresis_mps)
    finite = (np.isfinite(v) & np.isfinite(sig.a_meas) & np.isfinite(sig.ap_raw)
              & np.isfinite(sig.bp_raw))
    standstill = np.nan_to_num(v, nan=0.0) < cfg.v_stop_mps
    above = np.isfinite(v) & (v > zones[-1][2])
    change = np.zeros(n, dtype=bool)
    change[1:] = zid[1:] != zid[:-1]
    boundary = dilate(change, half, half)
    base_bad = ~finite | standstill | (zid < 0)
    bad = dilate(base_bad, half, half) | boundary
    return ZoneMasks(zid, standstill, above, boundary, base_bad, bad)


def estimate_pedal_dead_time(sig: LongitudinalSignals, bad: np.ndarray, zid: np.ndarray,
                             n_zones: int, cfg: LongitudinalIdConfig) -> PedalDeadTime:
    """The pedal dead time minimising the pooled per-zone OLS residual over a grid of delays
    (one sample per step); 0 with a note when the minimum is at the search limit, gains less
    than ``dead_time_min_gain``, or no zone has enough samples."""
    dt = sig.dt_s
    lags = np.arange(0, int(round(cfg.dead_time_max_s / dt)) + 1)
    sse = np.full(len(lags), np.inf)
    for k, lag in enumerate(lags):
        apd = sig.smooth(delayed(sig.ap_raw, lag * dt, dt))
        bpd = sig.smooth(delayed(sig.bp_raw, lag * dt, dt))
        ok = ~bad & np.isfinite(apd) & np.isfinite(bpd)
        tot = 0.0
        for zi in range(n_zones):
            m = ok & (zid == zi)
            if m.sum() < cfg.min_samples:
                continue
            X = np.column_stack([np.ones(m.sum()), apd[m], bpd[m]])
            coef, *_ = np.linalg.lstsq(X, sig.a_meas[m], rcond=None)
            tot += float(np.sum((sig.a_meas[m] - X @ coef) ** 2))
        sse[k] = tot
    if not (np.isfinite(sse).all() and sse[0] > 0):
        return PedalDeadTime(0.0, float("nan"), 0.0,
                             "no zone had enough samples to estimate it: 0 used")
    k_best = int(np.argmin(sse))
    gain = 1.0 - sse[k_best] / sse[0]
    tau = float(lags[k_best] * dt)
    note = None
    if k_best == len(lags) - 1:
        note = (f"residual still falling at the search limit {cfg.dead_time_max_s:g} s: "
                "dead time not determined, 0 used")
    elif gain < cfg.dead_time_min_gain:
        note = (f"a dead time of {tau:.2f} s lowers the residual by only "
                f"{100 * gain:.1f}% (< {100 * cfg.dead_time_min_gain:g}%): not "
                "determined, 0 used")
    return PedalDeadTime(0.0 if note else tau, tau, gain, note)


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


def fit_zone(zi: int, zone, sig: LongitudinalSignals, masks: ZoneMasks, ped: Pedals,
             names: list[str], P_all: np.ndarray, cfg: LongitudinalIdConfig) -> ZoneFit:
    """Eq. 8 by OLS with HAC intervals on one zone's usable samples, its metrics and the FOS
    term selection; a pedal term only when the pedal was pressed ``min_pressed_s`` in the zone.
    Not fitted (``fitted`` False) with fewer than ``min_samples`` samples."""
    zname, lo, hi = zone
    dt, v, a_meas, n = sig.dt_s, sig.v, sig.a_meas, len(sig.v)
    m = ~masks.bad & (masks.zid == zi)
    nz = int(m.sum())
    in_zone = np.isfinite(v) & (masks.zid == zi) & ~masks.standstill
    rep: dict = {"name": zname, "v_min_mps": lo, "v_max_mps": hi, "samples": nz,
                 "seconds_in_zone": float(in_zone.sum() * dt),
                 "samples_excluded": int(in_zone.sum() - nz)}
    if nz < cfg.min_samples:
        rep["note"] = (f"only {nz} usable samples (need {cfg.min_samples}): not identified")
        return ZoneFit(None, False, rep)
    pressed_a = float(np.sum(m & (ped.ap > cfg.pressed)) * dt)
    pressed_b = float(np.sum(m & (ped.bp > cfg.pressed)) * dt)
    rep["accel_pedal_pressed_s"], rep["brake_pedal_pressed_s"] = pressed_a, pressed_b
    use_a = pressed_a >= cfg.min_pressed_s
    use_b = sig.has_brake and pressed_b >= cfg.min_pressed_s
    cols = [np.ones(n)] + ([ped.aps] if use_a else []) + ([-ped.bps] if use_b else [])
    X = np.column_stack(cols)
    r = ols_hac(X, a_meas, m)
    coef, ci = list(r.coef), [tuple(c) for c in r.ci95]
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
        "ci_method": r.method,
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
                  has_brake: bool, path) -> Zone:
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
    if not f.fitted:
        j = _nearest(i, fitted)
        off = fits[j].report["offset_mps2"]
        notes.append(f"no usable data ({rep['samples']} samples): offset copied from zone "
                     f"'{zones[j][0]}'")
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
        if f.fitted:
            notes.append(f"accelerator pressed only {rep['accel_pedal_pressed_s']:.1f} s: "
                         f"scale copied from zone '{zones[j][0]}'")
        else:
            notes.append(f"scale copied from zone '{zones[j][0]}'")
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
               f"brake pressed only {rep.get('brake_pedal_pressed_s', 0.0):.1f} s")
        if j is not None:
            br = fits[j].report["brake_scale_mps2"]
            notes.append(f"{why}: brake scale copied from zone '{zones[j][0]}'")
        else:
            br = cfg.brake_scale_prior_mps2
            notes.append(f"{why} (in every zone): brake scale is the prior "
                         f"{cfg.brake_scale_prior_mps2:g} m/s^2, not identified")
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
        "dead_time_method": "grid search of the pooled zone-fit residual, one-sample steps",
        "dead_time_estimate_s": dead.estimate_s,
        "dead_time_residual_reduction": dead.gain,
        "dead_time_note": dead.note,
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
