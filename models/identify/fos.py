"""Fast Orthogonal Search (FOS): hmpc's term-selection engine.

Korenberg, "A robust orthogonal algorithm for system identification and time-series
analysis", Biol. Cybern. 60 (1989) 267-276 (the report's ref. [6]); applied to identification
by Eklund, Korenberg and McLellan, J. Process Control 17 (2007) 742-754 (ref. [5]).

Given a target ``y`` [N] and a matrix of candidate terms ``P`` [N, M] with names, FOS builds
the model ``y ~ sum_k a_k p_{m_k}`` one term at a time, each time adding the candidate whose
orthogonal component gives the largest reduction of the mean-squared error. The
orthogonalisation is *implicit*: only the time averages of products of candidates
(``G = P'P/N``), and of candidates with the target (``P'y/N``), are formed, once. The
Gram-Schmidt quantities follow by Korenberg's recursions, for a selected set ``m_0..m_{r-1}``
and any remaining candidate ``m``::

    D(m, 0) = G[m, m_0]
    D(m, r) = G[m, m_r] - sum_{i<r} alpha(r, i) D(m, i)          alpha(m, r) = D(m, r) / D(r, r)
    C(m)    = (P'y/N)[m] - sum_{r} alpha(m, r) C(r)
    g_m     = C(m) / D(m, m)          error reduction  Q(m) = g_m^2 D(m, m) = C(m)^2 / D(m, m)

so choosing a term costs O(M K) per candidate, never a pass over the N samples. The
coefficients of the selected terms follow from the orthogonal ones by back-substitution and
equal ordinary least squares on the selected columns (tested in ``tests/identify/test_fos.py``).

Stopping: a term is added only while (1) fewer than ``max_terms`` are selected, (2) its error
reduction is at least ``min_reduction`` times the target's mean square (the training MSE of the
empty model) and at least Korenberg's noise threshold ``4 / (N_train + 1)`` times the current
MSE (a white-noise candidate would reduce the MSE by about ``1/(N+1)`` of it; he uses 4x), and
(3) the MSE on held-out data keeps falling: after ``patience`` terms that do not lower the
held-out MSE by ``min_holdout_gain`` (relative), the search stops, and the selection is cut back
to the prefix with the lowest held-out MSE. Held-out samples are whole blocks of consecutive
samples (``block_len``): with time series, neighbouring samples are correlated, so a randomly
interleaved hold-out would not test generalisation.

The module is generic (a matrix and names in, a selection out): the steering and accelerator
identification use it now, the mismatch diagnosis will reuse it.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import scipy.linalg


@dataclass
class FosResult:
    """Outcome of :func:`fos`.

    Attributes:
        terms: names of the selected terms, in order of selection.
        indices: their column indices in the candidate matrix.
        coefficients: coefficient of each selected term (same order); equal to ordinary least
            squares of the training target on the selected training columns.
        error_reduction: mean-squared-error reduction of each term when it was added [unit of
            y, squared] (training data).
        error_reduction_fraction: the same, as a fraction of the training target's mean square.
        train_mse_path: training MSE after 0, 1, ..., K terms (K = all terms tried).
        holdout_mse_path: held-out MSE after 0, 1, ..., K terms (empty without a hold-out).
        tried: names of all terms added before the stop (``terms`` is a prefix of it).
        stop_reason: why the search stopped (text).
        train_mask: boolean mask of the samples used to fit (all True without a hold-out).
    """

    terms: list[str]
    indices: list[int]
    coefficients: np.ndarray
    error_reduction: np.ndarray
    error_reduction_fraction: np.ndarray
    train_mse_path: np.ndarray
    holdout_mse_path: np.ndarray
    tried: list[str]
    stop_reason: str
    train_mask: np.ndarray = field(repr=False)

    def predict(self, P: np.ndarray) -> np.ndarray:
        """Model output for a candidate matrix with the same columns as the one searched."""
        P = np.asarray(P, dtype=float)
        if not self.indices:
            return np.zeros(P.shape[0])
        return P[:, self.indices] @ self.coefficients

    def to_dict(self) -> dict:
        """JSON-ready summary (names, coefficients, reductions, MSE paths)."""
        return {
            "terms": list(self.terms),
            "coefficients": [float(c) for c in self.coefficients],
            "error_reduction_fraction": [float(q) for q in self.error_reduction_fraction],
            "train_mse_path": [float(x) for x in self.train_mse_path],
            "holdout_mse_path": [float(x) for x in self.holdout_mse_path],
            "tried": list(self.tried),
            "stop_reason": self.stop_reason,
        }


def block_holdout(n: int, *, fraction: float = 0.25, block_len: int = 250) -> np.ndarray:
    """Boolean mask of held-out samples: every ``round(1/fraction)``-th block of ``block_len``.

    Deterministic (no randomness): blocks 0..k-2 train, block k-1 is held out, and so on, so
    every part of a recording contributes to both sets. Returns all False when ``n`` is too short
    to hold out at least one block and keep three for training.
    """
    if not 0.0 < fraction < 1.0:
        raise ValueError(f"fraction must be in (0, 1), got {fraction}")
    if block_len < 1:
        raise ValueError(f"block_len must be >= 1, got {block_len}")
    period = max(int(round(1.0 / fraction)), 2)
    block = np.arange(n) // block_len
    mask = (block % period) == (period - 1)
    if mask.sum() == 0 or (~mask).sum() < 3 * block_len:
        return np.zeros(n, dtype=bool)
    return mask


def fos(
    P: np.ndarray,
    y: np.ndarray,
    names: list[str] | None = None,
    *,
    holdout: np.ndarray | None | str = "blocks",
    holdout_fraction: float = 0.25,
    block_len: int = 250,
    max_terms: int | None = None,
    min_reduction: float = 1e-4,
    noise_threshold: bool = True,
    patience: int = 2,
    min_holdout_gain: float = 1e-3,
    force: list[str] | tuple[str, ...] = (),
    collinear_tol: float = 1e-9,
) -> FosResult:
    """Select terms of ``y ~ P[:, S] a`` greedily by error reduction (see the module doc).

    Args:
        P: candidate matrix [N, M]; a constant term is a column of ones.
        y: target [N].
        names: a name per column (default ``p0..p{M-1}``).
        holdout: boolean mask [N] of held-out samples, ``"blocks"`` for
            :func:`block_holdout` (``holdout_fraction``, ``block_len``), or None for no
            hold-out (all samples fit; the held-out rule is then off).
        holdout_fraction: fraction of the samples :func:`block_holdout` holds out.
        block_len: length of :func:`block_holdout`'s blocks [samples].
        max_terms: at most this many terms (default: all candidates).
        min_reduction: smallest error reduction accepted, as a fraction of mean(y^2).
        noise_threshold: apply Korenberg's 4/(N+1) rule.
        patience: stop after this many consecutive terms that fail to lower the held-out MSE.
        min_holdout_gain: relative held-out MSE decrease that counts as lowering it.
        force: names selected first, in this order, whatever their error reduction (e.g. the
            constant). They are never cut back.
        collinear_tol: a candidate whose orthogonal component has a mean square below this
            fraction of its own mean square is linearly dependent on the selection: skipped.

    Raises:
        ValueError: shapes that do not match, non-finite values, unknown ``force`` names.
    """
    P, y, names = _check_inputs(P, y, names)
    n, m = P.shape
    hmask = _holdout_mask(n, holdout, holdout_fraction, block_len)
    train = ~hmask
    use_holdout = bool(hmask.any())
    if train.sum() < 2:
        raise ValueError("fewer than 2 training samples")
    for f in force:
        if f not in names:
            raise ValueError(f"force names an unknown term {f!r}")
    max_terms = m if max_terms is None else min(int(max_terms), m)

    Pt, yt = P[train], y[train]
    nt = Pt.shape[0]
    # The only passes over the data: time averages of products (Korenberg's correlations).
    G = (Pt.T @ Pt) / nt  # [M, M]
    c0 = (Pt.T @ yt) / nt  # [M]
    y2 = float(yt @ yt) / nt  # mean square of the target = MSE of the empty model
    Ph, yh = P[hmask], y[hmask]
    st = _Search.start(G, c0, max_terms)
    forced = [names.index(f) for f in force]

    mse = y2
    train_path = [mse]
    hold_path = [float(np.mean(yh**2))] if use_holdout else []
    reductions: list[float] = []
    best_k, best_hold, bad = 0, (hold_path[0] if use_holdout else np.inf), 0
    stop = "all candidates used" if max_terms >= m else f"max_terms ({max_terms}) reached"

    while len(st.sel) < max_terms:
        r = len(st.sel)
        ok = st.admissible(collinear_tol)
        if r < len(forced):
            j = forced[r]
            if not ok[j]:
                raise ValueError(f"forced term {names[j]!r} is linearly dependent on the others")
        else:
            j, why = st.best(
                ok, min_reduction * y2, 4.0 / (nt + 1) * mse if noise_threshold else None, y2
            )
            if why is not None:
                stop = why
                break
        reductions.append(st.accept(j))
        mse = max(mse - reductions[-1], 0.0)
        train_path.append(mse)
        k = len(st.sel)
        if not use_holdout:
            best_k = k
            continue
        h = float(np.mean((yh - Ph[:, st.sel] @ st.coefficients(k)) ** 2))
        hold_path.append(h)
        if k <= len(forced) or h < best_hold * (1.0 - min_holdout_gain):
            best_k, best_hold, bad = k, h, 0
        else:
            bad += 1
            if bad >= patience:
                stop = (
                    f"held-out MSE did not fall by {min_holdout_gain:g} (relative) for "
                    f"{patience} term(s)"
                )
                break

    k = best_k
    red = np.array(reductions[:k])
    return FosResult(
        terms=[names[i] for i in st.sel[:k]],
        indices=st.sel[:k],
        coefficients=st.coefficients(k),
        error_reduction=red,
        error_reduction_fraction=(red / y2) if y2 > 0 else np.zeros(k),
        train_mse_path=np.array(train_path),
        holdout_mse_path=np.array(hold_path),
        tried=[names[i] for i in st.sel],
        stop_reason=stop,
        train_mask=train,
    )


def _check_inputs(P, y, names) -> tuple[np.ndarray, np.ndarray, list[str]]:
    """``P`` [N, M] and ``y`` [N] as finite float arrays, and one unique name per column."""
    P = np.asarray(P, dtype=float)
    y = np.asarray(y, dtype=float)
    if P.ndim != 2 or y.ndim != 1 or P.shape[0] != y.shape[0]:
        raise ValueError(f"expected P [N, M] and y [N], got {P.shape} and {y.shape}")
    m = P.shape[1]
    names = [f"p{i}" for i in range(m)] if names is None else list(names)
    if len(names) != m or len(set(names)) != m:
        raise ValueError("names must be unique, one per column of P")
    if not (np.all(np.isfinite(P)) and np.all(np.isfinite(y))):
        raise ValueError("P and y must be finite (drop NaN rows before calling fos)")
    return P, y, names


def _holdout_mask(n: int, holdout, fraction: float, block_len: int) -> np.ndarray:
    """The held-out samples [N] for :func:`fos`'s ``holdout`` argument."""
    if isinstance(holdout, str):
        if holdout != "blocks":
            raise ValueError(f"holdout must be a mask, 'blocks' or None, got {holdout!r}")
        return block_holdout(n, fraction=fraction, block_len=block_len)
    if holdout is None:
        return np.zeros(n, dtype=bool)
    hmask = np.asarray(holdout, dtype=bool)
    if hmask.shape != (n,):
        raise ValueError(f"holdout mask must have shape ({n},)")
    return hmask


@dataclass
class _Search:
    """Korenberg's recursions for the terms selected so far (module doc), over M candidates.

    ``D[r, j] = D(j, r)`` = mean(p_j w_r) for all candidates, ``alpha[r, i] = alpha(m_r, i)``
    (i < r), ``Dd[r] = D(m_r, m_r)`` = mean(w_r^2), ``g[r]`` the weight of the orthogonal
    function w_r. For every candidate j, ``Djj[j]`` is the mean square of its component
    orthogonal to the selection and ``Cj[j]`` that component's mean product with y (Korenberg's
    D(j, j) and C(j)); one recursion step per selected term keeps them current.
    """

    G: np.ndarray
    diagG: np.ndarray
    D: np.ndarray
    alpha: np.ndarray
    Dd: np.ndarray
    g: np.ndarray
    Djj: np.ndarray
    Cj: np.ndarray
    available: np.ndarray
    sel: list[int]

    @classmethod
    def start(cls, G: np.ndarray, c0: np.ndarray, max_terms: int) -> _Search:
        m = G.shape[0]
        diagG = np.diag(G).copy()
        return cls(
            G,
            diagG,
            np.zeros((max_terms, m)),
            np.zeros((max_terms, max_terms)),
            np.zeros(max_terms),
            np.zeros(max_terms),
            diagG.copy(),
            c0.copy(),
            np.ones(m, dtype=bool),
            [],
        )

    def admissible(self, collinear_tol: float) -> np.ndarray:
        """Candidates not yet selected and not linearly dependent on the selection."""
        return self.available & (self.Djj > collinear_tol * np.maximum(self.diagG, 1e-300))

    def best(
        self, ok: np.ndarray, min_q: float, noise_q: float | None, y2: float
    ) -> tuple[int, str | None]:
        """The admissible candidate with the largest error reduction, and why to stop instead
        (None to accept it): nothing admissible, below ``min_q`` or below ``noise_q``."""
        if not ok.any():
            return -1, "remaining candidates are linearly dependent on the selection"
        q = np.full(len(ok), -np.inf)
        q[ok] = self.Cj[ok] ** 2 / self.Djj[ok]
        j = int(np.argmax(q))
        if q[j] < min_q:
            return j, f"best error reduction {q[j] / y2:.2e} of mean(y^2) is below min_reduction"
        if noise_q is not None and q[j] < noise_q:
            return j, "best error reduction is below Korenberg's 4/(N+1) noise threshold"
        return j, None

    def accept(self, j: int) -> float:
        """Select candidate ``j`` as the next term; return its error reduction."""
        r = len(self.sel)
        D, alpha, Dd = self.D, self.alpha, self.Dd
        for i in range(r):  # alpha(m_r, i) = D(m_r, i) / D(i, i)
            alpha[r, i] = D[i, j] / Dd[i]
        D[r] = self.G[:, j] - alpha[r, :r] @ D[:r]  # D(:, r) by the recursion
        Dd[r] = D[r, j]
        self.g[r] = self.Cj[j] / Dd[r]
        a_col = D[r] / Dd[r]  # alpha(j', r) for every candidate j'
        self.Djj = self.Djj - a_col * D[r]
        self.Cj = self.Cj - a_col * self.Cj[j]
        self.sel.append(j)
        self.available[j] = False
        return self.g[r] ** 2 * Dd[r]

    def coefficients(self, k: int) -> np.ndarray:
        """Coefficients of the first ``k`` selected terms (:func:`_coefficients`)."""
        return _coefficients(self.g[:k], self.alpha[:k, :k])


def _coefficients(g: np.ndarray, alpha: np.ndarray) -> np.ndarray:
    """Coefficients of the selected terms from the weights g of the orthogonal functions.

    With ``w_r = p_{m_r} - sum_{i<r} alpha(r, i) w_i``, the selected columns are
    ``P_S = W L'`` where L is unit lower triangular with ``L[r, i] = alpha(r, i)``. So
    ``y ~ W g = P_S (L')^-1 g`` and the coefficients solve the upper-triangular ``L' a = g``.
    """
    k = len(g)
    if k == 0:
        return np.zeros(0)
    L = np.tril(alpha[:k, :k], -1) + np.eye(k)
    return scipy.linalg.solve_triangular(L.T, g, lower=False, unit_diagonal=True)
