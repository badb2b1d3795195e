"""Figures of a discovery run, and the report directory ``jaxflex discover --report`` writes.

* :func:`plot_discovery` — the error falling as effects are added (NRMSE per output, FRF NRMSE,
  held-out error), noise floors dashed;
* :func:`plot_before_after` — one record measured against the base and the final model;
* :func:`save_discovery_report` — ``table.txt``, ``discover.json``, the error figure, the
  diagnosis of the base and final model and a before/after overlay per record.

Everything drawn is read from a :class:`~jaxflex.discovery.DiscoveryReport`.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path

from matplotlib.figure import Figure

from jaxflex._io import check_writable, safe_stem, write_json, write_text
from jaxflex.comparison import channel_units
from jaxflex.discovery import DiscoveryReport
from jaxflex.plots._style import save_figure
from jaxflex.plots.diagnose import plot_diagnosis, plot_error_falling, plot_overlay


def plot_discovery(report: DiscoveryReport, **kwargs) -> Figure:
    """The error of every step of ``report`` (see :func:`plot_error_falling`)."""
    steps = report.steps
    outputs = report.channels
    holdout = None
    if steps[0].holdout:
        holdout = {o: [100.0 * s.holdout["relative_error"][o] for s in steps] for o in outputs}
    return plot_error_falling(
        [s.structure for s in steps],
        {o: [s.nrmse[o] for s in steps] for o in outputs},
        noise_floor=report.noise_floor,
        frf_nrmse=[s.frf_nrmse for s in steps],
        holdout=holdout,
        **kwargs,
    )


def plot_before_after(report: DiscoveryReport, which: int | str = 0, **kwargs) -> Figure:
    """Record ``which`` (position or name; the fitted records, then the held-out ones) against
    the base and the final model, each channel in its unit."""
    records = [*report.records, *(report.holdout or ())]
    names = [r.name for r in records]
    i = names.index(which) if isinstance(which, str) else which
    first, last = report.base, report.final
    before = [*first.predictions, *first.holdout_predictions]
    after = [*last.predictions, *last.holdout_predictions]
    role = "fitted" if i < len(report.records) else "held out"
    labels = (first.structure, last.structure)
    if labels[0] == labels[1]:
        labels = (f"{labels[0]}, nothing added", labels[1])
    return plot_overlay(
        records[i], before[i], after[i], labels=labels, outputs=report.channels,
        units=channel_units(last.fit.model, report.channels), role=role, **kwargs,
    )


def report_paths(names: Sequence[str], directory: str | os.PathLike,
                 fmt: str = "png") -> tuple[Path, ...]:
    """The files :func:`save_discovery_report` writes for a run on records ``names`` (the
    fitted ones, then the held-out ones: each gets a before/after figure)."""
    directory = Path(directory)
    stems = [safe_stem(n) for n in names]
    if len(set(stems)) != len(stems):
        raise ValueError(f"record names {list(names)} map to clashing file names")
    return (
        directory / "table.txt",
        directory / "discover.json",
        directory / f"error_falling.{fmt}",
        directory / f"diagnosis_base.{fmt}",
        directory / f"diagnosis_final.{fmt}",
        *(directory / f"{s}_before_after.{fmt}" for s in stems),
    )


def save_discovery_report(
    report: DiscoveryReport,
    directory: str | os.PathLike,
    *,
    overwrite: bool = False,
    fmt: str = "png",
) -> tuple[Path, ...]:
    """Write the step table, the JSON and every figure of ``report`` into ``directory``.

    Every target is checked before anything is written, so a refused overwrite leaves the
    directory untouched.
    """
    directory = Path(directory)
    if directory.exists() and not directory.is_dir():
        raise ValueError(f"{directory}: exists and is not a directory")
    names = [*report.records.names, *(report.holdout.names if report.holdout else ())]
    targets = report_paths(names, directory, fmt)
    for path in targets:
        check_writable(path, overwrite)
    text = report.table() + "\n" + "\n".join(report.explanations()) + "\n" + report.summary()
    write_text(targets[0], text, overwrite=overwrite)
    write_json(targets[1], report.to_dict(), overwrite=overwrite)
    save_figure(plot_discovery(report), targets[2], overwrite=overwrite)
    model = report.final.fit.model
    drive = {"units": channel_units(model, report.channels),
             "input_name": report.records[0].input_name, "input_unit": model.drive.unit}
    save_figure(plot_diagnosis(report.base.diagnosis, **drive), targets[3], overwrite=overwrite)
    save_figure(plot_diagnosis(report.final.diagnosis, **drive), targets[4], overwrite=overwrite)
    for i, path in enumerate(targets[5:]):
        save_figure(plot_before_after(report, i), path, overwrite=overwrite)
    return targets


__all__ = ["plot_before_after", "plot_discovery", "report_paths", "save_discovery_report"]
