"""Figures of an excitation design.

* :func:`plot_design` — the designed torque and the predicted response (joint angle and speed
  against their limits, tip acceleration);
* :func:`plot_intervals` — predicted 95 % interval half-widths per parameter for several inputs
  (grouped bars, log scale), optionally with the criterion's history beside it.

Everything drawn is read from a :class:`~jaxflex.design.DesignResult` or from the output of
:func:`~jaxflex.design.compare_inputs`; nothing is computed here.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np
from matplotlib.figure import Figure

from jaxflex.design import CRITERIA, DesignResult
from jaxflex.plots._style import MARK, MEASURED, MODEL, new_figure, style

DESIGN_FIGSIZE = (8.0, 7.0)
"""Default size (inches) of the designed-input figure."""
INTERVALS_FIGSIZE = (10.0, 4.5)
"""Default size (inches) of the predicted-intervals figure."""
_INPUT_COLOURS = ("tab:blue", "tab:orange", "tab:green", "tab:red", "tab:purple", "tab:brown")


def plot_design(
    result: DesignResult,
    *,
    figsize: tuple[float, float] = DESIGN_FIGSIZE,
    dpi: float = 100.0,
    title: str | None = None,
) -> Figure:
    """Designed torque (with its peak and RMS limits) and the response predicted by the model."""
    fig, axes = new_figure(3, 1, figsize=figsize, dpi=dpi, sharex=True)
    ax_tau, ax_motion, ax_acc = axes[:, 0]
    t, lim = result.time, result.limits

    ax_tau.plot(t, result.torque, color=MODEL, lw=1.0, label="designed torque")
    for sign in (-1, 1):
        ax_tau.axhline(sign * lim["peak_torque"], color=MARK, ls="--", lw=0.8)
    ax_tau.axhline(lim["rms_torque"], color=MEASURED, ls=":", lw=0.8)
    ax_tau.set_ylabel("torque (N m)")
    ax_tau.legend(
        [ax_tau.lines[0], ax_tau.lines[1], ax_tau.lines[3]],
        [
            f"designed ({result.criterion}-optimal), rms {result.achieved['rms_torque']:.3g} N m",
            f"peak limit ±{lim['peak_torque']:g}",
            f"rms limit {lim['rms_torque']:g}",
        ],
        loc="upper right",
        fontsize="small",
    )

    ax_motion.plot(t, result.joint_angle, color=MODEL, lw=1.0, label="joint angle (rad)")
    ax_motion.plot(t, result.joint_velocity, color="tab:green", lw=1.0, label="joint speed (rad/s)")
    for sign in (-1, 1):
        ax_motion.axhline(sign * lim["max_angle"], color=MODEL, ls="--", lw=0.8)
        ax_motion.axhline(sign * lim["max_speed"], color="tab:green", ls="--", lw=0.8)
    ax_motion.set_ylabel("predicted motion")
    ax_motion.legend(loc="upper right", fontsize="small", title="dashed: limits")

    ax_acc.plot(t, result.tip_acceleration, color=MODEL, lw=0.8)
    ax_acc.set_ylabel("tip acceleration (m/s²)")
    ax_acc.set_xlabel("time (s)")
    worst, width = result.worst
    fig.suptitle(
        title or f"designed excitation: worst predicted interval ±{100 * width:.3g} % ({worst})"
    )
    return fig


def plot_intervals(
    comparison: Mapping[str, Mapping[str, Mapping[str, float]]],
    *,
    history: Sequence[float] | None = None,
    criterion: str = "",
    figsize: tuple[float, float] = INTERVALS_FIGSIZE,
    dpi: float = 100.0,
    title: str | None = None,
) -> Figure:
    """Predicted relative 95 % half-widths (%) per parameter, one bar per input.

    ``comparison`` maps an input's name to ``{"intervals": {parameter: half-width}, ...}`` (as
    :func:`~jaxflex.design.compare_inputs` returns); with ``history`` a second panel shows the
    design criterion against the iteration.
    """
    if not comparison:
        raise ValueError("comparison must hold at least one input")
    ncols = 1 if history is None else 2
    ratios = None if history is None else [3.0, 1.0]
    fig = Figure(figsize=figsize, dpi=dpi, layout="constrained")
    axes = fig.subplots(1, ncols, squeeze=False, gridspec_kw={"width_ratios": ratios})[0]
    for ax in axes:
        style(ax)
    ax = axes[0]
    inputs = list(comparison)
    names = list(comparison[inputs[0]]["intervals"])
    width = 0.8 / len(inputs)
    x = np.arange(len(names))
    for i, label in enumerate(inputs):
        values = [100 * comparison[label]["intervals"][n] for n in names]
        ax.bar(
            x + (i - (len(inputs) - 1) / 2) * width,
            values,
            width,
            label=label,
            color=_INPUT_COLOURS[i % len(_INPUT_COLOURS)],
        )
    ax.set_yscale("log")
    ax.set_xticks(x, names)
    ax.set_ylabel("predicted 95 % half-width (% of value)")
    ax.legend(fontsize="small")
    if history is not None:
        axes[1].plot(np.arange(len(history)), history, marker="o", ms=3, color=MODEL)
        axes[1].set_xlabel("iteration")
        label = f"{criterion}: {CRITERIA[criterion]}" if criterion in CRITERIA else criterion
        axes[1].set_ylabel(label or "criterion")
    fig.suptitle(title or "predicted parameter intervals per input (same RMS torque)")
    return fig


__all__ = ["plot_design", "plot_intervals"]
