"""Actuator dead time and lag from command to response, learned on line
(:class:`ResponseFit`), and the command history both it and the zone fit read
(:class:`CommandHistory`).

The response of a channel to its command is taken as a first-order lag behind a dead time
(the catalogue's ``actuator_delay`` and ``actuator_lag``): steering, the road-wheel angle (from
the yaw rate) against the steering-wheel command; longitudinal, the measured acceleration
against the commanded one (eq. 8 of the file on the pedal commands, or the acceleration
command itself). Because the two describe one mismatch in two ways (``models.catalogue``'s
``ALTERNATIVES``), they are fitted jointly on a grid: every (dead time, lag) candidate
simulates its response to the commands issued, exactly for commands held over each control
period (the period split where the delayed command switches, the lag's mean over each piece),
and keeps the sums of a least-squares fit ``y = c0 + c1 x`` (offset and gain free, so that a
wrong map or zone gain cannot move the timing) with exponential forgetting over
``timing_window_s`` (lagd's 60 s). The candidates' sums are numpy arrays written in place:
one control step is a few dozen vector operations over the grid, no allocation.

The estimate is the candidate of least residual; its 95 % set is every candidate whose
residual is within the likelihood-ratio bound (chi-square, 2 degrees of freedom) of the least;
it is valid once ``timing_min_excited_s`` of excited data (a command that changed by a step
within ``timing_excited_after_s``) went into the sums and the fit explains the response (R^2
of at least ``MIN_R2``).
"""

from __future__ import annotations

import math

import numpy as np

from hmpc.controller.adapt.config import AdaptConfig

#: [1] least share of the response's variance the best candidate must explain to be valid:
#: below it the channel is noise, or driven by something else (the driver, a grade).
MIN_R2 = 0.5
#: chi-square quantile, 2 degrees of freedom, 95 %: the likelihood-ratio set of (delay, lag).
CHI2_2_95 = 5.99


class CommandHistory:
    """The last commands of one channel, one per control period (a ring allocated once).

    ``value(j)`` is the command issued ``j`` periods before the latest (0: the latest).
    """

    def __init__(self, capacity: int, initial: float = 0.0):
        self.cap = int(capacity)
        self.ring = np.full(self.cap, float(initial))
        self.k = 0  # index of the next write
        self.count = 0

    def push(self, value: float) -> None:
        self.ring[self.k % self.cap] = value
        self.k += 1
        self.count += 1

    def value(self, back: int) -> float:
        return float(self.ring[(self.k - 1 - back) % self.cap])


def lag_coefficients(delay_s, tau_s, period_s: float):
    """Per candidate: (m, f, a1, b1, a2, b2) of a held command delayed by ``delay_s`` = (m + f)
    periods through a lag ``tau_s``: over one period the delayed command is the one ``m + 1``
    periods back for the first ``f`` of it, then the one ``m`` back; each piece's lag
    factor ``a = exp(-duration / tau)`` and mean factor ``b = tau / duration (1 - a)`` (the
    lag output's mean over a piece is ``u + (e - u) b``)."""
    d = np.asarray(delay_s, dtype=float) / period_s
    m = np.floor(d + 1e-9)
    f = np.clip(d - m, 0.0, 1.0)
    tau = np.asarray(tau_s, dtype=float)
    out = []
    for dur in (f * period_s, (1.0 - f) * period_s):
        with np.errstate(divide="ignore", invalid="ignore"):
            a = np.where(tau > 0, np.exp(-dur / np.where(tau > 0, tau, 1.0)), 0.0)
            b = np.where((tau > 0) & (dur > 0), tau / np.where(dur > 0, dur, 1.0) * (1 - a), 0.0)
        out += [a, b]
    return m.astype(np.int64), f, out[0], out[1], out[2], out[3]


def lagged_mean(
    e: float, u1: float, u2: float, f: float, a1: float, b1: float, a2: float, b2: float
) -> tuple[float, float]:
    """One period of a delayed, lagged command (scalars): from lag output ``e``, input ``u1``
    for the first ``f`` of the period then ``u2``; returns (mean output, output at the end)."""
    m1 = u1 + (e - u1) * b1
    e1 = u1 + (e - u1) * a1
    m2 = u2 + (e1 - u2) * b2
    e2 = u2 + (e1 - u2) * a2
    return f * m1 + (1.0 - f) * m2, e2


class ResponseFit:
    """Dead time and lag of ``channels`` command channels by the candidate grid (see the
    module docstring); the channels share the grid, so that one vector operation serves all.

    Args:
        config: the grid, the window and the validity thresholds.
        period_s: the control period [s] (one command per period).
        steps: per channel, the command change that excites its fit [the command's unit].
    """

    def __init__(self, config: AdaptConfig, period_s: float, steps):
        c = config
        self.period_s = T = float(period_s)
        delays = np.arange(0.0, c.timing_max_s + 1e-9, c.delay_step_s)
        lags = np.asarray([x for x in c.lag_grid_s if x <= c.timing_max_s + 1e-9], dtype=float)
        D, L = np.meshgrid(delays, lags, indexing="ij")
        self.delay_s, self.lag_s = D.ravel(), L.ravel()
        self.n = n = len(self.delay_s)
        self.channels = nc = len(steps)
        m, f, a1, b1, a2, b2 = lag_coefficients(self.delay_s, self.lag_s, T)
        # one period (see lagged_mean): with D = e - u1 and W = u1 - u2, the mean is
        # u2 + c1 D + c3 W and the lag output at its end u2 + a2 W + c4 D
        g = 1.0 - f
        self._c1 = f * b1 + g * b2 * a1
        self._c3 = f + g * b2
        self._a2 = a2
        self._c4 = a1 * a2
        cap = int(m.max()) + 3
        self.cap = cap
        self.ring = np.zeros((nc, cap))
        self.k = 0
        # ring columns of the commands m + 1 and m periods before the latest, per position
        # of the latest in the ring (a table: no index arithmetic per step)
        base = np.arange(cap)[:, None]
        self._tab1 = (base - m[None, :] - 1) % cap + np.arange(nc)[:, None, None] * cap
        self._tab2 = (base - m[None, :]) % cap + np.arange(nc)[:, None, None] * cap
        self._tab1 = np.ascontiguousarray(self._tab1.transpose(1, 0, 2))  # (cap, nc, n)
        self._tab2 = np.ascontiguousarray(self._tab2.transpose(1, 0, 2))
        self._lam = math.exp(-T / c.timing_window_s)
        self._step = np.asarray(steps, dtype=float)
        self._excited_for = c.timing_excited_after_s
        self._min_excited = c.timing_min_excited_s
        shape = (nc, n)
        self.e, self.x = np.zeros(shape), np.zeros(shape)
        # the forgotten sums of x, x^2 and x y per channel and candidate, and this period's
        # weighted terms, each as one array: one vector operation updates all three
        self._sums, self._terms = np.zeros((3, nc, n)), np.zeros((3, nc, n))
        self.sx, self.sxx, self.sxy = self._sums
        self._u1, self._u2, self._d, self._w, self._t = (np.zeros(shape) for _ in range(5))
        self.sw, self.sy, self.syy = np.zeros(nc), np.zeros(nc), np.zeros(nc)
        self._wy = np.zeros(nc)
        self.weight = np.zeros(nc)  # this period's weight per channel (0: unusable)
        self.y = np.zeros(nc)  # this period's measured response per channel
        self.excited_s = [0.0] * nc
        self._last_change_t = [-math.inf] * nc
        self._last_cmd = [math.nan] * nc
        self._started = False

    def command(self, t_s: float, values) -> None:
        """The commands (one per channel) that acted over the period ending at ``t_s`` [s]
        (their means, when the period spans several control periods), pushed before
        :meth:`advance` computes that period's responses."""
        if not self._started:
            self.ring[:] = np.asarray(values, dtype=float)[:, None]
            self.e[:] = self.ring[:, :1]
            self._started = True
        col = self.k % self.cap
        for ch, v in enumerate(values):
            self.ring[ch, col] = v
            last = self._last_cmd[ch]
            if last != last or abs(v - last) >= self._step[ch]:
                if last == last:
                    self._last_change_t[ch] = t_s
                self._last_cmd[ch] = v
        self.k += 1

    def advance(self) -> None:
        """Every candidate's mean response over the period that just ended (``x``): the
        commands issued up to the previous step through each delay and lag."""
        if not self._started:
            return
        row = (self.k - 1) % self.cap
        u1, u2, d, w, t, e = self._u1, self._u2, self._d, self._w, self._t, self.e
        flat = self.ring.reshape(-1)
        flat.take(self._tab1[row], out=u1)
        flat.take(self._tab2[row], out=u2)
        np.subtract(e, u1, out=d)
        np.subtract(u1, u2, out=w)
        np.multiply(d, self._c1, out=self.x)
        np.add(self.x, u2, out=self.x)
        np.multiply(w, self._c3, out=t)
        np.add(self.x, t, out=self.x)
        np.multiply(w, self._a2, out=e)
        np.add(e, u2, out=e)
        np.multiply(d, self._c4, out=t)
        np.add(e, t, out=e)

    def add(self, t_s: float) -> None:
        """Add the period that ended at ``t_s``: each channel's measured mean response
        ``y[ch]`` with ``weight[ch]`` (1: usable, 0: not; call after :meth:`advance`)."""
        if not self._started:
            return
        lam, w, y = self._lam, self.weight, self.y
        for ch in range(self.channels):
            if w[ch] > 0:
                excited = t_s - self._last_change_t[ch] <= self._excited_for
                self.excited_s[ch] = lam * self.excited_s[ch] + (self.period_s if excited else 0.0)
        np.multiply(self.sw, lam, out=self.sw)
        np.add(self.sw, w, out=self.sw)
        np.multiply(w, y, out=self._wy)
        np.multiply(self.sy, lam, out=self.sy)
        np.add(self.sy, self._wy, out=self.sy)
        np.multiply(self.syy, lam, out=self.syy)
        self.syy += self._wy * y
        wx, wxx, wxy = self._terms
        x = self.x
        np.multiply(x, w[:, None], out=wx)
        np.multiply(wx, x, out=wxx)
        np.multiply(wx, y[:, None], out=wxy)
        np.multiply(self._sums, lam, out=self._sums)
        np.add(self._sums, self._terms, out=self._sums)

    def estimate(self, ch: int) -> dict | None:
        """Channel ``ch``'s fit as {delay_s, lag_s, delay_ci95_s, lag_ci95_s, r2, excited_s,
        valid}, or None before enough data."""
        w = float(self.sw[ch])
        if w < 10.0:
            return None
        sy = float(self.sy[ch])
        sxx = self.sxx[ch] - self.sx[ch] * self.sx[ch] / w
        sxy = self.sxy[ch] - self.sx[ch] * sy / w
        syy = float(self.syy[ch]) - sy * sy / w
        good = (sxx > 1e-12) & (sxy > 0)  # a response opposite to its command: no fit
        sse = np.full(self.n, np.inf)
        np.subtract(syy, sxy * sxy / np.where(good, sxx, 1.0), out=sse, where=good)
        i = int(np.argmin(sse))
        best = float(sse[i])
        if not math.isfinite(best) or syy <= 0:
            return None
        ok = sse <= best * (1.0 + CHI2_2_95 / max(w - 2.0, 1.0))
        d_in, l_in = self.delay_s[ok], self.lag_s[ok]
        r2 = 1.0 - best / syy
        valid = self.excited_s[ch] >= self._min_excited and r2 >= MIN_R2
        return {
            "delay_s": float(self.delay_s[i]),
            "lag_s": float(self.lag_s[i]),
            "delay_ci95_s": [float(d_in.min()), float(d_in.max())],
            "lag_ci95_s": [float(l_in.min()), float(l_in.max())],
            "r2": float(r2),
            "excited_s": float(self.excited_s[ch]),
            "valid": bool(valid),
        }
