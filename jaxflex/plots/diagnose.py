"""Figures of residual diagnostics and of a discovery run.

* :func:`plot_autocorrelation` — residual autocorrelation with the white-noise band;
* :func:`plot_cross_correlation` — residual–torque correlation over lags, peak lag marked;
* :func:`plot_spectrum` — residual PSD against the noise floor, peaks labelled in Hz;
* :func:`plot_localisation` — misfit concentration per operating condition and time window;
* :func:`plot_diagnosis` — all of the above for both output channels on one page;
* :func:`plot_error_falling` — NRMSE per model structure of a discovery run, noise floor dashed;
* :func:`plot_overlay` — one record measured against the model before and after.

Every number drawn is read from a :class:`~jaxflex.diagnosis.Diagnosis` (or given); nothing is
computed here beyond unit conversions.
"""

from __future__ import annotations

import textwrap
from collections.abc import Mapping, Sequence

import numpy as np
from matplotlib.axes import Axes
from matplotlib.figure import Figure

from jaxflex.data import OUTPUT_COLUMNS, Record
from jaxflex.diagnosis import (
    Autocorrelation,
    CrossCorrelation,
    Diagnosis,
    Localisation,
    ResidualSpectrum,
)
from jaxflex.discovery.explain import noise_claim
from jaxflex.plots._style import MARK, MEASURED, MODEL, RESIDUAL, figure_axes, new_figure, style

_LABELS = {"joint_angle": "joint angle", "tip_acceleration": "tip acceleration",
           "root_strain": "root strain", "tip_deflection": "tip deflection",
           "joint_velocity": "joint velocity"}
_COLOURS = {"joint_angle": MODEL, "tip_acceleration": RESIDUAL, "root_strain": "tab:purple",
            "tip_deflection": "tab:brown", "joint_velocity": "tab:olive"}
_AFTER = "tab:green"


def _label(name: str) -> str:
    """A channel's name in words (``deflection_angle`` → ``deflection angle``)."""
    return _LABELS.get(name, name.replace("_", " "))


def _colour(name: str, i: int) -> str:
    """A channel's colour: its own where it has one, else the ``i``-th of the cycle."""
    return _COLOURS.get(name, f"C{i % 10}")


def _legend_beside(ax: Axes) -> None:
    """The axes' legend right of it, off the data (constrained layout makes room)."""
    ax.legend(loc="upper left", bbox_to_anchor=(1.02, 1.0), fontsize="small", frameon=False)


def plot_autocorrelation(acf: Autocorrelation, ax: Axes | None = None, title: str = "",
                         legend: bool = True) -> Figure:
    """Stem plot of ``ρ_k`` over the lag (ms) with the ``±1.96/√N`` band; Ljung–Box in the title
    (``legend``: the band's key beside the axes)."""
    fig, ax = figure_axes(ax)
    lag_ms = 1e3 * acf.lags * acf.dt
    ax.vlines(lag_ms, 0.0, acf.values, color=RESIDUAL, lw=1.2)
    ax.plot(lag_ms, acf.values, "o", color=RESIDUAL, ms=2.5)
    ax.axhspan(-acf.band, acf.band, color="0.85", zorder=0, label="95 % band")
    ax.axhline(0.0, color="0.4", lw=0.8)
    ax.set_xlabel("lag (ms)")
    ax.set_ylabel("autocorrelation")
    test = f"Ljung-Box Q = {acf.statistic:.3g}, p = {acf.p_value:.2g}"
    ax.set_title(f"{title}\n{test}" if title else test, fontsize="medium")
    if legend:
        _legend_beside(ax)
    return fig


def plot_cross_correlation(
    xc: CrossCorrelation, ax: Axes | None = None, title: str = "", input_name: str = "torque",
    legend: bool = True,
) -> Figure:
    """Residual–input correlation over lag (ms), the band and the peak lag (``input_name``: the
    drive's input quantity; the peak lag under the axis)."""
    fig, ax = figure_axes(ax)
    lag_ms = 1e3 * xc.lags * xc.dt
    ax.plot(lag_ms, xc.values, color=RESIDUAL, lw=1.2)
    ax.axhspan(-xc.band, xc.band, color="0.85", zorder=0, label="95 % band")
    ax.axvline(0.0, color="0.4", lw=0.8)
    ax.plot([1e3 * xc.peak_lag_s], [xc.peak_value], "o", color=MARK, label="peak lag")
    ax.set_xlabel(f"lag (ms): residual after {input_name} →\n"
                  f"peak at {1e3 * xc.peak_lag_s:+.3g} ms")
    ax.set_ylabel("cross-correlation")
    ax.set_title(title or f"residual vs {input_name}", fontsize="medium")
    if legend:
        _legend_beside(ax)
    return fig


def plot_spectrum(
    spectrum: ResidualSpectrum,
    ax: Axes | None = None,
    title: str = "",
    f_max: float | None = 120.0,
    unit: str = "",
    legend: bool = True,
) -> Figure:
    """Residual PSD (log scale) with the white-noise floor; the peaks above it are marked and
    their frequencies listed under the axis (``legend``: the curves' key beside the axes)."""
    fig, ax = figure_axes(ax)
    sel = spectrum.freqs > 0
    if f_max is not None:
        sel &= spectrum.freqs <= f_max
    ax.semilogy(spectrum.freqs[sel], spectrum.psd[sel], color=RESIDUAL, lw=1.0, label="residual")
    ax.axhline(spectrum.noise_psd, color="0.3", ls="--", lw=1.0, label="noise floor")
    peaks = sorted(f for f in spectrum.peaks_hz if f_max is None or f <= f_max)
    label = "frequency (Hz)"
    if peaks:  # marked on the curve, their frequencies under the axis: labels never collide
        at = [spectrum.psd[int(np.argmin(np.abs(spectrum.freqs - f)))] for f in peaks]
        ax.plot(peaks, np.asarray(at) * 1.6, "v", color=MARK, ms=5, label="spectral peak")
        label += "\n" + textwrap.fill("peaks " + ", ".join(f"{f:.1f}" for f in peaks) + " Hz",
                                      36)
    ax.set_xlabel(label)
    squared = f"({unit})²" if any(c in unit for c in "/^ ·") else f"{unit}²"
    ax.set_ylabel("PSD (1/Hz)" if unit == "1" else f"PSD ({squared}/Hz)" if unit else "PSD")
    ax.set_title(title or "residual spectrum", fontsize="medium")
    if legend:
        _legend_beside(ax)
    return fig


def plot_localisation(loc: Localisation, ax: Axes | None = None, title: str = "") -> Figure:
    """Horizontal bars of the misfit concentration (share of misfit / share of time).

    A bar beyond 1 (the dashed line) marks a condition or time window where the misfit is
    denser than on average.
    """
    fig, ax = figure_axes(ax, figsize=(6.0, 5.0))
    items = list(loc.conditions) + list(loc.windows)
    names = [c.condition for c in items]
    values = [c.concentration for c in items]
    colours = [MODEL] * len(loc.conditions) + ["0.55"] * len(loc.windows)
    y = np.arange(len(items))[::-1]
    ax.barh(y, values, color=colours)
    ax.axvline(1.0, color="0.3", ls="--", lw=1.0)
    ax.set_yticks(y, names, fontsize="x-small")
    ax.set_xlabel("misfit concentration\n(share of misfit / share of time)")
    ax.set_title(title or "where the misfit lies", fontsize="medium")
    return fig


def plot_diagnosis(diagnosis: Diagnosis, *, figsize=(13.0, 9.0), dpi: float = 100.0,
                   units: Mapping[str, str] | None = None, input_name: str = "torque",
                   input_unit: str = "N m") -> Figure:
    """One page: per channel the autocorrelation, cross-correlation with the drive's input
    (``input_name`` in ``input_unit``) and spectrum; localisation. ``units`` (channel → unit)
    label the residual spectra's axes. One key for every panel, under the page."""
    units = dict(units or {})
    channels = list(diagnosis.channels)
    fig = Figure(figsize=figsize, dpi=dpi, layout="constrained")
    grid = fig.add_gridspec(len(channels), 4, width_ratios=[1.0, 1.0, 1.0, 1.15])
    drive = f"{input_name} ({input_unit})" if input_unit else input_name
    for row, name in enumerate(channels):
        c = diagnosis.channels[name]
        label = _label(name)
        _, verdict, statistic = noise_claim(c, diagnosis.alpha)
        axes = [style(fig.add_subplot(grid[row, k])) for k in range(3)]
        plot_autocorrelation(c.whiteness, axes[0], title=f"{label}: whiteness", legend=False)
        if c.noise.kind != "white":  # a quantised channel's noise test is not Ljung-Box
            axes[0].set_title(axes[0].get_title() + "\n(quantised: not its noise test)",
                              fontsize="small")
        plot_cross_correlation(c.input_correlation, axes[1], title=f"{label} vs {drive}",
                               input_name=input_name, legend=False)
        statistic = statistic.replace("; ", "\n")  # one test a line: as wide as its axes
        plot_spectrum(c.spectrum, axes[2], title=f"{label}: {verdict}\n{statistic}",
                      unit=units.get(name, ""), legend=False)
        axes[2].title.set_fontsize("small")
    ax = style(fig.add_subplot(grid[:, 3]))
    plot_localisation(diagnosis.localisation, ax)
    handles: dict[str, object] = {}
    for a in fig.axes:  # one entry per key: the band, the floor, the curves, the peaks
        for handle, key in zip(*a.get_legend_handles_labels(), strict=True):
            handles.setdefault(key, handle)
    fig.legend(list(handles.values()), list(handles), loc="outside lower center",
               ncols=len(handles), fontsize="small", frameon=False)
    return fig


def plot_error_falling(
    labels: Sequence[str],
    nrmse: Mapping[str, Sequence[float]],
    *,
    noise_floor: Mapping[str, float] | None = None,
    frf_nrmse: Sequence[float] | None = None,
    holdout: Mapping[str, Sequence[float]] | None = None,
    figsize=(8.0, 4.5),
    dpi: float = 100.0,
) -> Figure:
    """NRMSE (log scale) per model structure, one line per output; noise floors dashed.

    ``labels`` name the steps (e.g. "base", "+ payload"); ``nrmse`` maps an output to one value
    per step, as do ``frf_nrmse`` and ``holdout`` (held-out relative error in percent).
    """
    if not labels:
        raise ValueError("plot_error_falling needs at least one step")
    fig, axes = new_figure(1, 1, figsize=figsize, dpi=dpi)
    ax = axes[0, 0]
    x = np.arange(len(labels))
    for i, (name, values) in enumerate(nrmse.items()):
        if len(values) != len(labels):
            raise ValueError(f"nrmse[{name!r}] has {len(values)} values for {len(labels)} steps")
        colour = _colour(name, i)
        ax.semilogy(x, values, "o-", color=colour, label=f"{_label(name)} NRMSE")
        if noise_floor and name in noise_floor:
            ax.axhline(noise_floor[name], color=colour, ls="--", lw=1.0,
                       label=f"{_label(name)} noise floor")
    if frf_nrmse is not None:
        ax.semilogy(x, frf_nrmse, "s-", color="0.35", label="FRF NRMSE")
    order = list(nrmse)
    for name, values in (holdout or {}).items():
        i = order.index(name) if name in order else len(order) + 1
        ax.semilogy(x, values, "^:", color=_colour(name, i),
                    label=f"held-out {_label(name)} error")
    ax.set_xticks(x, [textwrap.fill(t, 18) for t in labels])
    ax.set_ylabel("error (%)")
    ax.set_title("error as effects are added", fontsize="medium")
    _legend_beside(ax)
    return fig


def plot_overlay(
    record: Record,
    before: Mapping[str, np.ndarray] | object,
    after: Mapping[str, np.ndarray] | object,
    *,
    labels: tuple[str, str] = ("before", "after"),
    outputs: Sequence[str] = OUTPUT_COLUMNS,
    units: Mapping[str, str] | None = None,
    role: str = "",
    figsize=(9.0, 6.5),
    dpi: float = 100.0,
) -> Figure:
    """Measured outputs of ``record`` against the model before and after, residuals below.

    ``before`` and ``after`` are simulated outputs (:class:`~jaxflex.simulation.Outputs`, whose
    sensor readings count too, or a mapping channel → array); ``units`` name each channel's
    unit (default: the record's), ``role`` the record's (fitted, held out) in the title.
    """
    units = dict(units or {})

    def get(source, name):
        value = source[name] if isinstance(source, Mapping) else source.channel(name)
        value = np.asarray(value, dtype=np.float64)
        if value.shape != (record.n_samples,):
            raise ValueError(f"{name} has shape {value.shape}, expected ({record.n_samples},)")
        return value

    fig, axes = new_figure(2 * len(outputs), 1, figsize=figsize, dpi=dpi, sharex=True,
                           height_ratios=[3.0, 1.2] * len(outputs))
    t = record.time
    for k, name in enumerate(outputs):
        measured = record.channel(name)
        ax, ax_res = axes[2 * k, 0], axes[2 * k + 1, 0]
        unit = units.get(name) or record.units.get(name) or "-"
        ax.plot(t, measured, color=MEASURED, lw=1.0, label="measured")
        for source, label, colour, ls in ((before, labels[0], MODEL, ":"),
                                          (after, labels[1], _AFTER, "--")):
            model = get(source, name)
            ax.plot(t, model, color=colour, lw=1.2, ls=ls, label=label)
            ax_res.plot(t, measured - model, color=colour, lw=0.9, label=label)
        ax.set_ylabel(f"{_label(name)}\n({unit})")
        ax_res.axhline(0.0, color="0.4", lw=0.6)
        ax_res.set_ylabel(f"residual\n({unit})")
    axes[-1, 0].set_xlabel("time (s)")
    fig.align_ylabels(axes[:, 0])  # one column of labels, clear of every axes' tick labels
    held = f" ({role})" if role else ""
    width = int(9.0 * figsize[0])  # characters of the medium font across the figure
    fig.suptitle(textwrap.fill(f"{record.name}{held}: {labels[0]} vs {labels[1]}", width),
                 fontsize="medium")
    keys = axes[0, 0].get_legend_handles_labels()
    fig.legend(*keys, loc="outside lower center", fontsize="small", frameon=False,
               ncols=3 if sum(map(len, keys[1])) <= width else 1)
    return fig


__all__ = [
    "plot_autocorrelation",
    "plot_cross_correlation",
    "plot_diagnosis",
    "plot_error_falling",
    "plot_localisation",
    "plot_overlay",
    "plot_spectrum",
]
