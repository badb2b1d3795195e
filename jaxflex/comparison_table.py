"""The text of a comparison: the time-domain and FRF tables and the notes that define them
(:meth:`jaxflex.comparison.Comparison.table`)."""

from __future__ import annotations

import math
import textwrap
from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING

from jaxflex.initial import LEAD_IN_PERIODS

if TYPE_CHECKING:
    from jaxflex.comparison import Comparison, RecordComparison

SHORT = {"joint_angle": "angle", "tip_acceleration": "tip acc"}
"""Short names of the reference channels in the table."""


def format_table(c: Comparison) -> str:
    """Two narrow tables: the time domain (a row per record and channel), the FRF (a row per
    record); a floor column only where some row has a floor to show."""
    short = {o: SHORT.get(o, o.replace("_", " ")) for o in c.channels}
    time_floor = any(o in r.noise_floor for r in c.rows for o in c.channels)
    header = ["record", "role", "channel", "NRMSE %", "rel.err"] + (["floor %"] * time_floor)
    lines = []
    for r in c.rows:
        for o in c.channels:
            cells = [r.name, r.role, short[o], _channel_cell(r, o, r.nrmse, _number),
                     _channel_cell(r, o, r.relative_error, _scientific)]
            if time_floor:
                cells.append(_number(r.noise_floor[o]) if o in r.noise_floor else "-")
            lines.append(cells)
    frf_floor = any("frf" in r.noise_floor for r in c.rows)
    frf_header = ["record", "role", "FRF NRMSE %", "FRF raw %", "bins"] + (
        ["floor FRF %"] * frf_floor)
    frf_lines = []
    for r in c.rows:
        cells = [r.name, r.role, _number(r.frf_nrmse), _number(r.frf_nrmse_raw),
                 f"{r.frf_bins[0]}/{r.frf_bins[1]}"]
        if frf_floor:
            cells.append(_number(r.noise_floor["frf"]) if "frf" in r.noise_floor else "-")
        frf_lines.append(cells)

    window = "the whole record" if c.t_end is None else f"0 <= t <= {c.t_end:g} s"
    notes = [
        f"NRMSE = 100 rms(y - y_model)/rms(y) and rel.err = |y - y_model|/|y|, over {window}.",
        f"FRF: H1 estimate {c.input_name} -> {c.link.replace('_', ' ')}; FRF NRMSE = "
        f"{c.frf_settings.describe()} "
        "('bins': compared/in band); FRF raw = every bin of the band.",
    ]
    if time_floor or frf_floor:
        noise = ", ".join(f"{k} {v:g}" for k, v in c.noise.items())
        notes.append(f"floor = the NRMSE the sensor noise alone gives ({noise}).")
    notes += _channel_notes(c)
    if c.lead_ins:
        spans = ", ".join(f"{name} {span:.3g} s" for name, span in c.lead_ins.items())
        notes.append("held-out records not at rest start from the state estimated over their "
                     f"first seconds alone ({spans}: {LEAD_IN_PERIODS:g} periods of the lowest "
                     "mode); the rest of each is predicted from it, and the NRMSE covers the "
                     "whole record.")
    if c.resonances_hz:
        shown = [f"{f:.2f}" for f in c.resonances_hz if f <= c.frf_settings.f_max] or [
            f"{c.resonances_hz[0]:.2f}"
        ]
        peaks = ", ".join(f"{f:.2f}" for f in c.model_resonances_hz)
        fitted = f"Model resonances as fitted (its FRF's peaks): {peaks} Hz; " if peaks else ""
        notes.append(f"{fitted}free-hub modes: {', '.join(shown)} Hz.")
    notes = [textwrap.fill(n, 100, subsequent_indent="  ") for n in notes]
    tables = _aligned(header, lines, text_columns=3) + [""] + _aligned(
        frf_header, frf_lines, text_columns=2)
    return "\n".join([*tables, *notes]) + "\n"


def _aligned(header: Sequence[str], rows: Sequence[Sequence[str]],
             text_columns: int) -> list[str]:
    """``header``, a rule, ``rows`` and a rule as lines of aligned columns: the first
    ``text_columns`` left-aligned, numbers right-aligned."""
    widths = [max(len(h), *(len(row[j]) for row in rows)) for j, h in enumerate(header)]

    def fmt(cells: Sequence[str]) -> str:
        return "  ".join(
            cell.ljust(w) if j < text_columns else cell.rjust(w)
            for j, (cell, w) in enumerate(zip(cells, widths, strict=True))
        ).rstrip()

    rule = "-" * len(fmt(header))
    return [fmt(header), rule, *map(fmt, rows), rule]


def _channel_cell(row: RecordComparison, channel: str, values: Mapping[str, float],
                  number) -> str:
    """A channel's metric in the table: '-' where the record does not log the channel, 'no
    motion' where it is zero throughout (no NRMSE is defined: see the notes)."""
    if channel not in values:
        return "-"
    return "no motion" if channel in row.still else number(values[channel])


def _channel_notes(c: Comparison) -> list[str]:
    """The notes that the channel cells '-' and 'no motion' need: which is which, and the
    model's RMS error, in the channel's unit, where a channel does not move."""
    notes = []
    if any(o not in r.nrmse for r in c.rows for o in c.channels):
        notes.append("-: the record does not log that channel; it is not compared there.")
    still = [f"{r.name} {o} {r.rms_error[o]:.3g} {c.units.get(o) or ''}".rstrip()
             for r in c.rows for o in r.still]
    if still:
        notes.append("no motion: the measured channel is zero throughout, so no NRMSE is "
                     f"defined; the model's RMS error there: {', '.join(still)}.")
    return notes


def _scientific(x: float) -> str:
    return f"{x:.2e}" if math.isfinite(x) else "n/a"


def _number(x: float) -> str:
    """Three significant digits, fixed-point for readable percentages."""
    if not math.isfinite(x):
        return "n/a"
    if x == 0 or abs(x) >= 100:
        return f"{x:.1f}"
    digits = max(0, 2 - math.floor(math.log10(abs(x))))
    return f"{x:.{digits}f}"


__all__ = ["SHORT", "format_table"]
