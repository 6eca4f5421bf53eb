"""What an online model estimate reports: the run JSON's ``adaptation`` (per learned value its
start, end, 95 % interval, convergence time, validity and use), the counts of
``details.adaptation`` (samples used and gated, spikes, wheel faults, fall-back events) and the
history the figures draw (:class:`History`). Reads a ``ModelAdapter``; computes nothing it
did not record.
"""

from __future__ import annotations

import math

import numpy as np

from hmpc.controller.adapt.config import (
    KEY_LONG_DELAY,
    KEY_LONG_LAG,
    KEY_STEER_DELAY,
    KEY_STEER_LAG,
    KEY_STEER_OFFSET,
    KEY_STEER_SCALE,
    zone_key,
)


def adaptation_report(ad, t0_s: float | None = None) -> dict:
    """The run JSON's ``adaptation`` of adapter ``ad``: KEY -> {initial, final, ci95,
    converged_t_s, valid, used, ...}. ``converged_t_s``: seconds from ``t0_s`` (default: the
    first learning step) after which the estimate stayed within its final interval, widened to
    an immaterial difference; None for a value no data moved. Filter parameters add
    ``identified``, ``updates`` and, when not both used and identified, ``reason``; dead times
    and lags their fit's ``excited_s`` and ``r2``, and their ``ci95`` is their 95 % set."""
    if t0_s is None:
        t0_s = ad.t0_s if ad.t0_s is not None else 0.0
    ad._drift_all()
    ad._check_validity()
    now = ad._values_now()
    used = ad._used_values()
    nz = len(ad.zones.names)
    used_of = dict(zip((KEY_STEER_OFFSET, KEY_STEER_SCALE), used[:2]))
    used_of.update(
        zip((KEY_STEER_DELAY, KEY_LONG_DELAY, KEY_STEER_LAG, KEY_LONG_LAG), used[2 + 3 * nz :])
    )
    if ad.zones.inputs == "pedals":
        for zi, name in enumerate(ad.zones.names):
            for k, coef in enumerate(ad._coefs):
                used_of[zone_key(name, coef)] = used[2 + k * nz + zi]
    t, vals, _sig = ad.history.arrays()
    out = {}
    for j, key in enumerate(ad.keys):
        final, s = now[key]
        ent = {
            "initial": float(ad.initial[key][0]),
            "final": float(final),
            "ci95": None,
            "converged_t_s": _converged(ad, key, t, vals[:, j], final, s, t0_s),
            "used": used_of.get(key),
        }
        if j < len(ad._plist):
            ent["ci95"] = [float(final - 1.96 * s), float(final + 1.96 * s)]
            ent["valid"] = bool(ad.valid[j])
            ent["identified"] = bool(ad.identified[j])
            _k, f, i, _t, _r = ad._plist[j]
            ent["updates"] = int(f.updates[i])
            why = ad._why_not(j)
            if why:
                ent["reason"] = why
        else:
            ch = "steering" if key in (KEY_STEER_DELAY, KEY_STEER_LAG) else "longitudinal"
            est = ad.timing_est[ch]
            ent["valid"] = bool(est is not None and est["valid"])
            ent["excited_s"] = 0.0 if est is None else est["excited_s"]
            if est is not None:
                ent["ci95"] = est["delay_ci95_s" if "delay" in key else "lag_ci95_s"]
                ent["r2"] = est["r2"]
        out[key] = ent
    return out


def _converged(ad, key, t, v, final, sigma, t0_s) -> float | None:
    """Seconds from ``t0_s`` after which the estimate stayed within its final interval
    (widened to the config's immaterial difference); None when it never moved."""
    if len(t) == 0 or not np.any(v != v[0]) and v[0] == ad.initial[key][0]:
        return None
    c = ad.cfg
    if key == KEY_STEER_OFFSET:
        floor = c.converged_offset_rad
    elif key.endswith("offset_mps2"):
        floor = c.converged_offset_mps2
    elif key.endswith("_s"):
        floor = c.converged_timing_s
    else:
        floor = c.converged_rel * abs(final)
    tol = max(1.96 * sigma if sigma == sigma else 0.0, floor)
    out = np.flatnonzero(np.abs(v - final) > tol)
    if len(out) == 0:
        return float(t[0] - t0_s)
    if out[-1] + 1 >= len(t):
        return None
    return float(t[out[-1] + 1] - t0_s)


def adaptation_counts(ad) -> dict:
    """Counts of adapter ``ad`` for ``details.adaptation``: samples used and gated, spikes
    dropped, wheel faults, widenings, the dead-time fits, the fall-back events."""
    fs = [ad.steering.filter] + ad.zones.filters
    return {
        "steering_samples": dict(ad.steering.samples),
        "zone_samples": dict(ad.zones.samples),
        "spikes_dropped": dict(ad.signals.spikes),
        "wheel_speed_faults": int(ad.signals.wheel_faults),
        "widened": int(sum(f.widened for f in fs)),
        "rejected": int(sum(f.rejected for f in fs)),
        "inputs": ad.inputs,
        "timing": {k: v for k, v in ad.timing_est.items()},
        "events": [{"t_s": round(t, 3), "what": w} for t, w in ad.events],
    }


class History:
    """(t, estimate, 1-sigma) per key every ``period_s``, in arrays that double when full."""

    def __init__(self, n_keys: int, period_s: float):
        self.period_s = float(period_s)
        self.n = 0
        self.t = np.zeros(1024)
        self.v = np.zeros((1024, n_keys))
        self.s = np.zeros((1024, n_keys))
        self.t_last = -math.inf

    def add(self, t_s: float, vals) -> None:
        if self.n >= len(self.t):
            self.t = np.concatenate([self.t, np.zeros(len(self.t))])
            self.v = np.concatenate([self.v, np.zeros_like(self.v)])
            self.s = np.concatenate([self.s, np.zeros_like(self.s)])
        i = self.n
        self.t[i] = t_s
        for j, (v, s) in enumerate(vals):
            self.v[i, j] = v
            self.s[i, j] = s
        self.n += 1
        self.t_last = t_s

    def arrays(self):
        return self.t[: self.n], self.v[: self.n], self.s[: self.n]
