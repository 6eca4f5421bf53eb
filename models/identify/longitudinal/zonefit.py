"""Eq. 8 fitted on one zone (:func:`fit_zone`): coefficients with intervals, metrics, FOS terms.

**Fit**: ordinary least squares on [1, accel_pedal, brake_pedal] (a pedal only when it was
pressed ``min_pressed_s`` in the zone) with 95% intervals from ``models.identify.stats.ols_hac``
(correlated residuals) widened by the pedal timing bound (:func:`ols_timed`: when within a
sample a pedal moved is not recorded).

**Term selection**: Fast Orthogonal Search (``models.identify.fos``) chooses, per zone, among
the candidates 1, accel_pedal, brake_pedal (at the dead time), the pedals delayed a further
0.25 s and 0.5 s, v, v^2, accel_pedal * v, and ``accel_cmd`` when the recording has one (an
ACC request is not a pedal, but when it explains what the pedals do not, the report says so).
The selected terms, their error reductions and the FOS model's NMSE are reported; the written
eq. 8 keys come from the OLS fit above.

**Metrics** (the report's section V-C): ``nmse_pct = 100 * MSE / variance of the measured
acceleration`` over the zone's samples, and ``speed_rmse_mps``, the RMS error of the speed
reconstructed by integrating the model from the measured speed at the start of every run of
zone samples (runs cut at ``segment_s``, the MPC horizon scale of the report). The speed
replay (:func:`speed_rmse`) is a score of the zone fit and lives beside it.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from hmpc.models.identify.fos import fos
from hmpc.models.params import Zone
from hmpc.models.logs.recording import Recording
from hmpc.models.identify.stats import ols_hac
from hmpc.models.identify.steering import delayed
from hmpc.models.identify.longitudinal.config import LongitudinalIdConfig
from hmpc.models.identify.longitudinal.signals import LongitudinalSignals, Pedals, ZoneMasks


@dataclass
class ZoneFit:
    """Eq. 8 fit of one zone, its metrics and term selection."""

    zone: Zone | None  # set by longitudinal.identifiable once the zone's values are decided
    fitted: bool
    report: dict
    a_model: np.ndarray | None = field(repr=False, default=None)


def _runs(mask: np.ndarray, max_len: int):
    idx = np.flatnonzero(np.diff(np.concatenate([[0], mask.astype(np.int8), [0]])))
    for s, e in zip(idx[::2], idx[1::2]):
        for a in range(s, e, max_len):
            yield a, min(a + max_len, e)


def speed_rmse(
    v_meas: np.ndarray, a_model: np.ndarray, mask: np.ndarray, dt_s: float, segment_s: float
) -> float:
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
    return float(np.sqrt(np.mean(e**2)))


def fos_candidates(
    rec: Recording, sig: LongitudinalSignals, ped: Pedals
) -> tuple[list[str], np.ndarray]:
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
    return np.column_stack(
        [np.ones(len(aps))] + ([aps] if use_a else []) + ([-bps] if use_b else [])
    )


def ols_timed(X: np.ndarray, alt_X: list, y: np.ndarray, m: np.ndarray):
    """OLS with 95% intervals = the HAC interval (``stats.ols_hac``) widened by the pedal
    timing bound: the largest coefficient change when the pedal columns are read half a sample
    earlier or later (``alt_X``; ``stats.half_sample_kernels``). The recording does not say
    when within a sample a pedal moved (a pedal held at 100 Hz and recorded at 50 Hz); that
    ambiguity alone can move a scale by more than its HAC half-width, so intervals without it
    miss the truth. Returns (``OlsResult``, intervals [(low, high)], statistical half-widths,
    timing half-widths)."""
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


def fit_zone(
    zi: int,
    zone,
    sig: LongitudinalSignals,
    masks: ZoneMasks,
    ped: Pedals,
    names: list[str],
    P_all: np.ndarray,
    cfg: LongitudinalIdConfig,
) -> ZoneFit:
    """Eq. 8 by OLS with HAC intervals on one zone's usable samples, its metrics and the FOS
    term selection; a pedal term only when the pedal was pressed ``min_pressed_s`` in the zone.
    Not fitted (``fitted`` False) with less than ``min_zone_s`` of usable samples."""
    zname, lo, hi = zone
    dt, v, a_meas = sig.dt_s, sig.v, sig.a_meas
    m = ~masks.bad & (masks.zid == zi)
    nz = int(m.sum())
    in_zone = np.isfinite(v) & (masks.zid == zi) & ~masks.standstill
    rep: dict = {
        "name": zname,
        "v_min_mps": lo,
        "v_max_mps": hi,
        "samples": nz,
        "seconds_in_zone": float(in_zone.sum() * dt),
        "samples_excluded": int(in_zone.sum() - nz),
    }
    if nz < cfg.min_samples(dt):
        rep["not_fitted_because"] = (
            f"no usable data ({nz} samples, {nz * dt:.1f} s; {cfg.min_zone_s:g} s needed)"
        )
        rep["note"] = f"{rep['not_fitted_because']}: not identified"
        return ZoneFit(None, False, rep)
    pressed_a = float(np.sum(m & (ped.ap > cfg.pressed)) * dt)
    pressed_b = float(np.sum(m & (ped.bp > cfg.pressed)) * dt)
    rep["accel_pedal_pressed_s"], rep["brake_pedal_pressed_s"] = pressed_a, pressed_b
    use_a = pressed_a >= cfg.min_pressed_s
    use_b = sig.has_brake and pressed_b >= cfg.min_pressed_s
    X = _zone_design(ped.aps, ped.bps, use_a, use_b)
    r, ci, stat_hw, sys_hw = ols_timed(
        X, [_zone_design(a, b, use_a, use_b) for a, b in ped.alt], a_meas, m
    )
    coef, ci = list(r.coef), list(ci)
    off, off_ci = coef.pop(0), ci.pop(0)
    sc, sc_ci = (coef.pop(0), ci.pop(0)) if use_a else (None, None)
    br, br_ci = (coef.pop(0), ci.pop(0)) if use_b else (None, None)
    a_fit = X @ r.coef
    resid = a_meas[m] - a_fit[m]
    var = float(np.var(a_meas[m]))
    nmse = 100.0 * float(np.mean(resid**2)) / var if var > 0 else float("nan")
    # model acceleration from the unsmoothed (delayed) pedals, for the speed reconstruction
    a_raw = off + (sc or 0.0) * np.nan_to_num(ped.ap) - (br or 0.0) * np.nan_to_num(ped.bp)
    srmse = speed_rmse(v, a_raw, m, dt, cfg.segment_s)
    rep.update(
        {
            "offset_mps2": off,
            "offset_ci95_mps2": list(off_ci),
            "scale_mps2": sc,
            "scale_ci95_mps2": None if sc_ci is None else list(sc_ci),
            "brake_scale_mps2": br,
            "brake_scale_ci95_mps2": None if br_ci is None else list(br_ci),
            "nmse_pct": nmse,
            "speed_rmse_mps": srmse,
            "accel_rms_mps2": float(np.sqrt(np.mean(a_meas[m] ** 2))),
            "residual_rms_mps2": float(np.sqrt(np.mean(resid**2))),
            "ci_method": r.method + " + half-sample pedal timing bound",
            "ci_statistical_half_width": [float(x) for x in stat_hw],
            "ci_timing_half_width": [float(x) for x in sys_hw],
            "fos": _fos_report(m, a_meas, names, P_all, dt, cfg),
        }
    )
    return ZoneFit(None, True, rep, a_fit)


def _fos_report(
    m: np.ndarray,
    a_meas: np.ndarray,
    names: list[str],
    P_all: np.ndarray,
    dt: float,
    cfg: LongitudinalIdConfig,
) -> dict | None:
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
    fr = fos(
        Pz,
        a_meas[mf],
        [names[j] for j in keep],
        force=["1"],
        max_terms=cfg.fos_max_terms,
        block_len=block,
    )
    var_f = float(np.var(a_meas[mf]))
    return {
        **fr.to_dict(),
        "samples": int(mf.sum()),
        "nmse_pct": 100.0 * float(np.mean((a_meas[mf] - fr.predict(Pz)) ** 2)) / var_f
        if var_f > 0
        else None,
        "candidates_left_out": [names[j] for j in range(len(names)) if j not in keep],
    }
