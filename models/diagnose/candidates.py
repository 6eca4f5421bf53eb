"""One hypothesis against the model below it: whether it is accepted, and the record of it.

A hypothesis (its :class:`~models.diagnose.hypothesis.HypothesisScore` against the baseline's,
or against the model it is stacked on) is accepted (:func:`accept`) when it lowers the
held-out free-run RMSE by ``DiagnoseConfig.min_gain`` and by more than the channel's
:class:`Resolution`, and lowers the BIC (effective samples); a linear longitudinal term must
also be selected by FOS (Korenberg) among the baseline's terms (:func:`fos_selects`).
:func:`candidate` is the record ``hmpc diagnose`` keeps of every hypothesis tried (its
``_``-keys: the acceptance and the held-out error series, until the findings are ranked).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from hmpc.models.catalogue import CATALOGUE
from hmpc.models.diagnose import longitudinal as lon
from hmpc.models.diagnose.common import DiagnoseConfig
from hmpc.models.diagnose.hypothesis import HypothesisScore
from hmpc.models.diagnose.lon_data import fit_samples
from hmpc.models.identify.fos import fos


@dataclass(frozen=True)
class Resolution:
    """Smallest held-out improvement that counts, per channel (the sensors' resolution)."""

    #: CAN wheel speed: 0.01 km/h steps, GNSS speed noise ~0.03 m/s; a speed replay that
    #: improves by less than 0.005 m/s is inside what the sensors can tell apart
    speed_mps: float = 0.005
    #: 0.06 deg: a survey-grade INS heading is good to 0.1 deg rms (models.sim.sensors.InsNoise),
    #: so a replay that gains less than about half of that is not a change in the car's steering
    heading_rad: float = 0.001
    #: speed difference CAN - GNSS
    speed_vs_gnss_mps: float = 0.005


def accept(
    before: float, after: float, bic_b: float, bic_a: float, res: float, cfg: DiagnoseConfig
) -> tuple[bool, str]:
    """Whether a hypothesis whose held-out RMSE goes from ``before`` to ``after`` (BIC from
    ``bic_b`` to ``bic_a``) is accepted, with the reason; ``res``: the channel's resolution
    (:class:`Resolution`, the RMSE's unit)."""
    gain = (before - after) / before if before > 0 else 0.0
    if not np.isfinite(after):
        return False, "no held-out score"
    if gain < cfg.min_gain:
        return False, f"held-out gain {100 * gain:.1f} % < {100 * cfg.min_gain:.0f} %"
    if before - after < res:
        return False, (
            f"held-out improvement {before - after:.4g} below the channel resolution {res:g}"
        )
    if cfg.require_bic and not bic_a < bic_b:
        return False, "BIC does not improve"
    return True, "accepted"


def fos_selects(
    d: lon.LonData, name: str, base: dict | None = None, spec: lon.LonSpec | None = None
) -> bool:
    """FOS (forced baseline terms) keeps the extension's term on its blocked hold-out
    (``spec``: the fitted hypothesis, e.g. a grade with its compensation rate)."""
    spec = spec or lon.LonSpec(name, **(base or {}))
    X, zone = lon._design(d, lon.fit_inputs(d, spec), spec)
    # the samples the fit uses (not those whose zone is ambiguous: a derivative window across
    # a zone change, or a speed at a zone boundary): there the measured dv/dt is neither
    # zone's law, and its error, larger than a resistance's within-zone slope, decides FOS's
    # hold-out instead of the term
    use = fit_samples(d, X, zone)
    Xs = X[use]
    keep = np.abs(Xs).max(axis=0) > 1e-12
    Xs = Xs[:, keep]
    names = [f"b{i}" for i in range(Xs.shape[1] - 1)] + [name]
    y = d.a[use]
    # FOS's smallest error reduction (1e-4) is a fraction of mean(y^2); here y is the whole
    # pedal-driven acceleration and the baseline is forced, so the question is what the term
    # adds to what the baseline leaves: the threshold is taken as that fraction of the
    # baseline's residual (a resistance that is a large part of the free-run error can be a
    # tiny fraction of mean(a^2)); Korenberg's 4/(N+1) rule and the blocked hold-out stay as
    # they are
    if len(y) > Xs.shape[1]:
        X_base = Xs[:, :-1]
        resid = y - X_base @ np.linalg.lstsq(X_base, y, rcond=None)[0]
        frac = float(np.mean(resid**2) / max(np.mean(y**2), 1e-300))
    else:
        frac = 1.0
    try:
        res = fos(
            Xs,
            y,
            names,
            force=names[:-1],
            block_len=int(10.0 / d.dt),
            min_reduction=1e-4 * min(frac, 1.0),
        )
    except ValueError:
        return False
    return name in res.terms


def candidate(
    effect: str,
    subsystem: str,
    channel: str,
    base: HypothesisScore,
    scored: HypothesisScore,
    before: float,
    after: float,
    ok: bool,
    why: str,
    window_s: float,
) -> dict:
    """The record of hypothesis ``effect`` (``scored``) against the model below it (``base``):
    held-out RMSE ``before`` -> ``after`` on ``channel`` (free-run windows of ``window_s``),
    whether it was accepted (``ok``) and why."""
    params, intervals = scored.params, scored.intervals
    e_b, e_a, dbic = base.heldout_err, scored.heldout_err, scored.bic - base.bic
    gain = (before - after) / before if before > 0 and np.isfinite(after) else 0.0
    return {
        "effect": effect,
        "subsystem": subsystem,
        "channel": channel,
        "parameters": {k: float(v) for k, v in params.items()},
        "intervals": {k: [float(a), float(b)] for k, (a, b) in intervals.items()},
        "heldout_rmse_before": float(before),
        "heldout_rmse_after": float(after),
        "gain": float(gain),
        "delta_bic": float(dbic),
        "physics": CATALOGUE[effect]["physics"],
        "why": why,
        "_ok": ok,
        "_before": e_b,
        "_after": e_a,
        "_window_s": window_s,
    }
