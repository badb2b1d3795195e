"""Figure of a record (measured or simulated): its input and its output channels."""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np
from matplotlib.figure import Figure

from jaxflex.data import OUTPUT_COLUMNS, Record
from jaxflex.plots._style import new_figure


def plot_record(
    records: Record | Sequence[Record],
    *,
    channels: Sequence[str] | None = None,
    units: Mapping[str, str] | None = None,
    figsize=(8.0, 6.5),
    dpi=100.0,
) -> Figure:
    """The input and each channel of one or several records, one panel each.

    ``channels`` default to the joint angle (in degrees) and tip acceleration of the reference
    format, or, for a record as a rig logs it, ``units``' channels (each in the unit given
    there, e.g. a sensor's own).
    """
    records = [records] if isinstance(records, Record) else list(records)
    units = dict(units or {})
    first = records[0]
    if channels is None:
        channels = [c for c in units if c not in ("time", first.input_name)] or [
            c for c in OUTPUT_COLUMNS if c in first.columns]
    fig, axes = new_figure(1 + len(channels), 1, figsize=figsize, dpi=dpi, sharex=True)
    ax_input, *ax_channels = axes[:, 0]
    for record in records:
        ax_input.plot(record.time, record.input, label=record.name)
        for ax, c in zip(ax_channels, channels, strict=True):
            y = record.channel(c)
            ax.plot(record.time, np.degrees(y) if _in_degrees(c, units) else y,
                    linewidth=0.8, label=record.name)
    input_unit = units.get(first.input_name) or first.units[first.input_name] or "unit"
    ax_input.set_ylabel(f"{first.input_name} [{input_unit}]")
    for ax, c in zip(ax_channels, channels, strict=True):
        unit = "deg" if _in_degrees(c, units) else units.get(c) or first.units.get(c) or "-"
        ax.set_ylabel(f"{c.replace('_', ' ')} [{unit}]")
    axes[-1, 0].set_xlabel("time [s]")
    if len(records) > 1:
        ax_input.legend(loc="upper right", frameon=False)
    return fig


def _in_degrees(channel: str, units: Mapping[str, str]) -> bool:
    """The reference format's joint angle is shown in degrees."""
    return channel == "joint_angle" and channel not in units
