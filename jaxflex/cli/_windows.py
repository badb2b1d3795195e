"""``--window``, once for every record or once per record: parsed, checked against each record,
resolved to the ``(t0, t1)`` that :func:`jaxflex.measured.model_record` cuts.

Forms (times in seconds, in each record's own time; a record's name is its file's stem):

* ``T0:T1`` — every record; ``T0:`` runs to each record's end, ``:T1`` from its start, ``:`` is
  the whole record;
* ``NAME=T0:T1`` (and ``NAME=T0:``, ``NAME=:T1``, ``NAME=:``) — the record ``NAME`` only; it
  overrides a window given for every record;
* ``auto``, ``NAME=auto`` — from the end of the rest before the record's first motion
  (:func:`jaxflex.rest.find_rest`, over a span of the link's lowest period,
  :func:`jaxflex.measured.rest_span`) to its end.

A command adds the option with :func:`add_windows_argument` and then needs only::

    windows = parse_windows(args.window, [r.name for r in records])
    for r in records:
        window = resolve_window(windows[r.name], r, rest_bands(arm.sensors, r))

:func:`parse_windows` gives each record a :class:`Window`, or None for the whole record;
:func:`check_window` checks an explicit window against a record's time span and fills in its
open ends; :func:`resolve_window` does that, or finds the rest for ``auto``. Every problem is a
one-line :class:`~jaxflex.cli.UsageError` that starts with ``--window TEXT:`` (exit status 2).
"""

from __future__ import annotations

import argparse
import difflib
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

from jaxflex.cli import UsageError

if TYPE_CHECKING:
    from jaxflex.data import Record
    from jaxflex.rest import RestBand

AUTO = "auto"
"""The window text that finds the rest start (:func:`jaxflex.rest.find_rest`)."""
FORMS = "T0:T1, T0:, :T1 or auto, optionally after NAME="
"""The forms of ``--window``, as the errors list them."""
_MS_FACTOR = 10.0  # a time this many times a record's end or more suggests milliseconds
_LISTED = 6  # record names an unknown-name error lists


@dataclass(frozen=True)
class Window:
    """One ``--window``: for the record ``name`` (None: every record), from ``start`` to ``end``
    in seconds (None: the record's first or last sample), or, with ``auto``, from its rest."""

    text: str
    name: str | None = None
    start: float | None = None
    end: float | None = None
    auto: bool = False


def add_windows_argument(p: argparse.ArgumentParser) -> None:
    """``--window [NAME=]T0:T1``, which may be given several times (module doc)."""
    p.add_argument(
        "--window", action="append", metavar="[NAME=]T0:T1",
        help="use only T0 <= t <= T1 (s, in the records' own time) of every record, or of the "
             "record NAME (its file's stem); T0: runs to the record's end, :T1 from its start; "
             "auto starts at the end of the rest before the record's first motion (still for "
             "a period of the link's lowest mode); once per record",
    )


def parse_windows(
    texts: Sequence[str] | str | None, names: Sequence[str]
) -> dict[str, Window | None]:
    """Each record's window, by name, from the ``--window`` texts given (None: not given; one
    text is taken as a list of one); None is the whole record."""
    texts = [texts] if isinstance(texts, str) else list(texts or ())
    every: Window | None = None
    named: dict[str, Window] = {}
    for text in texts:
        window = _parse(text, names)
        earlier = every if window.name is None else named.get(window.name)
        if earlier is not None:
            who = "every record" if window.name is None else f"record {window.name!r}"
            raise UsageError(
                f"--window {_echo(text)}: {who} already has a window (--window "
                f"{_echo(earlier.text)}); give one window for every record and NAME=T0:T1 for "
                "each record that differs"
            )
        if window.name is None:
            every = window
        else:
            named[window.name] = window
    chosen = {name: named.get(name, every) for name in names}
    return {name: None if _whole(w) else w for name, w in chosen.items()}


def check_window(
    window: Window, name: str, t_start: float, t_end: float, dt: float = 0.0
) -> tuple[float, float]:
    """``window`` as ``(t0, t1)`` for record ``name``, which spans ``t_start`` to ``t_end`` (s):
    open ends filled in, an end that overshoots the record by up to ``dt`` (one sample) cut back.
    A window outside the record, or that only partly overlaps it, is refused (say which end; a
    window that fits when read in milliseconds says so)."""
    if window.auto:
        raise ValueError(f"check_window: --window {window.text} is found by resolve_window")
    slack = max(float(dt), 1e-9 * max(1.0, abs(t_start), abs(t_end)))
    lo = t_start if window.start is None else window.start
    hi = t_end if window.end is None else window.end
    starts_before, ends_after = lo < t_start - slack, hi > t_end + slack
    if not (starts_before or ends_after or lo >= t_end or hi <= t_start):
        return max(lo, t_start), min(hi, t_end)
    who = "the record" if window.name is not None else f"record {name!r}"
    spans = (f"--window {_echo(window.text)}: {who} spans {_seconds(t_start)} to "
             f"{_seconds(t_end)} s")
    if _in_ms(window, t_start, t_end, slack):
        raise UsageError(f"{spans}; is the window in ms? times are in seconds")
    if lo >= t_end or hi <= t_start:
        raise UsageError(f"{spans}; the window lies {'after' if lo >= t_end else 'before'} it")
    ends = []
    if starts_before:
        ends.append(f"starts before it (use T0 >= {_seconds(t_start)}, or leave T0 out)")
    if ends_after:
        ends.append(f"ends after it (use T1 <= {_seconds(t_end)}, or leave T1 out)")
    raise UsageError(f"{spans}; the window {' and '.join(ends)}")


def resolve_window(
    window: Window | None,
    record: Record,
    bands: Mapping[str, float | RestBand],
    span: float | None = None,
) -> tuple[float, float] | None:
    """The ``(t0, t1)`` to cut ``record`` to (None: all of it): ``window`` checked against the
    record (:func:`check_window`), or, for ``auto``, from the rest that ``bands`` (rest
    tolerances by channel, :func:`jaxflex.rest.rest_bands`) and ``span`` (default
    :data:`jaxflex.rest.REST_SPAN`) find, to its end; the rest the record's header states
    counts (:func:`jaxflex.rest.stated_rest`), and a record still from its first sample for
    less than ``span`` (all it holds before it moves) is taken from that rest where it lasts
    :data:`jaxflex.rest.REST_SPAN`."""
    from jaxflex.rest import REST_SPAN, find_rest, stated_rest

    if window is None:
        return None
    t_start, t_end = float(record.time[0]), float(record.time[-1])
    if not window.auto:
        return check_window(window, record.name, t_start, t_end, record.dt)
    try:
        t0 = find_rest(
            record.time, {c: record.channel(c) for c in bands}, bands,
            record.channel(record.input_name), REST_SPAN if span is None else span,
            name=record.name, rested=stated_rest(record), opening=REST_SPAN,
        )
    except ValueError as err:
        message = str(err).replace("window=(t0, t1)", f"--window {_echo(record.name)}=T0:T1")
        message = message.replace("initial_state='estimate'", "--initial-state estimate")
        raise UsageError(f"--window {_echo(window.text)}: {message}") from None
    return t0, t_end


def _parse(text: str, names: Sequence[str]) -> Window:
    """One ``--window`` text; unknown record names and malformed times are refused."""
    name, equals, times = text.rpartition("=")
    record = name if equals else None
    if record is not None and record not in names:
        raise UsageError(f"--window {_echo(text)}: {_unknown(record, names)}")
    if times == AUTO:
        return Window(text, record, auto=True)
    if times.count(":") != 1:
        raise UsageError(f"--window {_echo(text)}: expected {FORMS} (times in seconds)")
    lo_text, _, hi_text = times.partition(":")
    lo, hi = _time(text, "T0", lo_text), _time(text, "T1", hi_text)
    if lo is not None and hi is not None and not lo < hi:
        raise UsageError(
            f"--window {_echo(text)}: T0 = {_seconds(lo)} s must be below T1 = {_seconds(hi)} s"
        )
    return Window(text, record, lo, hi)


def _time(text: str, label: str, part: str) -> float | None:
    """``part`` of ``text`` as seconds (None when empty: an open end)."""
    if not part.strip():
        return None
    try:
        value = float(part)
    except ValueError:
        value = math.nan
    if not (math.isfinite(value) and value >= 0):
        raise UsageError(
            f"--window {_echo(text)}: {label} = {part!r} must be a finite number of seconds >= 0"
        )
    return value


def _unknown(name: str, names: Sequence[str]) -> str:
    if not name:
        return "the record name before '=' is empty"
    close = difflib.get_close_matches(name, list(names), n=1, cutoff=0.6)
    if close:
        return f"no record is named {name!r}; did you mean {close[0]!r}?"
    listed = ", ".join(repr(n) for n in list(names)[:_LISTED])
    more = f" and {len(names) - _LISTED} more" if len(names) > _LISTED else ""
    return f"no record is named {name!r}; the records are {listed}{more}"


def _whole(window: Window | None) -> bool:
    """True for no window or ``:``, the whole record."""
    return window is None or (not window.auto and window.start is None and window.end is None)


def _in_ms(window: Window, t_start: float, t_end: float, slack: float) -> bool:
    """True when ``window``'s times are far beyond the record and fit it read as milliseconds."""
    given = [t for t in (window.start, window.end) if t is not None]
    lo = t_start if window.start is None else window.start / 1e3
    hi = t_end if window.end is None else window.end / 1e3
    reach = max(abs(t_end), t_end - t_start)
    return max(given) > _MS_FACTOR * reach and t_start - slack <= lo < hi <= t_end + slack


def _echo(text: str) -> str:
    """``text`` as an error shows it, on one line: each character that is not printable (a
    newline, a tab, a control character) escaped as Python writes it."""
    return "".join(c if c.isprintable() else repr(c)[1:-1] for c in text)


def _seconds(t: float) -> str:
    return f"{t:.6g}"


__all__ = ["AUTO", "Window", "add_windows_argument", "check_window", "parse_windows",
           "resolve_window"]
