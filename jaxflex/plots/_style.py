"""Shared look of jaxflex figures, and the one way to save them.

Figures are plain :class:`matplotlib.figure.Figure` objects, not registered with pyplot: they
need no display (drawing uses the Agg canvas), leave no global state behind, and in a notebook
they show inline when returned (after ``%matplotlib inline``) or through ``display(fig)``.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
from matplotlib.axes import Axes
from matplotlib.figure import Figure

from jaxflex._io import atomic_write

MEASURED = "0.25"
"""Colour of measured data (dark grey)."""
MODEL = "tab:blue"
"""Colour of the model."""
RESIDUAL = "tab:red"
"""Colour of residuals (measured − model)."""
MARK = "tab:orange"
"""Colour of markers such as resonance lines."""
FORMATS = ("png", "pdf", "svg")
"""File formats :func:`save_figure` writes (from the suffix)."""


def new_figure(
    nrows: int = 1,
    ncols: int = 1,
    *,
    figsize: tuple[float, float] = (8.0, 5.0),
    dpi: float = 100.0,
    sharex: bool = False,
    height_ratios: list[float] | None = None,
) -> tuple[Figure, np.ndarray]:
    """A constrained-layout figure and its axes (always a 2-D array), styled with :func:`style`."""
    fig = Figure(figsize=figsize, dpi=dpi, layout="constrained")
    axes = fig.subplots(
        nrows, ncols, sharex=sharex, squeeze=False, gridspec_kw={"height_ratios": height_ratios}
    )
    for ax in axes.flat:
        style(ax)
    return fig, axes


def figure_axes(
    ax: Axes | None, *, figsize: tuple[float, float] = (6.0, 3.5), dpi: float = 100.0
) -> tuple[Figure, Axes]:
    """``ax`` and its figure, or a new single-axes figure when ``ax`` is None."""
    if ax is not None:
        return ax.figure, ax
    fig, axes = new_figure(1, 1, figsize=figsize, dpi=dpi)
    return fig, axes[0, 0]


def style(ax: Axes) -> Axes:
    """Light grid behind the data, no top/right spines."""
    ax.grid(True, color="0.9", linewidth=0.8)
    ax.set_axisbelow(True)
    ax.spines[["top", "right"]].set_visible(False)
    return ax


def save_figure(
    fig: Figure, path: str | os.PathLike, *, overwrite: bool = False, dpi: float | None = None
) -> Path:
    """Write ``fig`` to ``path`` (format from the suffix: .png, .pdf or .svg), atomically.

    The image keeps the figure's size (``figsize · dpi`` pixels for PNG, no tight cropping). An
    existing file is refused (:class:`~jaxflex._io.OutputExistsError`) unless ``overwrite``.
    """
    path = Path(path)
    fmt = path.suffix.lower().lstrip(".")
    if fmt not in FORMATS:
        raise ValueError(
            f"{path}: cannot save a figure as {path.suffix!r}; use one of "
            f"{', '.join('.' + f for f in FORMATS)}"
        )
    return atomic_write(
        path, lambda p: fig.savefig(p, format=fmt, dpi=dpi or fig.dpi), overwrite=overwrite
    )


__all__ = [
    "MARK", "MEASURED", "MODEL", "RESIDUAL", "figure_axes", "new_figure", "save_figure", "style"
]
