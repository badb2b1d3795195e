"""Figure of one record's simulation beside its k-step-ahead predictions: each channel with the
measured signal, the free simulation and the prediction at every horizon, and below it each
one's error (measured − model), NRMSE in the legend."""

from __future__ import annotations

import numpy as np
from matplotlib.figure import Figure

from jaxflex.plots._style import MEASURED, MODEL, new_figure
from jaxflex.prediction_report import PredictionComparison

PREDICTION_FIGSIZE = (8.0, 6.5)
"""Default size (inches) of the prediction figure."""
HORIZON_COLOURS = ("tab:green", "tab:orange", "tab:purple", "tab:brown", "tab:pink")
"""Line colours of the horizons, in increasing order (repeated beyond five)."""


def plot_prediction(row: PredictionComparison, *, units: dict[str, str] | None = None,
                    figsize: tuple[float, float] = PREDICTION_FIGSIZE,
                    dpi: float = 100.0) -> Figure:
    """Measured, simulated and predicted channels of one record, their errors underneath."""
    channels, units = row.channels, units or {}
    fig, axes = new_figure(2 * len(channels), 1, figsize=figsize, dpi=dpi, sharex=True,
                           height_ratios=[3.0, 1.5] * len(channels))
    scores, p = row.scores(), row.prediction
    series = [("simulation", row.simulated, MODEL, "--")] + [
        (f"{h:g} s", y, HORIZON_COLOURS[i % len(HORIZON_COLOURS)], "-")
        for i, (h, y) in enumerate(sorted(p.predicted.items()))]
    for k, channel in enumerate(channels):
        ax, ax_err = axes[2 * k, 0], axes[2 * k + 1, 0]
        measured = p.measured[k]
        ax.plot(row.time, measured, color=MEASURED, lw=1.0, label="measured")
        for label, y, colour, style in series:
            name = label if label == "simulation" else f"{label} ahead"
            ax.plot(row.time, y[k], color=colour, lw=1.0, ls=style,
                    label=f"{name} ({scores[label][channel]:.3g} %)")
            ax_err.plot(row.time, measured - y[k], color=colour, lw=0.7, ls=style)
        unit = units.get(channel, "-")
        ax.set_ylabel(f"{channel.replace('_', ' ')}\n({unit})")
        ax.legend(loc="best", fontsize="x-small", frameon=False, ncol=2)
        spread = np.max(np.abs(measured - series[-1][1][k])) if len(series) > 1 else None
        if spread:  # the simulation's drift would hide the predictions' errors
            ax_err.set_ylim(-3.0 * spread, 3.0 * spread)
        ax_err.axhline(0.0, color="0.5", lw=0.6)
        ax_err.set_ylabel(f"error\n({unit})")
    axes[-1, 0].set_xlabel("time (s)")
    axes[-1, 0].set_xlim(row.time[0], row.time[-1])
    fig.align_ylabels(axes[:, 0])
    fig.suptitle(f"{row.name} ({row.role}): simulation and k-step-ahead prediction")
    return fig


__all__ = ["plot_prediction"]
