"""The refinement of eq. 7 by eq. 1 position replay (the report's "compare the actual position
with our estimate").

The bicycle model (eq. 1) is replayed over non-overlapping windows of ``window_s`` from the
measured position and heading at each window's start, driven by the measured front-axle speed
and the delayed steering-wheel angle, and offset and scale minimise the position error
(``scipy.optimize.least_squares``). Needs ``x``, ``y``, ``heading`` (body yaw, ENU). Eq. 1 moves
the front-axle centre F, the recording gives the nav point N = F + R(heading) (lever - [b, 0]):
the geometry's ``vehicle.nav_lever_arm_m`` when given, else the lever arm's x is estimated
with the map (y taken as 0, bounds ``lever_arm_x_bounds_m``) and reported; when it cannot be
separated from the map the replay is marked untrusted and never chosen. Its 95% intervals
come from the cluster-robust sandwich with the replay windows as clusters
(``models.identify.stats.cluster_cov``), Student-t critical values.
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import least_squares
from scipy.stats import t as student_t

from hmpc.models.plant import heading_rate, position_rates, road_wheel_angle
from hmpc.models.identify.stats import cluster_cov
from hmpc.models.identify.steering.fits import MapFit


def _windows(ok: np.ndarray, n_win: int) -> list[tuple[int, int]]:
    """Non-overlapping windows [i0, i1) of ``n_win`` samples inside the True runs of ``ok``."""
    out = []
    idx = np.flatnonzero(np.diff(np.concatenate([[0], ok.astype(np.int8), [0]])))
    for s, e in zip(idx[::2], idx[1::2]):
        for i0 in range(s, e - n_win + 1, n_win):
            out.append((i0, i0 + n_win))
    return out


class _Replay:
    """Vectorised eq. 1 replay over windows; residuals are predicted minus measured (x, y).

    Eq. 1 moves the front-axle centre F. The recorded position is the nav point N (GNSS/INS
    reference), ``N = F + R(psi) (lever - [b, 0])`` with ``lever`` [m] in body axes from the
    rear-axle centre and psi the recorded body heading (ENU yaw, the heading of eq. 1). Each
    window starts from F derived from the measured N and heading; the replayed F is carried
    back to N with the replayed heading and compared with the measurement. ``lever`` given:
    theta = (offset, scale); None: theta = (offset, scale, lever_x), lever_y = 0.
    """

    def __init__(self, windows, x, y, psi, v, sw, dt_s, b, stride, lever=None):
        self.dt, self.b, self.lever = dt_s, b, lever
        self.lever_x_fit = b  # the estimated lever arm's x once fitted (lever None)
        self.win_id = np.full(len(x), -1)
        self.start = np.zeros(len(x), dtype=int)
        for w, (i0, i1) in enumerate(windows):
            self.win_id[i0:i1] = w
            self.start[i0:i1] = i0
        self.inwin = self.win_id >= 0
        sel = np.zeros(len(x), dtype=bool)
        for i0, i1 in windows:
            sel[i0 + stride : i1 : stride] = True
        self.res_idx = np.flatnonzero(sel)
        self.groups = np.concatenate([self.win_id[self.res_idx]] * 2)
        self.x, self.y, self.psi, self.v = x, y, psi, v
        self.sw = np.where(self.inwin, sw, 0.0)
        self.vz = np.where(self.inwin, v, 0.0)

    def arm(self, theta) -> tuple[float, float]:
        """(dx, dy) [m]: body-axes vector from the front-axle centre to the nav point."""
        if self.lever is not None:
            return float(self.lever[0]) - self.b, float(self.lever[1])
        lx = theta[2] if len(theta) > 2 else self.lever_x_fit
        return float(lx) - self.b, 0.0

    def predict(self, theta):
        """Nav-point positions from eq. 7 and eq. 1 (the plant's functions), integrated by the
        cumulative trapezoid from each window's first measured pose."""
        off, sc = theta[0], theta[1]
        dx, dy = self.arm(theta)
        p0 = self.psi[self.start]
        x0 = self.x[self.start] - (np.cos(p0) * dx - np.sin(p0) * dy)
        y0 = self.y[self.start] - (np.sin(p0) * dx + np.cos(p0) * dy)
        delta = road_wheel_angle(self.sw, off, sc)
        w = heading_rate(self.vz, delta, self.b)
        cw = np.concatenate([[0.0], np.cumsum(0.5 * self.dt * (w[1:] + w[:-1]))])
        psi = p0 + cw - cw[self.start]
        fx, fy = position_rates(psi, self.vz, delta)
        cx = np.concatenate([[0.0], np.cumsum(0.5 * self.dt * (fx[1:] + fx[:-1]))])
        cy = np.concatenate([[0.0], np.cumsum(0.5 * self.dt * (fy[1:] + fy[:-1]))])
        xp = x0 + cx - cx[self.start] + np.cos(psi) * dx - np.sin(psi) * dy
        yp = y0 + cy - cy[self.start] + np.sin(psi) * dx + np.cos(psi) * dy
        return xp, yp

    def residuals(self, theta):
        xp, yp = self.predict(theta)
        i = self.res_idx
        return np.concatenate([xp[i] - self.x[i], yp[i] - self.y[i]])


def _fit_replay(rec, v_front, sw_d, usable, dt, b, cfg, x0, lever=None):
    """Eq. 7 by the position replay (:class:`_Replay`). ``lever``: the geometry's
    ``nav_lever_arm_m``; None: its x is estimated with the map (bounded to
    ``cfg.lever_arm_x_bounds_m``) and the replay is untrusted when it cannot be separated
    from the map (``extra['trusted']``, ``extra['untrusted_because']``)."""
    x, y, psi = (np.asarray(rec[c], dtype=float) for c in ("x", "y", "heading"))
    ok = usable & np.isfinite(x) & np.isfinite(y) & np.isfinite(psi) & np.isfinite(sw_d)
    n_win = int(round(cfg.window_s / dt))
    wins = _windows(ok, n_win)
    if len(wins) < 3:
        return None, 0
    rp = _Replay(
        wins,
        x,
        y,
        np.unwrap(np.nan_to_num(psi)),
        np.nan_to_num(v_front),
        np.nan_to_num(sw_d),
        dt,
        b,
        max(1, cfg.replay_stride),
        lever,
    )
    theta0 = np.asarray(x0, dtype=float)[:2]
    if lever is None:
        lo_x, hi_x = cfg.lever_arm_x_bounds_m[0], b + cfg.lever_arm_x_bounds_m[1]
        theta0 = np.append(theta0, 0.5 * b)
        sol = least_squares(
            rp.residuals,
            theta0,
            method="trf",
            x_scale=np.array([0.01, 0.01, 1.0]),
            bounds=([-np.inf, -np.inf, lo_x], [np.inf, np.inf, hi_x]),
        )
    else:
        sol = least_squares(rp.residuals, theta0, method="lm", x_scale=np.array([0.01, 0.01]))
    if lever is None:
        rp.lever_x_fit = float(sol.x[2])
    cov = cluster_cov(sol.jac, sol.fun, rp.groups)
    G = len(wins)
    crit = float(student_t.ppf(0.975, max(G - 1, 1)))
    se = np.sqrt(np.clip(np.diag(cov), 0, None))
    d = np.sqrt(np.outer(np.diag(cov), np.diag(cov)))
    corr_m = np.divide(cov, d, out=np.zeros_like(cov), where=d > 0)
    corr = float(corr_m[0, 1])
    extra = {
        "windows": G,
        "window_s": cfg.window_s,
        "status": int(sol.status),
        "initial": [float(v) for v in x0],
        "trusted": True,
    }
    if lever is not None:
        extra["nav_lever_arm_m"] = [float(lever[0]), float(lever[1])]
        extra["lever_arm_source"] = "geometry (vehicle.nav_lever_arm_m)"
    else:
        lx, half = float(sol.x[2]), float(crit * se[2])
        c_lever = float(np.max(np.abs(corr_m[2, :2])))
        extra.update(
            {
                "nav_lever_arm_m": [lx, 0.0],
                "lever_arm_x_ci95_m": [lx - half, lx + half],
                "lever_arm_source": "estimated with the map (y taken as 0)",
                "lever_arm_map_correlation": c_lever,
            }
        )
        why = []
        if c_lever > cfg.max_param_corr:
            why.append(f"the lever arm's x is correlated {c_lever:.3f} with the map")
        if not half <= cfg.max_lever_arm_ci_m:
            why.append(f"the lever arm's x is known only to +-{half:.2f} m")
        if min(lx - lo_x, hi_x - lx) < 1e-3:
            why.append(f"the lever arm's x ({lx:.2f} m) is at its bound")
        if why:
            extra["trusted"] = False
            extra["untrusted_because"] = (
                "the position's reference point is not in the geometry "
                "(vehicle.nav_lever_arm_m) and " + "; ".join(why)
            )
    fit = MapFit(
        "position_replay",
        float(sol.x[0]),
        float(sol.x[1]),
        (float(sol.x[0] - crit * se[0]), float(sol.x[0] + crit * se[0])),
        (float(sol.x[1] - crit * se[1]), float(sol.x[1] + crit * se[1])),
        corr,
        len(rp.res_idx),
        float(np.sqrt(np.mean(sol.fun**2))),
        "m",
        f"cluster-robust sandwich over {G} replay windows, t({G - 1})",
        extra,
    )
    return (fit, rp, sol.x), G
