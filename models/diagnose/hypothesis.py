"""What every hypothesis of the catalogue offers the diagnosis, whatever its subsystem
(``sensors``, ``steering``, ``longitudinal``), and the parameter search they share.

- :class:`FittedModel`: one fit of a hypothesis (equation error SSE over ``n`` samples with
  ``k`` parameters): what the grid search and the BIC need.
- :class:`HypothesisScore`: a hypothesis scored on held-out folds (the per-sample held-out
  error, the BIC of its full-data fit, its parameters and their intervals): what a candidate
  record (``models.diagnose.candidates``) is made of. The held-out RMSE is named with its
  channel's unit in each subsystem (``heldout_rmse_mps``, ``heldout_rmse_rad``).
- :func:`grid_search`: a hypothesis's nonlinear parameter (a delay, a lag, a gradient) found
  on a grid of the SSE per sample, refined around the best point.
"""

from __future__ import annotations

from typing import Protocol, TypeVar
from collections.abc import Callable

import numpy as np


class FittedModel(Protocol):
    """One fit of a hypothesis: its equation-error SSE, samples and parameters."""

    sse: float
    n: int
    k: int


class HypothesisScore(Protocol):
    """A hypothesis scored by blocked held-out replay plus its full-data fit."""

    name: str | None
    heldout_err: np.ndarray  #: per-sample held-out error in the channel's unit (NaN elsewhere)
    bic: float  #: BIC of the full-data fit (effective samples)
    params: dict  #: catalogue parameter name -> value
    intervals: dict  #: catalogue parameter name -> [lo, hi] (95 %)


def sse_per_sample(m: FittedModel) -> float:
    """SSE per sample: comparable across grid points that use different samples (a delay
    drops a few at each segment's start)."""
    return m.sse / max(m.n, 1)


_Model = TypeVar("_Model", bound=FittedModel)


def grid_search(
    fit_at: Callable[[float], _Model],
    grid: np.ndarray,
    fine_step: float | None = None,
    *,
    end_pad: float = 0.0,
    rtol: float = 0.0,
    atol: float = 0.0,
) -> tuple[_Model, np.ndarray, np.ndarray]:
    """The fit of ``fit_at`` with the smallest SSE per sample over ``grid``.

    With ``fine_step``: refined by a fine grid of that step from one coarse step below the best
    point (not below 0) to one coarse step above it (``end_pad`` added to the end so that it
    is included); fine points within ``atol + rtol * |coarse point|`` of a coarse point are
    not fitted again.

    Returns (best model, the grid fitted (sorted), SSE per sample per grid point).
    """
    models = [fit_at(g) for g in grid]
    sse = np.array([sse_per_sample(m) for m in models])
    best = int(np.nanargmin(sse))
    if fine_step is None:
        return models[best], grid, sse
    step = grid[1] - grid[0]
    fine = np.arange(max(grid[best] - step, 0.0), grid[best] + step + end_pad, fine_step)
    fine = fine[~np.isclose(fine[:, None], grid[None, :], rtol=rtol, atol=atol).any(axis=1)]
    models += [fit_at(g) for g in fine]
    grid = np.concatenate([grid, fine])
    sse = np.concatenate([sse, [sse_per_sample(m) for m in models[len(sse) :]]])
    order = np.argsort(grid)
    grid, sse, models = grid[order], sse[order], [models[i] for i in order]
    best = int(np.nanargmin(sse))
    return models[best], grid, sse
