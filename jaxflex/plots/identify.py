"""Figures of an identification: convergence of the search and the parameter intervals.

* :func:`plot_convergence` — best cost per generation, one thin line per run and the median of
  each method thick (the paper's convergence curves);
* :func:`plot_intervals` — each identified parameter's interval, drawn in units of its own
  half-width (log scale for log-scale parameters) and labelled with its value and spread, with
  the true value where known (inside the interval ⇔ within ±1);
* :func:`plot_fit` — both for one :class:`~jaxflex.identification.Fit`.

Everything drawn is read from fits (or their histories); nothing is computed here but medians.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np
from matplotlib.axes import Axes
from matplotlib.figure import Figure
from matplotlib.ticker import MaxNLocator

from jaxflex.identification import Fit
from jaxflex.plots._style import MARK, MODEL, RESIDUAL, figure_axes, new_figure

METHOD_COLOURS = {"de": "tab:blue", "ga": "tab:green", "pso": "tab:purple"}
"""Colour of each evolutionary method in the convergence figures."""


def _histories(runs) -> dict[str, list[np.ndarray]]:
    """``method → [best-cost history per run]`` from a Fit, Fits, or such a mapping."""
    if isinstance(runs, Fit):
        runs = [runs]
    if isinstance(runs, Mapping):
        return {str(k): [np.asarray(h, dtype=float) for h in v] for k, v in runs.items()}
    grouped: dict[str, list[np.ndarray]] = {}
    for fit in runs:
        if not isinstance(fit, Fit):
            raise TypeError(f"expected Fit objects, got {type(fit).__name__}")
        grouped.setdefault(fit.method, []).append(np.asarray(fit.history.best, dtype=float))
    return grouped


def plot_convergence(
    runs: Fit | Sequence[Fit] | Mapping[str, Sequence[Sequence[float]]],
    *,
    ax: Axes | None = None,
    figsize: tuple[float, float] = (7.0, 4.5),
    dpi: float = 100.0,
    title: str | None = "Convergence of the search",
) -> Figure:
    """Best cost against generation (log scale) for every run, median per method in bold."""
    grouped = _histories(runs)
    if not grouped or not any(len(v) for v in grouped.values()):
        raise ValueError("plot_convergence needs at least one run")
    fig, ax = figure_axes(ax, figsize=figsize, dpi=dpi)
    for i, (method, histories) in enumerate(grouped.items()):
        colour = METHOD_COLOURS.get(method.lower(), f"C{i}")
        for h in histories:
            ax.plot(np.arange(h.size), h, color=colour, alpha=0.3, linewidth=0.8)
        length = min(h.size for h in histories)
        median = np.median(np.stack([h[:length] for h in histories]), axis=0)
        label = f"{method.upper()} (median of {len(histories)})" if len(histories) > 1 else (
            method.upper()
        )
        ax.plot(np.arange(length), median, color=colour, linewidth=2.2, label=label)
    ax.set_yscale("log")
    ax.xaxis.set_major_locator(MaxNLocator(integer=True))
    ax.set_xlabel("generation")
    ax.set_ylabel("best cost (mean squared NRMSE)")
    ax.legend(frameon=False)
    if title:
        ax.set_title(title)
    return fig


def plot_intervals(
    fit: Fit,
    truth: Mapping[str, float] | None = None,
    *,
    ax: Axes | None = None,
    figsize: tuple[float, float] = (7.0, 4.0),
    dpi: float = 100.0,
    title: str | None = None,
) -> Figure:
    """Each parameter's interval scaled to ±1, labelled with its spread; ``truth`` marked."""
    if not fit.intervals:
        raise ValueError("this fit has no intervals (identify(..., intervals=True) computes them)")
    fig, ax = figure_axes(ax, figsize=figsize, dpi=dpi)
    names = list(fit.intervals)
    log = dict(zip(fit.names, fit.identifiability.get("coordinates", ()), strict=False))
    y = np.arange(len(names))[::-1]
    reach = 1.0
    for yi, name in zip(y, names, strict=True):
        value = fit.params[name]
        lo, hi = fit.intervals[name]
        colour = RESIDUAL if name in fit.poorly_identifiable else MODEL
        ax.plot([-1.0, 1.0], [yi, yi], color=colour, linewidth=3, solid_capstyle="butt")
        ax.plot([0.0], [yi], "o", color=colour, markersize=5)
        if log.get(name, "log") == "log" and hi / value > 1.5:
            spread = f"×/÷ {hi / value:.3g}"
        elif log.get(name, "log") == "log":
            spread = f"± {100 * (hi / value - 1):.2g} %"
        else:
            spread = f"± {100 * (hi - value) / abs(value):.2g} %"
        ax.annotate(f"{value:.5g}  {spread}", (1.0, yi), xytext=(6, 4),
                    textcoords="offset points", fontsize=8, color=colour)
        if truth is not None and name in truth:
            if log.get(name, "log") == "log":
                where = np.log(truth[name] / value) / np.log(hi / value)
            else:
                where = (truth[name] - value) / (hi - value)
            reach = max(reach, min(abs(where), 5.0) + 0.3)
            ax.plot([np.clip(where, -5.0, 5.0)], [yi], "x", color=MARK, markersize=8, mew=2)
    ax.set_yticks(y, [f"{n}{' (poor)' if n in fit.poorly_identifiable else ''}" for n in names])
    ax.set_xlim(-reach - 0.2, reach + 1.2)
    ax.axvline(0.0, color="0.6", linewidth=0.8)
    note = "; x = true value" if truth is not None else ""
    ax.set_xlabel(f"position in the {100 * fit.level:g} % interval (±1 = its ends{note})")
    ax.set_title(title or f"Parameter intervals ({fit.method.upper()}, seed {fit.seed})")
    return fig


def plot_fit(
    fit: Fit,
    truth: Mapping[str, float] | None = None,
    *,
    figsize: tuple[float, float] = (11.0, 4.5),
    dpi: float = 100.0,
) -> Figure:
    """Convergence (left) and parameter intervals (right) of one fit."""
    fig, axes = new_figure(1, 2 if fit.intervals else 1, figsize=figsize, dpi=dpi)
    plot_convergence(fit, ax=axes[0, 0])
    if fit.refinement is not None and fit.refinement.accepted:
        generations = fit.history.best.size - 1
        axes[0, 0].plot([generations], [fit.cost], "*", color=MARK, markersize=12,
                        label="after refinement")
        axes[0, 0].legend(frameon=False)
    if fit.intervals:
        plot_intervals(fit, truth, ax=axes[0, 1])
    return fig


__all__ = ["plot_convergence", "plot_fit", "plot_intervals"]
