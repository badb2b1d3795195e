"""Figure of a record (measured or simulated): torque, joint angle and tip acceleration."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from matplotlib.figure import Figure

from jaxflex.data import Record
from jaxflex.plots._style import new_figure


def plot_record(records: Record | Sequence[Record], *, figsize=(8.0, 6.5), dpi=100.0) -> Figure:
    """Torque, joint angle (degrees) and tip acceleration of one or several records."""
    records = [records] if isinstance(records, Record) else list(records)
    fig, axes = new_figure(3, 1, figsize=figsize, dpi=dpi, sharex=True)
    ax_tau, ax_angle, ax_acc = axes[:, 0]
    for record in records:
        ax_tau.plot(record.time, record.torque, label=record.name)
        ax_angle.plot(record.time, np.degrees(record.joint_angle), label=record.name)
        ax_acc.plot(record.time, record.tip_acceleration, linewidth=0.8, label=record.name)
    ax_tau.set_ylabel("torque [N m]")
    ax_angle.set_ylabel("joint angle [deg]")
    ax_acc.set_ylabel("tip acceleration [m/s²]")
    ax_acc.set_xlabel("time [s]")
    if len(records) > 1:
        ax_tau.legend(loc="upper right", frameon=False)
    return fig
