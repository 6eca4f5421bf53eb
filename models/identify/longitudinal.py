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
    within [v_min - h, v_max + h] (as ``HybridPlant.select_zone``)."""
    v = np.asarray(v_mps, dtype=float)
    vmax = np.array([z[2] for z in zones])
    vmin = np.array([z[1] for z in zones])
    z = np.searchsorted(vmax, v, side="left")
    z = np.where(np.isfinite(v) & (z < len(zones)), z, -1)
    if hysteresis_mps <= 0:
        return z
    out = z.copy()
    cur = -1
    for i in range(len(v)):
        if not np.isfinite(v[i]):
            cur = -1
            out[i] = -1
            continue
        if cur >= 0:
            lo = -np.inf if cur == 0 else vmin[cur] - hysteresis_mps
            hi = vmax[cur] + hysteresis_mps
            if lo <= v[i] <= hi and not (cur == len(zones) - 1 and v[i] > vmax[-1]):
                out[i] = cur
                continue
        cur = int(z[i])
        out[i] = cur
    return out


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
    zones = [(str(n), float(lo), float(hi)) for n, lo, hi in cfg.zones]
    if not zones:
        raise InputError("no speed zones given", rec.meta.get("path"))
    for i, (n, lo, hi) in enumerate(zones):
        if not hi > lo or (i and abs(lo - zones[i - 1][2]) > 1e-9) or (i == 0 and lo != 0.0):
            raise InputError(f"zones must be contiguous from 0 m/s with v_max > v_min "
                             f"(zone {n!r}: {lo}..{hi})", rec.meta.get("path"))
    if cfg.accel_source not in ACCEL_SOURCES:
        raise InputError(f"unknown accel source {cfg.accel_source!r} (one of "
                         f"{', '.join(ACCEL_SOURCES)})", rec.meta.get("path"))
    rec.require("accel_pedal")
    dt = 1.0 / rec.rate_hz
    n = len(rec)
    # ---- speed (eq. 1's v)
    if "wheel_speed_fl" in rec and "wheel_speed_fr" in rec:
        _, v = road_wheel_angle_from_front(rec["wheel_speed_fl"], rec["wheel_speed_fr"],
                                           vehicle.wheelbase_m, vehicle.track_front_m)
        speed_src = "front-axle-centre speed from the CAN front wheel speeds"
    else:
        rec.require("speed")
        v = np.asarray(rec["speed"], dtype=float)
        speed_src = "CAN 'speed' channel"
    # ---- acceleration, and the matching smoother for the regressors
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

    def smooth(x):
        return apply_kernel(x, g_ker)

    ap_raw = np.asarray(rec["accel_pedal"], dtype=float)
    has_brake = "brake_pedal" in rec
    bp_raw = np.asarray(rec["brake_pedal"], dtype=float) if has_brake else np.zeros(n)
    half = len(d_ker) // 2 + 1

    # ---- zones and exclusions
    zid = assign_zones(v, zones, cfg.hysteresis_mps)
    finite = np.isfinite(v) & np.isfinite(a_meas) & np.isfinite(ap_raw) & np.isfinite(bp_raw)
    standstill = np.nan_to_num(v, nan=0.0) < cfg.v_stop_mps
    above = np.isfinite(v) & (v > zones[-1][2])
    # a sample is usable if its whole smoothing window shares its zone and is moving & finite
    change = np.zeros(n, dtype=bool)
    change[1:] = zid[1:] != zid[:-1]
    boundary = dilate(change, half, half)
    base_bad = ~finite | standstill | (zid < 0)
    bad = dilate(base_bad, half, half) | boundary

    # ---- dead time: pooled per-zone OLS residual over a grid of delays
    say("longitudinal: estimating the pedal dead time")
    lags = np.arange(0, int(round(cfg.dead_time_max_s / dt)) + 1)
    sse = np.full(len(lags), np.inf)
    for k, lag in enumerate(lags):
        apd, bpd = smooth(delayed(ap_raw, lag * dt, dt)), smooth(delayed(bp_raw, lag * dt, dt))
        ok = ~bad & np.isfinite(apd) & np.isfinite(bpd)
        tot = 0.0
        for zi in range(len(zones)):
            m = ok & (zid == zi)
            if m.sum() < cfg.min_samples:
                continue
            X = np.column_stack([np.ones(m.sum()), apd[m], bpd[m]])
            coef, *_ = np.linalg.lstsq(X, a_meas[m], rcond=None)
            tot += float(np.sum((a_meas[m] - X @ coef) ** 2))
        sse[k] = tot
    dead_note = None
    if np.isfinite(sse).all() and sse[0] > 0:
        k_best = int(np.argmin(sse))
        gain = 1.0 - sse[k_best] / sse[0]
        tau = float(lags[k_best] * dt)
        if k_best == len(lags) - 1:
            dead_note = (f"residual still falling at the search limit {cfg.dead_time_max_s:g} s: "
                         "dead time not determined, 0 used")
        elif gain < cfg.dead_time_min_gain:
            dead_note = (f"a dead time of {tau:.2f} s lowers the residual by only "
                         f"{100 * gain:.1f}% (< {100 * cfg.dead_time_min_gain:g}%): not "
                         "determined, 0 used")
        if dead_note:
            tau_est, tau = tau, 0.0
        else:
            tau_est = tau
    else:
        gain, tau, tau_est = 0.0, 0.0, float("nan")
        dead_note = "no zone had enough samples to estimate it: 0 used"
    ap, bp = delayed(ap_raw, tau, dt), delayed(bp_raw, tau, dt)
    aps, bps = smooth(ap), smooth(bp)
    bad |= ~(np.isfinite(aps) & np.isfinite(bps))
    say(f"longitudinal: pedal dead time {tau:.2f} s; acceleration from {accel_desc}")

    # ---- FOS candidates
    cand = {"1": np.ones(n), "accel_pedal": aps, "brake_pedal": bps}
    for extra in (0.25, 0.5):
        cand[f"accel_pedal(t-{extra:g}s)"] = smooth(delayed(ap, extra, dt))
        cand[f"brake_pedal(t-{extra:g}s)"] = smooth(delayed(bp, extra, dt))
    cand["v"] = smooth(v)
    cand["v^2"] = smooth(v * v)
    cand["accel_pedal*v"] = smooth(ap * v)
    if "accel_cmd" in rec:
        cand["accel_cmd"] = smooth(np.asarray(rec["accel_cmd"], dtype=float))
    names = list(cand)
    P_all = np.column_stack([cand[k] for k in names])

    fits: list[ZoneFit] = []
    for zi, (zname, lo, hi) in enumerate(zones):
        m = ~bad & (zid == zi)
        nz = int(m.sum())
        in_zone = np.isfinite(v) & (zid == zi) & ~standstill
        rep: dict = {"name": zname, "v_min_mps": lo, "v_max_mps": hi, "samples": nz,
                     "seconds_in_zone": float(in_zone.sum() * dt),
                     "samples_excluded": int(in_zone.sum() - nz)}
        if nz < cfg.min_samples:
            rep["note"] = (f"only {nz} usable samples (need {cfg.min_samples}): not identified")
            fits.append(ZoneFit(None, False, rep))
            continue
        pressed_a = float(np.sum(m & (ap > cfg.pressed)) * dt)
        pressed_b = float(np.sum(m & (bp > cfg.pressed)) * dt)
        rep["accel_pedal_pressed_s"], rep["brake_pedal_pressed_s"] = pressed_a, pressed_b
        use_a = pressed_a >= cfg.min_pressed_s
        use_b = has_brake and pressed_b >= cfg.min_pressed_s
        cols = [np.ones(n)] + ([aps] if use_a else []) + ([-bps] if use_b else [])
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
        a_raw = off + (sc or 0.0) * np.nan_to_num(ap) - (br or 0.0) * np.nan_to_num(bp)
        srmse = speed_rmse(v, a_raw, m, dt, cfg.segment_s)
        # FOS term selection on the zone samples
        # candidates missing on more than 10% of the zone's samples are left out (e.g. an ACC
        # request that is only sent while the ACC is engaged), then rows with a gap
        fin = np.isfinite(P_all[m])
        keep = [j for j in range(len(names)) if fin[:, j].mean() >= 0.9]
        mf = m & np.all(np.isfinite(P_all[:, keep]), axis=1)
        fos_rep = None
        if mf.sum() >= 20:
            # hold-out blocks of fos_block_s, shortened so that even a short zone keeps some
            block = max(min(int(round(cfg.fos_block_s / dt)), int(mf.sum()) // 8), 5)
            Pz = P_all[np.ix_(mf, keep)]
            fr = fos(Pz, a_meas[mf], [names[j] for j in keep], force=["1"],
                     max_terms=cfg.fos_max_terms, block_len=block)
            var_f = float(np.var(a_meas[mf]))
            fos_rep = {**fr.to_dict(), "samples": int(mf.sum()),
                       "nmse_pct": 100.0 * float(np.mean((a_meas[mf] - fr.predict(Pz)) ** 2))
                       / var_f if var_f > 0 else None,
                       "candidates_left_out": [names[j] for j in range(len(names))
                                               if j not in keep]}
        rep.update({
            "offset_mps2": off, "offset_ci95_mps2": list(off_ci),
            "scale_mps2": sc, "scale_ci95_mps2": None if sc_ci is None else list(sc_ci),
            "brake_scale_mps2": br,
            "brake_scale_ci95_mps2": None if br_ci is None else list(br_ci),
            "nmse_pct": nmse, "speed_rmse_mps": srmse,
            "accel_rms_mps2": float(np.sqrt(np.mean(a_meas[m] ** 2))),
            "residual_rms_mps2": float(np.sqrt(np.mean(resid ** 2))),
            "ci_method": r.method,
            "fos": fos_rep,
        })
        fits.append(ZoneFit(None, True, rep, a_fit))

    fitted = [i for i, f in enumerate(fits) if f.fitted]
    if not fitted:
        raise InputError("no speed zone has enough usable samples (moving, finite, inside one "
                         f"zone; need {cfg.min_samples} per zone): cannot identify eq. 8",
                         rec.meta.get("path"), channel="accel_pedal")
    # ---- build Zone objects, with fallbacks for what the data did not exercise
    with_scale = [i for i in fitted if fits[i].report["scale_mps2"] is not None]
    with_brake = [i for i in fitted if fits[i].report["brake_scale_mps2"] is not None]
    out_zones = []
    for i, f in enumerate(fits):
        zname, lo, hi = zones[i]
        rep = f.report
        notes = []
        ident = f.fitted
        if not f.fitted:
            j = _nearest(i, fitted)
            src_rep = fits[j].report
            off = src_rep["offset_mps2"]
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
        # throttle scale
        sc = rep.get("scale_mps2") if f.fitted else None
        sc_ci = rep.get("scale_ci95_mps2") if f.fitted else None
        if sc is None:
            ident = False
            j = _nearest(i, with_scale)
            if j is None:
                raise InputError("the accelerator pedal is never pressed long enough in any zone "
                                 f"(need {cfg.min_pressed_s} s): cannot identify eq. 8",
                                 rec.meta.get("path"), channel="accel_pedal")
            sc = fits[j].report["scale_mps2"]
            if f.fitted:
                notes.append(f"accelerator pressed only {rep['accel_pedal_pressed_s']:.1f} s: "
                             f"scale copied from zone '{zones[j][0]}'")
            else:
                notes.append(f"scale copied from zone '{zones[j][0]}'")
        elif abs(0.5 * (sc_ci[1] - sc_ci[0]) / sc) > cfg.max_rel_ci if sc != 0 else True:
            ident = False
            notes.append(f"scale known only to +-{100 * abs(0.5 * (sc_ci[1] - sc_ci[0]) / sc):.0f}%"
                         if sc != 0 else "scale is zero")
        br = rep.get("brake_scale_mps2") if f.fitted else None
        br_ci = rep.get("brake_scale_ci95_mps2") if f.fitted else None
        if br is None:
            ident = False
            j = _nearest(i, with_brake)
            why = ("no brake_pedal channel" if not has_brake else
                   f"brake pressed only {rep.get('brake_pedal_pressed_s', 0.0):.1f} s")
            if j is not None:
                br = fits[j].report["brake_scale_mps2"]
                notes.append(f"{why}: brake scale copied from zone '{zones[j][0]}'")
            else:
                br = cfg.brake_scale_prior_mps2
                notes.append(f"{why} (in every zone): brake scale is the prior "
                             f"{cfg.brake_scale_prior_mps2:g} m/s^2, not identified")
        elif abs(0.5 * (br_ci[1] - br_ci[0]) / br) > cfg.max_rel_ci if br != 0 else True:
            ident = False
            notes.append(f"brake scale known only to +-"
                         f"{100 * abs(0.5 * (br_ci[1] - br_ci[0]) / br):.0f}%"
                         if br != 0 else "brake scale is zero")
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
        out_zones.append(z)

    n_above = int(above.sum())
    report = {
        "accel_source": accel_desc,
        "speed_source": speed_src,
        "dead_time_s": tau,
        "dead_time_method": "grid search of the pooled zone-fit residual, one-sample steps",
        "dead_time_estimate_s": tau_est,
        "dead_time_residual_reduction": gain,
        "dead_time_note": dead_note,
        "zones": [f.report for f in fits],
        "above_last_zone": {"samples": n_above, "seconds": float(n_above * dt),
                            "v_max_mps": zones[-1][2],
                            "note": "not fitted (no zone model above the last zone)"},
        "standstill": {"samples": int(np.sum(standstill & np.isfinite(v))),
                       "seconds": float(np.sum(standstill & np.isfinite(v)) * dt),
                       "v_stop_mps": cfg.v_stop_mps,
                       "note": "excluded: the car is held, acceleration clamped at zero"},
        "boundary_samples_excluded": int(np.sum(boundary & ~base_bad)),
        "hysteresis_mps": cfg.hysteresis_mps,
        "smooth_s": cfg.smooth_s,
        "fos_candidates": names,
    }
    series = {"time": rec.time, "v_mps": v, "a_meas_mps2": a_meas, "accel_pedal": ap_raw,
              "brake_pedal": bp_raw if has_brake else None, "zone": zid, "used": ~bad,
              "a_model_mps2": {zones[i][0]: f.a_model for i, f in enumerate(fits) if f.fitted}}
    return LongitudinalResult(out_zones, tau, accel_desc, report, series)
