"""Figures of an identification: convergence of the search and the parameter intervals.

* :func:`plot_convergence` — best cost per generation, one thin line per run and the median of
  each method thick (the paper's convergence curves);
* :func:`plot_intervals` — each identified parameter's interval as percent deviation from its
  estimate on a symmetric-log axis, the robust (HAC) interval beneath it, unidentifiable
  parameters marked as such, and the true value where known;
* :func:`plot_fit` — both for one :class:`~jaxflex.identification.Fit`.

Everything drawn is read from fits (or their histories); nothing is computed here but medians.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np
from matplotlib.axes import Axes
from matplotlib.figure import Figure
from matplotlib.ticker import FixedLocator, MaxNLocator, NullLocator

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


def _percent(value: float, ends) -> np.ndarray:
    """Interval ends as deviations from the estimate, in percent of it."""
    with np.errstate(divide="ignore", invalid="ignore"):
        return 100.0 * (np.asarray(ends, dtype=float) - value) / abs(value)


def _spread(rel: np.ndarray) -> str:
    """``±x %`` for a symmetric interval, ``−a/+b %`` otherwise."""
    lo, hi = -rel[0], rel[1]
    if np.isclose(lo, hi, rtol=0.05):
        return f"±{_number(hi)} %"
    return f"−{_number(lo)}/+{_number(hi)} %"


def _number(value: float) -> str:
    """Two significant digits, whole numbers from 100 on (no exponent below 10⁶), ``4.4e7``
    beyond, ``∞`` for no end."""
    if not np.isfinite(value):
        return "∞"
    if 99.5 <= value < 1e6:
        return f"{value:.0f}"
    mantissa, _, exponent = f"{value:.2g}".partition("e")
    return f"{mantissa}e{int(exponent)}" if exponent else mantissa


def _decade_ticks(linthresh: float, left: float, right: float, per_side: int = 3) -> list[float]:
    """0 and ±powers of ten from ``linthresh`` out to the limits, at most ``per_side`` a side,
    the same decades on both sides (every second or third where more would crowd the labels):
    equal steps along the axis."""
    first = int(np.floor(np.log10(linthresh)))
    lasts = [int(np.floor(np.log10(limit))) if limit >= linthresh else first - 1
             for limit in (-left, right)]
    step = max(1, int(np.ceil((max(lasts) - first + 1) / per_side)))
    ticks = [0.0]
    for sign, last in zip((-1.0, 1.0), lasts, strict=True):
        ticks += [sign * 10.0**k for k in range(first, last + 1, step)]
    return sorted(ticks)


UNIDENTIFIABLE_REACH = 1e3
"""Where the interval figure stops an unidentifiable parameter's bar (percent of the value)."""


def plot_intervals(
    fit: Fit,
    truth: Mapping[str, float] | None = None,
    *,
    ax: Axes | None = None,
    figsize: tuple[float, float] = (7.0, 4.0),
    dpi: float = 100.0,
    title: str | None = None,
) -> Figure:
    """Each parameter's interval as percent deviation from its estimate (symmetric-log axis,
    so ±0.01 % and ±300 % are both readable); the robust (HAC) interval thinner beneath the
    nominal one; unidentifiable parameters marked as such; ``truth`` marked ×."""
    if not fit.intervals:
        raise ValueError("this fit has no intervals (identify(..., intervals=True) computes them)")
    fig, ax = figure_axes(ax, figsize=figsize, dpi=dpi)
    names = list(fit.intervals)
    y = np.arange(len(names))[::-1].astype(float)
    robust = fit.robust_intervals
    ends, labels = [], []
    for yi, name in zip(y, names, strict=True):
        value = fit.params[name]
        rel = _percent(value, fit.intervals[name])
        shown = name in fit.unidentifiable or not np.all(np.isfinite(rel))
        colour = RESIDUAL if name in fit.poorly_identifiable or shown else MODEL
        if shown:
            ax.annotate("", (UNIDENTIFIABLE_REACH, yi), (-100.0, yi), color=colour,
                        arrowprops={"arrowstyle": "<->", "color": colour, "lw": 1.5})
            labels.append(f"{name}\nnot identifiable")
        else:
            ax.plot(rel, [yi, yi], color=colour, linewidth=4, solid_capstyle="butt")
            ends.extend(np.abs(rel))
            text = f"{name}\n{_spread(rel)}"
            if name in robust:
                rob = _percent(value, robust[name])  # labelled as it is, drawn within reach
                drawn = np.clip(np.where(np.isfinite(rob), rob, UNIDENTIFIABLE_REACH),
                                -100.0, UNIDENTIFIABLE_REACH)
                ax.plot(drawn, [yi - 0.28, yi - 0.28], color=colour, alpha=0.45, linewidth=2,
                        solid_capstyle="butt")
                ends.extend(np.abs(drawn))
                text += f" (robust {_spread(rob)})"
            labels.append(text)
        ax.plot([0.0], [yi], "o", color=colour, markersize=5)
        if truth is not None and name in truth:
            where = float(_percent(value, [truth[name]])[0])
            ends.append(abs(where))
            ax.plot([where], [yi], "x", color=MARK, markersize=8, mew=2)
    finite = [e for e in ends if np.isfinite(e) and e > 0]
    linthresh = 10.0 ** np.floor(np.log10(min(finite))) if finite else 1.0
    reach = max(finite, default=1.0)
    if any(t.endswith("not identifiable") for t in labels):
        reach = max(reach, UNIDENTIFIABLE_REACH)
    ax.set_xscale("symlog", linthresh=linthresh, linscale=1.0)
    left, right = -min(1.5 * reach, 100.0), 1.5 * reach
    ax.set_xlim(left, right)
    ax.xaxis.set_major_locator(FixedLocator(_decade_ticks(linthresh, left, right)))
    ax.xaxis.set_minor_locator(NullLocator())
    ax.set_ylim(y.min() - 0.7, y.max() + 0.5)
    ax.set_yticks(y, labels, fontsize=8)
    ax.axvline(0.0, color="0.6", linewidth=0.8)
    keys = ["thin: robust"] if robust else []
    keys += ["×: true value"] if truth is not None else []
    key = f"\n({', '.join(keys)})" if keys else ""
    ax.set_xlabel(f"{100 * fit.level:g} % interval, % of the estimate{key}")
    conditional = ": conditional on the model" if fit.model_conditional else ""
    ax.set_title(title or f"Intervals ({fit.method.upper()}, seed {fit.seed}){conditional}",
                 fontsize=10)
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
