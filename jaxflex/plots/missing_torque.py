"""Figure of the missing hub torque: ``d̂`` over time with its ±2σ band, and as scatter maps
against the smoothed hub velocity, angle and the input, each with the found map's terms in that
variable drawn over the points."""

from __future__ import annotations

import numpy as np
from matplotlib.figure import Figure

from jaxflex.missing_torque import MissingTorque
from jaxflex.plots._style import MEASURED, MODEL, RESIDUAL, new_figure
from jaxflex.torque_regression import TorqueMap

MISSING_TORQUE_FIGSIZE = (9.0, 7.0)
"""Default size (inches) of the missing-torque figure."""
MAX_POINTS = 4000
"""At most this many points (evenly thinned) in each scatter map."""


def plot_missing_torque(estimate: MissingTorque, torque_map: TorqueMap | None = None, *,
                        input_unit: str = "N m",
                        figsize: tuple[float, float] = MISSING_TORQUE_FIGSIZE,
                        dpi: float = 100.0) -> Figure:
    """``d̂(t)`` of every record with its ±2σ band (and the map's value, given ``torque_map``);
    ``d̂`` against ``ω̂``, ``θ̂`` and ``u`` with the map's terms in each variable alone (and its
    constant) drawn over the points. ``input_unit`` labels the input axis."""
    fig, axes = new_figure(2, 2, figsize=figsize, dpi=dpi)
    ax_t, ax_w, ax_th, ax_u = axes.flat
    records = estimate.records
    for i, r in enumerate(records):
        first = i == 0
        ax_t.fill_between(r.time, r.torque - 2 * r.std, r.torque + 2 * r.std, color=MODEL,
                          alpha=0.25, lw=0, label="±2σ" if first else None)
        ax_t.plot(r.time, r.torque, color=MODEL, lw=0.8, label="estimated d̂" if first else None)
        if torque_map is not None and torque_map.selected:
            ax_t.plot(r.time, torque_map.evaluate(r.theta, r.omega, r.u, r.time), color=RESIDUAL,
                      lw=0.8, ls="--", label="map" if first else None)
    ax_t.set_xlabel("time (s)")
    ax_t.set_ylabel("missing torque d̂ (N m)")
    pooled = {k: np.concatenate([getattr(r, k) for r in records])
              for k in ("torque", "theta", "omega", "u")}
    stride = max(1, -(-pooled["torque"].size // MAX_POINTS))
    y = pooled["torque"][::stride]
    for ax, key, label in ((ax_w, "omega", "hub velocity ω̂ (rad/s)"),
                           (ax_th, "theta", "hub angle θ̂ (rad)"),
                           (ax_u, "u", f"input u ({input_unit})")):
        x = pooled[key][::stride]
        ax.scatter(x, y, s=3, color=MEASURED, alpha=0.4, lw=0, rasterized=True)
        ax.set_xlabel(label)
        ax.set_ylabel("d̂ (N m)")
        if torque_map is not None and torque_map.selected:
            grid = np.linspace(np.min(x), np.max(x), 400)
            values = {k: np.zeros_like(grid) for k in ("theta", "omega", "u")} | {key: grid}
            curve = torque_map.evaluate(values["theta"], values["omega"], values["u"],
                                        np.zeros_like(grid), only={key})
            ax.plot(grid, curve, color=RESIDUAL, lw=1.2)
    ax_w.scatter([], [], s=9, color=MEASURED, label="d̂ at the samples")
    if torque_map is not None and torque_map.selected:
        ax_w.plot([], [], color=RESIDUAL, lw=1.2, label="map's terms in that variable")
    title = "missing hub torque"
    if torque_map is not None:
        title += f": {torque_map.words}"
    if torque_map is not None and torque_map.selected:
        title += (f"\nmap: {_short(torque_map.expression)} (explains "
                  f"{100 * torque_map.explained:.0f} % of its variance)")
    fig.suptitle(title, fontsize="medium")
    handles, labels = [], []
    for ax in (ax_t, ax_w):
        h, lab = ax.get_legend_handles_labels()
        handles, labels = handles + h, labels + lab
    fig.legend(handles, labels, loc="outside lower center", ncols=min(len(labels), 5),
               fontsize="small", frameon=False)
    return fig


def _short(expression: str, width: int = 90) -> str:
    """The expression, cut to ``width`` characters for a title."""
    return expression if len(expression) <= width else expression[: width - 1] + "…"


__all__ = ["plot_missing_torque"]
