"""A Kalman filter on a few slowly varying parameters (:class:`ParamFilter`): recursive least
squares with a random-walk drift instead of exponential forgetting, bounded covariance, held
directions, an innovation gate and bounds.

The model is linear in the parameters: a measurement ``y = h' theta + e`` (``e`` of variance
``r``). Per update, the parameters whose regressor the data did not exercise are *held*: the
gain is the Kalman gain of the free parameters alone, as if the held ones were known, and zero
for the held ones, so that straight driving puts the offset where the held scale explains the
straight course. The covariance is that estimator's own, for any gain (the Joseph form ``P -
K (P h)' - (P h) K' + K K' S``, ``S = h' P h + r``): a held parameter's variance does not
shrink, and the correlation the sample creates is kept, so that a later update of the held
parameter moves the others with it. With every parameter free this is the Kalman update. The
innovation ``y - h' theta`` is gated on its chi-square score against ``S``.

Why not exponential forgetting: ``P / lambda`` inflates every direction, also those no data
excites, until one noisy sample throws them far (the wind-up of a steer ratio on a straight
road). Here the covariance grows only by a stated drift rate per second and never beyond the
prior's variances (each parameter's diagonal capped, by a congruence that keeps ``P``
positive semi-definite): an unexcited direction returns at most to "as uncertain as at the
start". After ``widen_after`` consecutive gated-out updates the filter widens back to the
prior and takes the next sample whatever its score, so that a sudden, real change of the car
is learned within seconds while a single outlier never is (the sensor checks upstream keep a
frozen or spiking channel from being that persistent).

Bounds: a value leaving ``[lo, hi]`` is clamped there and flagged (``at_bound``); the caller
falls back to its file for it.

Everything is on Python floats in lists allocated once: a 2- or 3-parameter filter costs a few
microseconds per update, without numpy's per-call overhead.
"""

from __future__ import annotations

import math


class ParamFilter:
    """Kalman filter on ``n`` parameters (see the module docstring).

    Args:
        theta0: initial values (the parameter file's).
        sigma0: prior 1-sigma of each (also the cap of its variance).
        walk_per_rts: drift 1-sigma per square root of a second of each.
        lo, hi: bounds of each.
        gate_chi2: innovation gate (chi-square, 1 degree of freedom).
        widen_after: consecutive gated-out updates before the filter widens to its prior.
    """

    def __init__(self, theta0, sigma0, walk_per_rts, lo, hi, *, gate_chi2: float, widen_after: int):
        n = len(theta0)
        self.n = n
        self.theta = [float(x) for x in theta0]
        self.cap = [float(s) ** 2 for s in sigma0]
        self.q = [float(w) ** 2 for w in walk_per_rts]
        self.lo = [float(x) for x in lo]
        self.hi = [float(x) for x in hi]
        self.P = [[self.cap[i] if i == j else 0.0 for j in range(n)] for i in range(n)]
        self.gate = float(gate_chi2)
        self.widen_after = int(widen_after)
        self.at_bound = [False] * n
        self.updates = [0] * n  # accepted updates that moved each parameter
        self.rejected = 0  # gated-out updates
        self.widened = 0  # times the filter widened to its prior
        self.rejects_run = 0  # consecutive gated-out updates
        self.restored = False  # started from a saved state (learned before)
        self._gate_open = False  # after widening, the next sample passes the gate
        self._ph = [0.0] * n  # P h
        self._C = [[0.0] * n for _ in range(n)]  # a conditional covariance
        self._k = [0.0] * n  # the gain

    def restore(self, theta, sigma) -> None:
        """Start from ``theta`` with 1-sigma ``sigma`` (a saved state), within the bounds."""
        self.restored = True
        for i in range(self.n):
            self.theta[i] = min(max(float(theta[i]), self.lo[i]), self.hi[i])
            row = self.P[i]
            for j in range(self.n):
                row[j] = 0.0
            row[i] = min(float(sigma[i]) ** 2, self.cap[i])

    def sigma(self, i: int) -> float:
        """1-sigma of parameter ``i``."""
        return math.sqrt(max(self.P[i][i], 0.0))

    def drift(self, dt_s: float) -> None:
        """Let ``dt_s`` [s] of drift pass: the variances grow by their walk, capped at the
        prior (each row and column scaled, which keeps ``P`` positive semi-definite)."""
        P, n = self.P, self.n
        for i in range(n):
            v = P[i][i] + self.q[i] * dt_s
            cap = self.cap[i]
            if v > cap:
                f = math.sqrt(cap / P[i][i]) if P[i][i] > 0 else 0.0
                for j in range(n):
                    if j != i:
                        P[i][j] *= f
                        P[j][i] *= f
                v = cap
            P[i][i] = v

    def update(self, h, y: float, r: float, free) -> bool:
        """One measurement ``y`` [its unit] = ``h' theta`` + noise of variance ``r``, moving
        only the parameters with ``free[i]`` true. Returns True when accepted by the gate."""
        P, n, ph, k, th = self.P, self.n, self._ph, self._k, self.theta
        s = r
        inn = y
        for i in range(n):
            row = P[i]
            acc = 0.0
            for j in range(n):
                acc += row[j] * h[j]
            ph[i] = acc
            s += h[i] * acc
            inn -= h[i] * th[i]
        if not (s > 0.0 and math.isfinite(inn)):
            return False
        if inn * inn / s > self.gate and not self._gate_open:
            self.rejected += 1
            self.rejects_run += 1
            if self.rejects_run >= self.widen_after:
                self._widen()
            return False
        self.rejects_run = 0
        self._gate_open = False
        # the gain of the free parameters alone, the held ones taken as known: the Kalman
        # gain with the free block's covariance conditional on the held values; zero for the
        # held ones
        C = self._conditional(free)
        sf = r
        for i in range(n):
            acc = 0.0
            if free[i]:
                row = C[i]
                for j in range(n):
                    if free[j]:
                        acc += row[j] * h[j]
            k[i] = acc
            sf += h[i] * acc
        for i in range(n):
            k[i] /= sf
        # the covariance of that estimator, whatever its gain (Joseph form):
        # P - K (P h)' - (P h) K' + K K' S
        for i in range(n):
            row = P[i]
            for j in range(n):
                row[j] += -k[i] * ph[j] - ph[i] * k[j] + k[i] * k[j] * s
        for i in range(n):
            if k[i] != 0.0:
                v = th[i] + k[i] * inn
                if v < self.lo[i]:
                    v, self.at_bound[i] = self.lo[i], True
                elif v > self.hi[i]:
                    v, self.at_bound[i] = self.hi[i], True
                else:
                    self.at_bound[i] = False
                th[i] = v
                self.updates[i] += 1
        return True

    def _conditional(self, free):
        """``P`` with its free block conditioned on the held parameters (Schur complement
        ``P_FF - P_FH P_HH^-1 P_HF``; one or two held), or ``P`` itself when all are free."""
        P, n = self.P, self.n
        held = [i for i in range(n) if not free[i]]
        if not held:
            return P
        C = self._C
        if len(held) == 1:
            m = held[0]
            pm = P[m][m]
            for i in range(n):
                for j in range(n):
                    C[i][j] = P[i][j] - (P[i][m] * P[m][j] / pm if pm > 0 else 0.0)
            return C
        a, b = held[0], held[1]
        det = P[a][a] * P[b][b] - P[a][b] * P[b][a]
        if not det > 0:
            return P
        ia, ib, iab = P[b][b] / det, P[a][a] / det, -P[a][b] / det
        for i in range(n):
            for j in range(n):
                C[i][j] = P[i][j] - (
                    P[i][a] * (ia * P[a][j] + iab * P[b][j])
                    + P[i][b] * (iab * P[a][j] + ib * P[b][j])
                )
        return C

    def _widen(self) -> None:
        """Back to the prior's variances (correlations dropped): the data has disagreed with
        the estimate ``widen_after`` times in a row."""
        for i in range(self.n):
            row = self.P[i]
            for j in range(self.n):
                row[j] = 0.0
            row[i] = self.cap[i]
        self.rejects_run = 0
        self.widened += 1
        self._gate_open = True  # the next sample is taken whatever its score: it re-anchors
