"""Noise levels of the measured channels: given, a quantisation step read from the written
values, a white-noise estimate from the residuals, or the signal's resolution floor."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

import numpy as np
from numpy.typing import ArrayLike

from jaxflex.data import KNOWN_UNITS, OUTPUT_COLUMNS, Record
from jaxflex.noise import NOISE_SOURCES, Noise, NoiseLevel, noise_levels

UNITS: dict[str, str] = dict(KNOWN_UNITS)
"""Unit of each output channel, for the reports."""


GRID_TOLERANCE = 3.0

"""A value lies on a quantisation grid if within this many times its own writing error of it."""


GRID_MARGIN = 32.0

"""A grid is only recognised with a step of this many typical (median) writing errors or more,
and from gaps between values this many times their own writing errors."""


HELD_FRACTION = 0.2

"""A signal that repeats its previous sample this often is held (a staircase): white-noise
estimates from its second differences collapse, so its jump size sets the floor."""


def _is_float32(x: np.ndarray) -> bool:
    """True if the values were float32: each is a float32, or the shortest decimal of one."""
    with np.errstate(over="ignore"):
        single = x.astype(np.float32)
    if np.all(single.astype(np.float64) == x):
        return True
    return all(float(np.format_float_scientific(s, unique=True)) == v
               for s, v in zip(single, x, strict=True))


def writing_error(values: ArrayLike) -> np.ndarray:
    """Per value, the largest error its written form can carry.

    Values are written with ``P`` significant digits or ``D`` fixed decimals (a logger's
    format); ``P`` and ``D`` are the most any value's shortest round-trip decimal needs (a value
    with trailing zeros needs fewer), and the error is half the place of the last digit,
    ``½·max(10^(e−P+1), 10^(−D))`` for a value of decimal exponent ``e``; at least a float32 ulp
    for float32 values, plus a few float64 ulps of arithmetic.
    """
    x = np.asarray(values, dtype=np.float64).ravel()
    nonzero = x[x != 0.0]
    exponents = np.zeros(nonzero.size, dtype=int)
    digits = np.zeros(nonzero.size, dtype=int)
    for i, v in enumerate(nonzero):
        mantissa, exponent = np.format_float_scientific(v, unique=True, trim="-").split("e")
        exponents[i] = int(exponent)
        digits[i] = len(mantissa.lstrip("-").replace(".", ""))
    error = np.zeros(x.size)
    if nonzero.size:
        significant = int(np.max(digits))
        decimals = int(np.max(digits - 1 - exponents))
        place = np.maximum(10.0 ** (exponents - significant + 1), 10.0 ** (-decimals))
        error[x != 0.0] = 0.5 * place
    if _is_float32(x):
        error = np.maximum(error, np.spacing(np.abs(x).astype(np.float32)).astype(np.float64))
    return error + 8.0 * np.spacing(np.max(np.abs(x), initial=0.0))


def quantisation_step(signal: ArrayLike) -> float | None:
    """The step ``q`` if the values lie on a grid ``offset + k·q``, else ``None``.

    The tolerance follows the precision the values were written with (:func:`writing_error`),
    so a grid is found from 6 or more significant digits, fixed decimals or float32, at any
    offset. The candidate step is the smallest gap between distinct values well above their
    writing errors, or a divisor of it up to 4 when the signal skips counts; step and offset are
    then fitted to the counts (weighted least squares) and every value must lie within
    :data:`GRID_TOLERANCE` writing errors of the grid. A step below :data:`GRID_MARGIN` typical
    writing errors cannot be told from the writing itself: ``None``.
    """
    x = np.asarray(signal, dtype=np.float64).ravel()
    x = x[np.isfinite(x)]
    values = np.unique(x)
    if values.size < 3:
        return None
    error = writing_error(values)
    gaps = np.diff(values)
    resolved = gaps > GRID_MARGIN * np.maximum(error[1:], error[:-1])
    if not np.any(resolved):
        return None
    smallest = np.flatnonzero(resolved)[np.argmin(gaps[resolved])]
    gap = float(gaps[smallest])
    gap_error = float(error[smallest] + error[smallest + 1])
    span = float(values[-1] - values[0])
    typical = float(np.median(error))
    for divisor in (1, 2, 3, 4):
        step = gap / divisor
        if span / step > 100 * x.size or step < GRID_MARGIN * typical:
            return None
        fitted = _fit_grid(values, error, step, gap_error / divisor)
        if fitted is not None:
            return fitted
    return None


def _fit_grid(values: np.ndarray, error: np.ndarray, step: float, step_error: float
              ) -> float | None:
    """The step of the grid through ``values`` near ``step``, or ``None`` if they are off it.

    The counts ``k`` of a rough step (error ``δq``) are only right while ``k·δq`` stays well
    below a step, so step and offset are fitted (weighted least squares of the small off-grid
    parts) over the values near the first, then over four times as many counts with the refined
    step, and so on until every value is covered.
    """
    reach = max(2.0, 0.1 * step / step_error)
    while True:
        counts = np.round((values - values[0]) / step)
        near = counts <= reach
        off_grid = values - values[0] - step * counts  # small: fitted without cancellation
        design = np.stack([np.ones_like(counts), counts], axis=1) / error[:, None]
        (offset, correction), *_ = np.linalg.lstsq(design[near], (off_grid / error)[near],
                                                   rcond=None)
        if near.all():
            inside = np.abs(off_grid - offset - correction * counts) <= GRID_TOLERANCE * error
            return float(step + correction) if inside.all() else None
        step += correction
        reach *= 4.0


def resolution(signal: ArrayLike) -> float:
    """The standard deviation below which the written signal cannot resolve a noise: the RMS
    rounding error of its written values (``writing error·2/√12``), or for a held signal (a
    staircase that repeats samples, :data:`HELD_FRACTION`) its median jump over ``√12``."""
    x = np.asarray(signal, dtype=np.float64).ravel()
    x = x[np.isfinite(x)]
    if x.size == 0:
        return 0.0
    written = float(np.sqrt(np.mean((2.0 * writing_error(x)) ** 2)) / math.sqrt(12.0))
    jumps = np.abs(np.diff(x))
    if jumps.size and np.mean(jumps == 0.0) >= HELD_FRACTION and np.any(jumps > 0):
        return max(written, float(np.median(jumps[jumps > 0])) / math.sqrt(12.0))
    return written


def white_noise_level(residual: ArrayLike) -> float:
    """Robust white-noise standard deviation from second differences.

    For white noise ``d_k = r_{k+1} − 2r_k + r_{k−1}`` has variance ``6σ²``, while smooth model
    error (a resonance at ``f`` sampled at ``fs``) is attenuated by ``(2πf/fs)²``; the median
    absolute deviation ignores the few samples where the error is not smooth. It collapses on a
    staircase (most second differences vanish): :func:`estimate_noise` holds it to a floor.
    """
    r = np.asarray(residual, dtype=np.float64)
    d = np.diff(r, n=2, axis=-1).ravel()
    if d.size < 3:
        raise ValueError("need at least 5 residual samples to estimate the noise level")
    mad = np.median(np.abs(d - np.median(d)))
    return float(1.482602218505602 * mad / math.sqrt(6.0))


def estimate_noise(records: Sequence[Record], residuals: Sequence[Mapping[str, np.ndarray]],
                   given: Noise | None = None,
                   channels: Sequence[str] = OUTPUT_COLUMNS) -> dict[str, NoiseLevel]:
    """Noise level of each of ``channels``: ``given`` (:func:`noise_levels`) where the user gave
    one; else quantised if every record's measurement lies on a grid (the finest step); else
    white, estimated from the residuals but never below the measurements' :func:`resolution`
    (then the level is that floor, flagged unsure)."""
    levels = noise_levels(given, channels)
    for channel in channels:
        if channel in levels:
            continue
        measured = [r.channel(channel) for r in records]
        steps = [quantisation_step(m) for m in measured]
        if all(s is not None for s in steps):
            levels[channel] = NoiseLevel.quantised(float(np.min(steps)), source="quantisation")
            continue
        estimate = white_noise_level(np.concatenate([res[channel] for res in residuals]))
        floor = max(resolution(m) for m in measured)
        if estimate > floor:
            levels[channel] = NoiseLevel(sigma=estimate, source="estimated", floor=floor)
        else:
            levels[channel] = NoiseLevel(sigma=floor, source="floor", floor=floor)
    return levels


def excess_misfit(residual: np.ndarray, noise: NoiseLevel | None) -> np.ndarray:
    """Per-sample squared misfit beyond the noise, in units of the noise variance.

    White noise: ``r²/σ² − 1`` (zero mean for pure noise; sums are clipped at zero). Quantised:
    ``((|r| − q/2)⁺/σ)²``, which vanishes while the residual is within the quantisation bound.
    Without a noise level: ``r²``.
    """
    if noise is None or noise.sigma <= 0:
        return residual**2
    if noise.kind == "quantised":
        return (np.maximum(np.abs(residual) - 0.5 * noise.step, 0.0) / noise.sigma) ** 2
    return (residual / noise.sigma) ** 2 - 1.0


def root_mean_square(a: ArrayLike) -> float:
    """Root mean square of ``a`` in float64."""
    return math.sqrt(float(np.mean(np.square(np.asarray(a, dtype=np.float64)))))


__all__ = [
    "NOISE_SOURCES",
    "NoiseLevel",
    "Noise",
    "noise_levels",
    "writing_error",
    "quantisation_step",
    "resolution",
    "white_noise_level",
    "estimate_noise",
]
