"""A matplotlib figure on its own Agg canvas: hmpc's figures change no global matplotlib state.

Importing or calling this never selects a backend and never touches pyplot's figure manager,
so a caller's interactive backend and open figures are left alone (``matplotlib.use`` on import
of a library module would switch them).
"""

from __future__ import annotations

from pathlib import Path

from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure


def new_figure(nrows: int = 1, ncols: int = 1, *, figsize: tuple[float, float], **subplots_kw):
    """A ``Figure`` with an Agg canvas and its axes, as ``pyplot.subplots`` returns them."""
    fig = Figure(figsize=figsize)
    FigureCanvasAgg(fig)
    return fig, fig.subplots(nrows, ncols, **subplots_kw)


def save_png(fig: Figure, path: str | Path, dpi: int) -> str:
    """Lay out and write the PNG; the figure is garbage once unreferenced (no pyplot to close)."""
    fig.tight_layout()
    fig.savefig(path, dpi=dpi)
    return str(path)
