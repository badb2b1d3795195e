"""Figures of a model-versus-measurement comparison, and the report that bundles them.

* :func:`plot_time` — measured and simulated outputs of one record, each with its residual
  underneath on a shared time axis;
* :func:`plot_frf` — FRF magnitude (dB) and unwrapped phase, measured against model, with the
  model's resonances marked and labelled in Hz and the bins left out of the FRF NRMSE shown apart;
* :func:`save_report` — the table, ``comparison.json`` and every figure into one directory.

Everything drawn is read from a :class:`~jaxflex.comparison.Comparison` (or a record and its
simulated outputs); no metric is computed here.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from matplotlib.figure import Figure
from matplotlib.ticker import MaxNLocator

from jaxflex._io import check_writable, safe_stem, write_json, write_text
from jaxflex.comparison import FRF, Comparison, merged_peaks
from jaxflex.data import OUTPUT_COLUMNS, Record
from jaxflex.plots._style import MARK, MEASURED, MODEL, RESIDUAL, new_figure, save_figure
from jaxflex.simulation import Outputs

TIME_FIGSIZE = (8.0, 6.5)
"""Default size (inches) of the time-domain comparison figure."""
FRF_FIGSIZE = (8.0, 6.0)
"""Default size (inches) of the frequency-response comparison figure."""


def plot_time(
    source: Comparison | Record,
    which: int | str = 0,
    *,
    simulated: Outputs | Record | None = None,
    outputs: Sequence[str] | None = None,
    figsize: tuple[float, float] = TIME_FIGSIZE,
    dpi: float = 100.0,
    title: str | None = None,
) -> Figure:
    """Measured vs model for each output of one record, the residual (measured − model) below.

    ``source`` is a comparison (``which`` picks the record by name or position; the legend
    quotes its NRMSE; ``outputs`` default to its channels that the record logs, in their units)
    or a measured record together with ``simulated`` outputs (``outputs`` default to joint
    angle and tip acceleration).
    """
    units: dict[str, str] = {}
    if isinstance(source, Comparison):
        record, out, row = source.record(which), source.outputs(which), source[which]
        if outputs is None:  # the channels the record logs
            outputs = [c for c in source.channels if c in record.columns]
        units = source.units
    elif isinstance(source, Record):
        if simulated is None:
            raise ValueError("plot_time(record, ...) needs the simulated outputs: simulated=...")
        record, out, row = source, simulated, None
    else:
        raise TypeError(f"plot_time expects a Comparison or a Record, got {type(source).__name__}")
    outputs = OUTPUT_COLUMNS if outputs is None else outputs
    outputs = [outputs] if isinstance(outputs, str) else list(outputs)
    if not outputs:
        raise ValueError("outputs must name at least one output")

    fig, axes = new_figure(
        2 * len(outputs),
        1,
        figsize=figsize,
        dpi=dpi,
        sharex=True,
        height_ratios=[3.0, 1.2] * len(outputs),
    )
    t = record.time
    for k, name in enumerate(outputs):
        model = np.asarray(out.channel(name))
        measured = record.channel(name)
        if model.shape != measured.shape:
            raise ValueError(
                f"simulated {name} has shape {model.shape} but record "
                f"{record.name!r} has {measured.shape}"
            )
        unit = units.get(name) or record.units.get(name) or "-"
        label = name.replace("_", " ")
        ax, ax_res = axes[2 * k, 0], axes[2 * k + 1, 0]
        model_label = (
            "model"
            if row is None or name not in row.nrmse
            else (f"model (NRMSE {row.nrmse[name]:.3g} %)")
        )
        ax.plot(t, measured, color=MEASURED, lw=1.0, label="measured")
        ax.plot(t, model, color=MODEL, lw=1.3, ls="--", label=model_label)
        ax.set_ylabel(f"{label}\n({unit})")
        ax.legend(loc="best", fontsize="small", frameon=False)
        ax_res.plot(t, measured - model, color=RESIDUAL, lw=0.8)
        ax_res.axhline(0.0, color="0.5", lw=0.6)
        ax_res.set_ylabel(f"residual\n({unit})")
    axes[-1, 0].set_xlabel("time (s)")
    axes[-1, 0].set_xlim(t[0], t[-1])
    fig.align_ylabels(axes[:, 0])  # one column of labels, clear of every axes' tick labels
    role = f" ({row.role})" if row is not None else ""
    fig.suptitle(title or f"{record.name}{role}: measured vs model")
    return fig


def plot_frf(
    source: Comparison | FRF,
    which: int | str | Sequence[int | str] | None = None,
    *,
    resonances_hz: Sequence[float] | None = None,
    f_max: float | None = None,
    figsize: tuple[float, float] = FRF_FIGSIZE,
    dpi: float = 100.0,
    title: str | None = None,
) -> Figure:
    """FRF input → link channel (torque → tip acceleration on the reference testbed):
    magnitude (dB re one output unit per drive input unit) and phase, measured vs model; the
    phase unwrapped along the model, each measured bin drawn within ±180° of it.

    ``source`` is a comparison (``which``: one record, several, or ``None`` for all) or a single
    :class:`~jaxflex.comparison.FRF`. Measured bins used by the FRF NRMSE are dots, bins left out
    (low input power or coherence) faint crosses; the model is a line over the compared bins.
    The model's resonances (``resonances_hz``, default: the peaks of the shown records' model
    FRFs, the model as fitted with its hub's real boundary) are dashed vertical lines labelled
    in Hz, the measured FRF's prominent peaks triangles (one legend entry for
    all records). The frequency axis runs to ``f_max`` (default: the comparison's band, 15 Hz).
    """
    path = ("torque", "tip_acceleration", {"torque": "N m", "tip_acceleration": "m s⁻²"})
    if isinstance(source, Comparison):
        path = (source.input_name, source.link, source.units)
        keys = (
            range(len(source))
            if which is None
            else ([which] if isinstance(which, (int, str)) else list(which))
        )
        rows = [source[k] for k in keys]
        curves = [(r.name, r.frf, r.measured_peaks_hz) for r in rows]
        resonances = (merged_peaks(p for r in rows for p in r.model_peaks_hz)
                      if resonances_hz is None else resonances_hz)
        f_max = source.frf_settings.f_max if f_max is None else f_max
    elif isinstance(source, FRF):
        curves = [("", source, ())]
        resonances = () if resonances_hz is None else resonances_hz
        f_max = source.f_max if f_max is None else f_max
    else:
        raise TypeError(f"plot_frf expects a Comparison or an FRF, got {type(source).__name__}")
    if not curves:
        raise ValueError("plot_frf: no record selected")
    if not f_max > 0:
        raise ValueError(f"f_max={f_max!r} must be a positive frequency (Hz)")

    fig, axes = new_figure(2, 1, figsize=figsize, dpi=dpi, sharex=True, height_ratios=[2.0, 1.0])
    ax_mag, ax_phase = axes[0, 0], axes[1, 0]
    single = len(curves) == 1
    shown_db, shown_phase = [], []
    peak_label = "measured peak"
    for i, (name, frf, peaks) in enumerate(curves):
        if not np.isfinite(frf.measured).any():  # the record does not log the link channel
            continue
        show = (frf.freqs > 0) & (frf.freqs <= f_max) & np.isfinite(frf.measured)
        used, left_out = show & frf.compared, show & ~frf.compared
        f = frf.freqs
        meas_db, model_db = _db(frf.measured), _db(frf.model)
        colour_meas, colour_model = (MEASURED, MODEL) if single else (f"C{i}", f"C{i}")
        suffix = "" if single else f" {name}"
        gaps = np.where(frf.compared, model_db, np.nan)  # no line through left-out bins
        ax_mag.plot(f[show], gaps[show], color=colour_model, lw=1.4, label=f"model{suffix}")
        ax_mag.plot(f[used], meas_db[used], "o", color=colour_meas, ms=4, label=f"measured{suffix}")
        ax_mag.plot(
            f[left_out],
            meas_db[left_out],
            "x",
            color=colour_meas,
            ms=4,
            alpha=0.35,
            label="left out (low input power)" if i == 0 and left_out.any() else None,
        )
        model_phase, measured_phase = _unwrapped_phase(frf, show)
        ax_phase.plot(f[show], model_phase[show], color=colour_model, lw=1.2)
        ax_phase.plot(f[used], measured_phase[used], "o", color=colour_meas, ms=3)
        shown_phase += [model_phase[used], measured_phase[used]]
        visible_peaks = [p for p in peaks if p <= f_max]
        if visible_peaks:
            ax_mag.plot(
                visible_peaks,
                np.interp(visible_peaks, f[used], meas_db[used]) + 3.0,
                "v",
                color=colour_meas,
                ms=6,
                label=peak_label,
            )
            peak_label = None  # one legend entry for every record's peaks
        shown_db += [meas_db[used], model_db[used]]

    label_y, previous = 0.98, -np.inf
    for k, f_res in enumerate(r for r in resonances if r <= f_max):
        # a label close to the one before it drops a line, so that the two stay apart
        label_y = 1.89 - label_y if f_res - previous < 0.1 * f_max else 0.98
        previous = f_res
        for ax in (ax_mag, ax_phase):
            ax.axvline(
                f_res,
                color=MARK,
                ls="--",
                lw=1.0,
                label="model resonance (as fitted)" if ax is ax_mag and k == 0 else None,
            )
        ax_mag.text(
            f_res,
            label_y,
            f" {f_res:.2f} Hz",
            transform=ax_mag.get_xaxis_transform(),
            color=MARK,
            fontsize="small",
            ha="left",
            va="top",
        )

    levels = np.concatenate(shown_db) if shown_db else np.empty(0)
    levels = levels[np.isfinite(levels)]
    if levels.size:
        ax_mag.set_ylim(levels.min() - 10.0, levels.max() + 10.0)
    source_name, link, units = path
    input_unit = units.get(source_name) or {"torque": "N m", "current": "A",
                                             "voltage": "V"}.get(source_name, "unit")
    output_unit = units.get(link) or "unit"
    ratio = f"1/{input_unit}" if output_unit == "1" else f"1 {output_unit} / {input_unit}"
    ax_mag.set_ylabel(f"|H| (dB re {ratio})")
    ax_mag.legend(
        loc="lower left", bbox_to_anchor=(0.0, 1.0), fontsize="small", frameon=False, ncols=3
    )
    ax_phase.set_ylabel("phase (deg)")
    phases = np.concatenate(shown_phase) if shown_phase else np.empty(0)
    phases = phases[np.isfinite(phases)]
    if phases.size:
        ax_phase.set_ylim(phases.min() - 20.0, phases.max() + 20.0)
    ax_phase.yaxis.set_major_locator(MaxNLocator(nbins=5, steps=[1, 1.8, 3.6, 4.5, 9, 10]))
    ax_phase.set_xlabel("frequency (Hz)")
    ax_phase.set_xlim(0.0, f_max)
    label = f" — {curves[0][0]}" if single and curves[0][0] else ""
    arrow = f"{source_name} → {link.replace('_', ' ')}"
    fig.suptitle(title or f"FRF {arrow} (H1){label}")
    return fig


def save_report(
    comparison: Comparison,
    directory: str | os.PathLike,
    *,
    overwrite: bool = False,
    fmt: str = "png",
    dpi: float = 100.0,
) -> tuple[Path, ...]:
    """Write ``table.txt``, ``comparison.json``, one ``<record>_time`` figure per record and
    ``frf`` (all records) into ``directory``; returns the paths.

    Every target is checked before anything is written, so a refused overwrite leaves the
    directory untouched.
    """
    directory = Path(directory)
    if directory.exists() and not directory.is_dir():
        raise ValueError(f"{directory}: exists and is not a directory")
    targets = report_paths(comparison.names, directory, fmt)
    for path in targets:
        check_writable(path, overwrite)
    figures = targets[2:]
    write_text(targets[0], comparison.table(), overwrite=overwrite)
    write_json(targets[1], comparison.to_dict(), overwrite=overwrite)
    for i, path in enumerate(figures[:-1]):
        save_figure(plot_time(comparison, i, dpi=dpi), path, overwrite=overwrite)
    save_figure(plot_frf(comparison, dpi=dpi), figures[-1], overwrite=overwrite)
    return tuple(targets)


def report_paths(
    names: Sequence[str], directory: str | os.PathLike, fmt: str = "png"
) -> tuple[Path, ...]:
    """The files :func:`save_report` writes for records ``names``: ``table.txt``,
    ``comparison.json``, ``<record>_time.<fmt>`` for each record, then ``frf.<fmt>``."""
    directory = Path(directory)
    stems = [f"{safe_stem(n)}_time" for n in names]
    if len(set(stems)) != len(stems):
        raise ValueError(f"record names {list(names)} map to clashing file names")
    figures = [directory / f"{s}.{fmt}" for s in stems] + [directory / f"frf.{fmt}"]
    return (directory / "table.txt", directory / "comparison.json", *figures)


def _unwrapped_phase(frf: FRF, show: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Model and measured phase (deg) over the compared bins of ``show``: the model's unwrapped
    along the frequency axis (across left-out bins, whose phase means nothing, by the smallest
    step), starting within ±180°; each measured bin within ±180° of the model's (the same
    angle, the turn that reads continuously). NaN elsewhere."""
    model = np.full(frf.freqs.shape, np.nan)
    measured = np.full(frf.freqs.shape, np.nan)
    bins = np.flatnonzero(show & frf.compared & np.isfinite(frf.model) & (frf.model != 0))
    if bins.size:
        model[bins] = np.degrees(np.unwrap(np.angle(frf.model[bins])))
        measured[bins] = model[bins] + np.degrees(np.angle(frf.measured[bins] / frf.model[bins]))
    return model, measured


def _db(h: np.ndarray) -> np.ndarray:
    with np.errstate(divide="ignore", invalid="ignore"):
        return 20.0 * np.log10(np.abs(h))


__all__ = ["plot_frf", "plot_time", "report_paths", "save_report"]
