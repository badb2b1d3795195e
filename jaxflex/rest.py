"""Rest: how far a still sensor's reading may wander, and where a record is at rest.

The simulator starts every record from rest, so a window of a logged record must start where
the arm is still: every sensor channel within its *rest tolerance* for ``span`` seconds
(:data:`REST_SPAN`). The input may already act there (the simulation applies it from the
window's start); where it switches on, it marks the motion's start more sharply than the
readings, which leave their bands a little after the arm starts to move.

* :func:`rest_tolerance` (and :func:`rest_band`, which also says why) is the rule: a quantised
  reading may toggle between adjacent levels (2 steps), white noise spans ``±4σ`` (8σ), and an
  ideal sensor (no resolution, no noise) gets ``1e-3`` of its reading's range;
  :func:`rest_bands` applies it to the sensors of an arm (anything with ``channel``,
  ``resolution``, ``noise`` and ``unit``) on one record.
* :func:`spread_within` compares a peak-to-peak spread with a tolerance, immune to float
  rounding (``0.406 − 0.404`` is within ``0.002``).
* :func:`rest_stretch` is the stretch of samples judged at a window's start: ``span`` from
  there, or, where the input switches on (or the file's own header says the rest ends) within
  it, the ``span`` before that, as far as the record goes. A record whose input starts from
  zero at its first sample is still at rest there: it moves *right after* that sample, not *at*
  it; one that moves before its input switches on is not.
* :func:`why_not_at_rest` says, in one line, why a window does not start at rest (None when it
  does): the channel, how much it changed, the tolerance and its reason, the span and the time.
* :func:`find_rest` finds where to start a window: at the end of the first stretch of rest
  that a motion follows, ``span`` before the motion (or at the record's first sample, where it
  rests until its input switches on).
* :func:`stated_rest` reads how long a record rests from its own header (the ``rest`` line that
  ``jaxflex simulate --arm`` writes, :func:`rest_note`).

All take a record's columns as arrays by name and its own time, so that, for a
:class:`~jaxflex.data.Record` ``r`` and an arm's sensors::

    bands = rest_bands(arm.sensors, r)
    channels = {c: r.channel(c) for c in bands}
    t0 = find_rest(r.time, channels, bands, r.channel(r.input_name), name=r.name)
    problem = why_not_at_rest(r.time, channels, bands, name=r.name, t0=window_start)
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Protocol

import numpy as np
from jaxtyping import Float
from scipy.ndimage import maximum_filter1d, minimum_filter1d

from jaxflex._arguments import finite_float

if TYPE_CHECKING:
    from jaxflex.data import Record

REST_SPAN = 0.05
"""Seconds of stillness that count as rest at a window's start."""
REST_STEPS = 2
"""Quantisation steps a still reading may span: it can toggle across a level boundary."""
REST_SIGMAS = 8.0
"""Noise standard deviations a still reading may span: ``±4σ``, which white noise leaves about
once in a thousand spans of 500 samples (``±3σ`` fails one span of 50 samples in 50)."""
REST_RANGE_FRACTION = 1e-3
"""Fraction of its reading's range an ideal sensor (no resolution, no noise) may wander."""
INPUT_FRACTION = 0.01
"""The input is on where its absolute value exceeds this fraction of its peak."""
REST_KEY = "rest"
"""The header key under which a record states its own rest (:func:`rest_note`)."""
REST_HINT = (
    "the simulation starts from rest, so start the window where the arm is still "
    "(window=(t0, t1)), or fit where the record starts (initial_state='estimate', slower)"
)
"""How a rest message ends; a command line replaces ``window=(t0, t1)`` and
``initial_state='estimate'`` by its options."""
_RELATIVE_SLACK = 1e-9
_ULPS = 8


@dataclass(frozen=True)
class RestBand:
    """A channel's rest tolerance (peak-to-peak, in its ``unit``) and the reason for it."""

    tolerance: float
    reason: str = ""
    unit: str = ""


class _Sensor(Protocol):
    channel: str
    resolution: float
    noise: float
    channel_unit: str


def rest_band(
    resolution: float, noise: float, signal_range: float = 0.0, unit: str = ""
) -> RestBand:
    """The rest tolerance of a sensor of ``resolution`` (quantisation step) and white ``noise``
    (standard deviation), and its reason: ``2·resolution + 8·noise``; for an ideal sensor
    (both 0) ``1e-3 · signal_range``, the peak-to-peak of its whole reading."""
    q = finite_float(resolution, "resolution", minimum=0.0)
    sigma = finite_float(noise, "noise", minimum=0.0)
    if q == 0 and sigma == 0:
        span = finite_float(signal_range, "signal_range", minimum=0.0)
        return RestBand(
            REST_RANGE_FRACTION * span,
            f"{REST_RANGE_FRACTION:g} of the reading's range {_amount(span, unit)}, "
            "an ideal sensor",
            unit,
        )
    parts = [f"{REST_STEPS} steps of {_amount(q, unit)}"] if q else []
    parts += [f"{REST_SIGMAS:g}σ, σ = {_amount(sigma, unit)}"] if sigma else []
    return RestBand(REST_STEPS * q + REST_SIGMAS * sigma, " + ".join(parts), unit)


def rest_tolerance(resolution: float, noise: float, signal_range: float = 0.0) -> float:
    """How far (peak-to-peak) a still sensor's reading may wander: :func:`rest_band`'s rule."""
    return rest_band(resolution, noise, signal_range).tolerance


def rest_bands(sensors: Sequence[_Sensor], record: Record) -> dict[str, RestBand]:
    """The rest band of each sensor whose channel ``record`` holds, by channel."""
    return {
        s.channel: rest_band(
            s.resolution, s.noise, float(np.ptp(record.channel(s.channel))), s.channel_unit
        )
        for s in sensors
        if s.channel in record.columns
    }


def spread_within(values: Float[np.ndarray, " n"], tolerance: float) -> bool:
    """True when the peak-to-peak of ``values`` is within ``tolerance``, with a slack of
    ``1e-9`` of the tolerance and 8 ulps of the values' magnitude for float rounding."""
    v = np.asarray(values, dtype=np.float64)
    if v.size == 0:
        raise ValueError("spread_within: values is empty")
    top, bottom = float(np.max(v)), float(np.min(v))
    return bool(_within(top - bottom, tolerance, max(abs(top), abs(bottom))))


def rest_note(t_start: float, t_end: float) -> str:
    """The value of a record's ``rest`` header line: it rests from ``t_start`` to ``t_end`` (s),
    where its input starts (:func:`stated_rest` reads it back)."""
    return (f"at rest from t = {float(t_start)!r} s to t = {float(t_end)!r} s, where the input "
            "starts")


_STATED = re.compile(r"at rest from t = (\S+) s to t = (\S+) s")
_SIMULATED = re.compile(r", after (\S+) s at rest$")  # the input line of older simulated records


def stated_rest(record: Record) -> tuple[float, float] | None:
    """``(t_start, t_end)``: where ``record``'s own header says it rests (s), or None.

    The ``rest`` line (:func:`rest_note`), or, in a record ``jaxflex simulate --arm`` wrote
    before that line existed, its input line's "after S s at rest" from its first sample. A line
    that does not read so states nothing."""
    meta = record.metadata
    start = float(record.time[0])
    found = _STATED.match(meta.get(REST_KEY, "").strip())
    older = _SIMULATED.search(meta.get("input", "").strip())
    try:
        if found:
            span = float(found[1]), float(found[2])
        elif older and meta.get("generator") == "jaxflex simulate --arm":
            span = start, start + float(older[1])
        else:
            return None
    except ValueError:
        return None
    return span if all(map(math.isfinite, span)) and span[0] <= span[1] else None


def rest_stretch(
    time: Float[np.ndarray, " n"],
    input_signal: Float[np.ndarray, " n"] | None = None,
    span: float = REST_SPAN,
    *,
    t0: float | None = None,
    rested: tuple[float, float] | None = None,
) -> slice:
    """The samples judged for rest at ``t0`` (the first sample when None): ``span`` s from
    there; or, where ``input_signal``, off at ``t0``, switches on (exceeds
    :data:`INPUT_FRACTION` of its peak) within that span, or the rest a record's header states
    (``rested``, :func:`stated_rest`) ends within it, the ``span`` s before that, as far back as
    the record goes. Motion after the input switches on is its response: the arm was at rest
    where the readings stood still until then."""
    t = np.asarray(time, dtype=np.float64)
    span = finite_float(span, "span", minimum=0.0, strict=True)
    n = _samples(t, span)
    first = _first(t, t0)
    return _stretch(t, None if input_signal is None else np.asarray(input_signal, np.float64),
                    first, n, rested)


def why_not_at_rest(
    time: Float[np.ndarray, " n"],
    channels: Mapping[str, Float[np.ndarray, " n"]],
    tolerances: Mapping[str, float | RestBand],
    span: float = REST_SPAN,
    *,
    name: str,
    t0: float | None = None,
    input_signal: Float[np.ndarray, " n"] | None = None,
    rested: tuple[float, float] | None = None,
) -> str | None:
    """None when record ``name`` is at rest at ``t0`` (its first sample when None), else one
    line that says why: each channel that changes by more than its tolerance, by how much, and
    the tolerance's reason. The samples judged are :func:`rest_stretch`'s: ``span`` s from
    ``t0``, or those before ``input_signal`` switches on (or the header's stated rest
    ``rested`` ends), when that comes sooner."""
    time, channels, bands, u, n = _checked(name, time, channels, tolerances, input_signal, span)
    first = _first(time, t0, name)
    cut = _stretch(time, u, first, n, rested)
    reasons = _unrest(channels, bands, cut)
    if not reasons:
        return None
    where = (f"in the first {span:g} s" if cut.start == first and cut.stop == first + n else
             f"from t = {_time(float(time[cut.start]))} s until its input switches on at "
             f"t = {_time(float(time[min(cut.stop, time.size - 1)]))} s")
    return (
        f"record {name!r} does not start at rest at t = {_time(float(time[first]))} s: "
        f"{' and '.join(reasons)} {where}; {REST_HINT}"
    )


def find_rest(
    time: Float[np.ndarray, " n"],
    channels: Mapping[str, Float[np.ndarray, " n"]],
    tolerances: Mapping[str, float | RestBand],
    input_signal: Float[np.ndarray, " n"] | None = None,
    span: float = REST_SPAN,
    *,
    name: str,
    rested: tuple[float, float] | None = None,
    opening: float | None = None,
) -> float:
    """The time to start a window of record ``name`` at: ``span`` s before its motion begins.

    A sample is *still* when it lies in a stretch of at least ``span`` s in which every channel
    stays within its tolerance (:func:`spread_within`). The motion begins at the first sample
    after the first still one that is not, or, when it comes first, where ``input_signal``,
    off in that stillness, switches on (exceeds :data:`INPUT_FRACTION` of its peak). The window
    starts at the last moment that leaves ``span`` s of stillness before the motion, for
    re-zeroing the readings (:func:`why_not_at_rest` then passes), and takes in all of the
    motion that follows; where the stillness is shorter than that before the input switches
    on, it starts where the stillness begins.

    It is the rest before the *first* motion: the model starts from rest once, and a later rest
    would leave out what came before it. A record whose readings stand still at its first
    sample until its input switches on (or its header's stated rest ``rested`` ends) within
    ``span`` starts at rest there (:func:`rest_stretch`): it is taken from its first sample. A
    record that starts in motion is taken from the first rest that a motion follows. With
    ``opening`` (s, below ``span``), a record whose readings stand still from its first sample
    for less than ``span`` but at least ``opening`` — all it holds before it moves — is taken
    from that rest (found over ``opening``) where the readings stay within their tolerances
    all along it. Raises a one-line ValueError when the record never rests for ``span`` s
    before it moves, or never moves.
    """
    time, channels, bands, u, n = _checked(name, time, channels, tolerances, input_signal, span)
    never = f"record {name!r} is never at rest for {span:g} s before it moves"
    start = _stretch(time, u, 0, n, rested)
    if start.stop < n and not _unrest(channels, bands, start):
        return float(time[0])  # still until its input switches on: it starts at rest
    still = _still(channels, bands, n) if time.size >= n else np.zeros(1, dtype=bool)
    if opening is not None and opening < span and not still[0]:
        n_open = _samples(time, finite_float(opening, "opening", minimum=0.0, strict=True))
        if time.size >= n_open and _still(channels, bands, n_open)[0]:
            t0 = find_rest(time, channels, bands, u, opening, name=name, rested=rested)
            end = int(np.searchsorted(time, t0 - 1e-6 * _step(time))) + n_open
            if not _unrest(channels, bands, slice(0, end)):
                return t0
    if time.size < n:
        raise ValueError(f"{never}: it lasts {_time(float(time[-1] - time[0]))} s")
    if not still.any():
        raise ValueError(
            f"{never}: from its first sample at t = {_time(float(time[0]))} s "
            f"{' and '.join(_unrest(channels, bands, slice(0, n)))} in the first {span:g} s; "
            f"{REST_HINT}"
        )
    first = int(np.argmax(still))
    covered = np.cumsum(np.concatenate([still, np.zeros(n - 1, dtype=bool)]).astype(np.int64))
    covered[n:] -= covered[:-n].copy()
    moving = np.flatnonzero(covered[first:] == 0)  # samples in no still stretch
    if moving.size == 0:
        if first == 0:
            raise ValueError(
                f"record {name!r} never moves: every channel stays within its rest tolerance "
                "from start to end"
            )
        raise ValueError(
            f"{never}: it rests only from t = {_time(float(time[first]))} s to its end; "
            f"{REST_HINT}"
        )
    motion = first + int(moving[0])
    if u is not None:
        on = np.abs(u[first:motion]) > INPUT_FRACTION * np.max(np.abs(u))
        off = np.flatnonzero(~on)  # a drive may still be on as the readings settle
        switch = np.flatnonzero(on[off[0] :]) if off.size else off
        motion = first + int(off[0]) + int(switch[0]) if switch.size else motion
    latest = np.flatnonzero(still[first : max(first, motion - n) + 1])
    return float(time[first + int(latest[-1])])


def _still(channels, bands, n: int) -> np.ndarray:
    """By the first of every ``n`` samples: every channel within its tolerance over them."""
    still = np.ones(next(iter(channels.values())).size - n + 1, dtype=bool)
    for c, y in channels.items():
        top, bottom = _sliding(maximum_filter1d, y, n), _sliding(minimum_filter1d, y, n)
        still &= _within(top - bottom, bands[c].tolerance, np.maximum(abs(top), abs(bottom)))
    return still


def _samples(time: np.ndarray, span: float) -> int:
    """Samples in ``span`` s (both ends counted), at least 2."""
    return max(2, math.ceil(span / _step(time) - 1e-6) + 1)


def _first(time: np.ndarray, t0: float | None, name: str = "") -> int:
    """The index of the first sample at or after ``t0`` (None: the first sample)."""
    start = float(time[0]) if t0 is None else finite_float(t0, "t0")
    first = int(np.searchsorted(time, start - 1e-6 * _step(time)))
    if first >= time.size:
        raise ValueError(
            f"record {name!r}: t0={start!r} s is after its last sample at {float(time[-1])!r} s"
        )
    return first


def _stretch(time: np.ndarray, u: np.ndarray | None, first: int, n: int,
             rested: tuple[float, float] | None) -> slice:
    """:func:`rest_stretch` by sample indices (``n`` samples in the span)."""
    ends = []
    if u is not None and u.size:
        on = np.flatnonzero(np.abs(u[first : first + n]) > INPUT_FRACTION * np.max(np.abs(u)))
        if on.size and on[0] > 0:  # off at first, switched on within the span
            ends.append(first + int(on[0]))
    if rested is not None:
        slack = 1e-6 * _step(time)
        if rested[0] - slack <= time[first] <= rested[1] + slack:
            ends.append(int(np.searchsorted(time, rested[1] + slack, side="right")))
    end = max(ends, default=first + n)
    if end >= first + n:
        return slice(first, first + n)
    return slice(max(0, end - n), end)


def _within(spread, tolerance: float, magnitude):
    """``spread <= tolerance`` up to float rounding (see :func:`spread_within`)."""
    eps = np.finfo(np.float64).eps
    return spread <= tolerance * (1 + _RELATIVE_SLACK) + _ULPS * eps * magnitude


def _sliding(filter1d, y: np.ndarray, n: int) -> np.ndarray:
    """``filter1d`` (max or min) over every run of ``n`` samples, by its first sample."""
    return filter1d(y, size=n, mode="nearest")[n // 2 : n // 2 + y.size - n + 1]


def _unrest(channels, bands, cut: slice) -> list[str]:
    """Why the samples ``cut`` are not at rest, one phrase per channel that moves."""
    reasons = []
    for c, y in channels.items():
        band = bands[c]
        if not spread_within(y[cut], band.tolerance):
            why = f": {band.reason}" if band.reason else ""
            reasons.append(
                f"{c!r} changes by {_amount(float(np.ptp(y[cut])), band.unit)} (rest tolerance "
                f"{_amount(band.tolerance, band.unit)}{why})"
            )
    return reasons


def _checked(name, time, channels, tolerances, input_signal, span):
    """The arguments as float64 arrays and rest bands, and the samples in ``span``; a problem
    is a one-line ValueError naming the record and the argument."""
    where = f"record {name!r}"
    span = finite_float(span, "span", minimum=0.0, strict=True)
    t = np.asarray(time, dtype=np.float64)
    if t.ndim != 1 or t.size < 2:
        raise ValueError(f"{where}: time must be 1-D with at least 2 samples, got {t.shape}")
    if not channels:
        raise ValueError(f"{where}: no channels to check for rest")
    arrays = {c: _column(where, c, y, t.size) for c, y in channels.items()}
    missing = [c for c in arrays if c not in tolerances]
    if missing:
        raise ValueError(f"{where}: no rest tolerance for channel(s) {missing}")
    bands = {c: _band(where, c, tolerances[c]) for c in arrays}
    u = None if input_signal is None else _column(where, "input", input_signal, t.size)
    return t, arrays, bands, u, _samples(t, span)


def _column(where: str, name: str, values, size: int) -> np.ndarray:
    y = np.asarray(values, dtype=np.float64)
    if y.shape != (size,):
        raise ValueError(f"{where}: {name!r} has shape {y.shape}; time has {size} samples")
    if not np.all(np.isfinite(y)):
        raise ValueError(f"{where}: {name!r} holds values that are not finite")
    return y


def _band(where: str, channel: str, tolerance: float | RestBand) -> RestBand:
    band = tolerance if isinstance(tolerance, RestBand) else RestBand(tolerance)
    try:
        finite_float(band.tolerance, "tolerance", minimum=0.0)
    except ValueError as err:
        raise ValueError(f"{where}: channel {channel!r}: rest {err}") from None
    return band


def _step(time: np.ndarray) -> float:
    return float(time[-1] - time[0]) / (time.size - 1)


def _amount(value: float, unit: str) -> str:
    """``value`` to 3 digits with its unit ('1', dimensionless, is left out)."""
    return f"{value:.3g}" if unit in ("", "1") else f"{value:.3g} {unit}"


def _time(t: float) -> str:
    return f"{t:.6g}"


__all__ = ["INPUT_FRACTION", "REST_HINT", "REST_KEY", "REST_SPAN", "RestBand", "find_rest",
           "rest_band", "rest_bands", "rest_note", "rest_stretch", "rest_tolerance",
           "spread_within", "stated_rest", "why_not_at_rest"]
