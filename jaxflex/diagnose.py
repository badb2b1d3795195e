"""Where does the model fail? Diagnostics of the residuals ``r = measured − model``.

Each diagnostic answers one question about the residuals of a fit, per output channel:

* **whiteness** — :func:`autocorrelation` with the ``±1.96/√N`` band and the Ljung–Box
  portmanteau statistic ``Q = N(N+2) Σ_k ρ_k²/(N−k)`` (χ² with ``h`` d.o.f. for white noise);
* **what the input explains** — :func:`cross_correlation` of the residual with the torque over
  lags (a delay shows as a peak at a positive lag);
* **where in frequency** — :func:`residual_spectrum` against the noise floor, and
  :func:`frf_error`: the measured and model FRF (torque → tip acceleration) per frequency band and
  the shift of each resonance in Hz;
* **where in time and operating condition** — :func:`localise`: the share of the misfit while the
  torque acts or in free vibration, near zero joint velocity and at reversals, at high speed, per
  angle range and per time window;
* **consistency across amplitudes** — :func:`amplitude_scaling`: how the residual grows with the
  record's torque amplitude (exponent 1: a linear-model error; below 1: friction-like).

:func:`diagnose` runs them all on records and the model's predictions and returns a
:class:`Diagnosis` (numbers, ``summary()`` text, ``to_dict()`` for JSON). The noise model matters:
an encoder's quantisation error is bounded but not white (constant while the arm rests), so a
quantised channel is judged by the quantisation bound and only white-noise channels by the
Ljung–Box test. Everything is NumPy float64; the χ² tail and peak finding are SciPy's.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike
from scipy.signal import find_peaks
from scipy.stats import chi2

from jaxflex.data import OUTPUT_COLUMNS, Record
from jaxflex.preprocess import differentiate

CHANNELS: tuple[str, ...] = OUTPUT_COLUMNS
"""Output channels compared with measurements: joint angle (rad), tip acceleration (m/s²)."""
UNITS: dict[str, str] = {"joint_angle": "rad", "tip_acceleration": "m/s^2"}
Z95 = 1.959963984540054
"""Two-sided 95 % normal quantile: the band ``±Z95/√N`` of a white sequence's correlations."""
RMS_RATIO_LIMIT = 1.3
"""A residual whose RMS exceeds this multiple of the noise level is "well above the noise"."""
QUANTISED_EXCESS_LIMIT = 0.25
"""Quantised channel: tolerated RMS of the residual beyond ``±q/2``, in quantisation steps."""


def chi2_sf(x: float, dof: float) -> float:
    """Survival function ``P(χ²_dof > x)`` (``scipy.stats.chi2.sf``)."""
    if dof <= 0:
        raise ValueError(f"chi-square degrees of freedom must be positive, got {dof!r}")
    if not x > 0:
        return 1.0
    return float(chi2.sf(x, dof))


# --- noise levels --------------------------------------------------------------------------------

NOISE_SOURCES: tuple[str, ...] = ("given", "quantisation", "estimated", "floor")
"""How a channel's noise level was obtained: given by the user, the quantisation step of the
measured values, estimated from the residuals as white noise, or the signal's resolution floor
(the white estimate fell below what the written values can resolve: unsure)."""
GRID_TOLERANCE = 3.0
"""A value lies on a quantisation grid if within this many times its own writing error of it."""
GRID_MARGIN = 32.0
"""A grid is only recognised with a step of this many typical (median) writing errors or more,
and from gaps between values this many times their own writing errors."""
HELD_FRACTION = 0.2
"""A signal that repeats its previous sample this often is held (a staircase): white-noise
estimates from its second differences collapse, so its jump size sets the floor."""


@dataclass(frozen=True)
class NoiseLevel:
    """The measurement noise of one channel: standard deviation, kind and how it was obtained.

    ``kind`` is ``"white"`` (additive white noise, e.g. an accelerometer) or ``"quantised"`` (an
    encoder with step ``step``: uniform error of standard deviation ``step/√12``, bounded by
    ``±step/2``, but constant whenever the signal rests). ``source`` is one of
    :data:`NOISE_SOURCES`; ``floor`` the resolution floor an estimate was held to (0 if none).
    """

    sigma: float
    kind: str = "white"
    step: float | None = None
    source: str = "given"
    floor: float = 0.0

    def __post_init__(self) -> None:
        if self.kind not in ("white", "quantised"):
            raise ValueError(f"noise kind must be 'white' or 'quantised', got {self.kind!r}")
        if self.source not in NOISE_SOURCES:
            raise ValueError(f"noise source must be one of {NOISE_SOURCES}, got {self.source!r}")

    @classmethod
    def quantised(cls, step: float, source: str = "given") -> NoiseLevel:
        return cls(sigma=step / math.sqrt(12.0), kind="quantised", step=step, source=source)

    @property
    def unsure(self) -> bool:
        """True when the level is a resolution floor rather than a measured noise."""
        return self.source == "floor"

    def describe(self) -> str:
        """How the level was obtained, for reports: ``"given"``, ``"quantisation step q=…"``,
        ``"white, estimated"`` or ``"floor: …"``."""
        if self.source == "quantisation":
            return f"quantisation step q={self.step:.6g}"
        if self.source == "estimated":
            return "white, estimated"
        if self.source == "floor":
            return (f"floor: the white estimate lies below the resolution {self.floor:.3g} of "
                    "the written values (unsure; give it with noise=...)")
        return "given" if self.kind == "white" else f"given, quantisation step q={self.step:.6g}"

    def to_dict(self) -> dict[str, Any]:
        return {"sigma": self.sigma, "kind": self.kind, "step": self.step,
                "source": self.source, "obtained": self.describe(), "unsure": self.unsure}


Noise = Mapping[str, float | NoiseLevel]
"""Noise levels as a user gives them: channel → white σ in the channel's unit, or a
:class:`NoiseLevel` (e.g. ``{"joint_angle": 1e-4}``; on the command line ``--noise
joint_angle=1e-4``)."""


def noise_levels(noise: Noise | None,
                 channels: Sequence[str] = CHANNELS) -> dict[str, NoiseLevel]:
    """User-given noise levels, validated: channel → :class:`NoiseLevel` (a number is a white
    standard deviation in the channel's unit, e.g. ``{"joint_angle": 1e-4}``)."""
    levels = {}
    for channel, value in dict(noise or {}).items():
        if channel not in channels:
            raise ValueError(f"noise given for unknown channel {channel!r}; channels: "
                             f"{list(channels)}")
        if not isinstance(value, NoiseLevel):
            try:
                value = NoiseLevel(sigma=float(value))
            except (TypeError, ValueError):
                raise ValueError(f"noise level of {channel} must be a number or a NoiseLevel, "
                                 f"got {value!r}") from None
        if not (math.isfinite(value.sigma) and value.sigma > 0):
            raise ValueError(f"noise level of {channel} must be positive and finite, got "
                             f"{value.sigma!r}")
        levels[channel] = value
    return levels


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
                   given: Noise | None = None) -> dict[str, NoiseLevel]:
    """Noise level per channel: ``given`` (:func:`noise_levels`) where the user gave one;
    else quantised if every record's measurement lies on a grid (the finest step); else white,
    estimated from the residuals but never below the measurements' :func:`resolution` (then
    the level is that floor, flagged unsure)."""
    levels = noise_levels(given)
    for channel in CHANNELS:
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


# --- correlation ---------------------------------------------------------------------------------


@dataclass(frozen=True)
class Autocorrelation:
    """Residual autocorrelation ``ρ_k`` for lags ``0…h`` and the Ljung–Box whiteness test."""

    lags: np.ndarray  # samples
    values: np.ndarray
    band: float  # ±band: 95 % range of ρ_k for white noise
    statistic: float  # Ljung–Box Q
    dof: int
    p_value: float
    dt: float

    def white(self, alpha: float = 0.01) -> bool:
        """True if whiteness is not rejected at level ``alpha``."""
        return self.p_value >= alpha

    @property
    def outside_band(self) -> float:
        """Fraction of lags ``k ≥ 1`` with ``|ρ_k|`` outside the band (≈ 5 % if white)."""
        return float(np.mean(np.abs(self.values[1:]) > self.band))


@dataclass(frozen=True)
class CrossCorrelation:
    """Normalised residual–input cross-correlation ``ρ_ru(k) = Σ r_t u_{t−k} / (N s_r s_u)``.

    A positive lag means the residual follows the input: what the input did ``k`` samples ago
    still shows in the misfit (a delay, a lag of the actuator).
    """

    lags: np.ndarray  # samples, −h…h
    values: np.ndarray
    band: float
    dt: float

    @property
    def peak_index(self) -> int:
        return int(np.argmax(np.abs(self.values)))

    @property
    def peak_lag_s(self) -> float:
        """Lag of the largest |correlation|, in seconds."""
        return float(self.lags[self.peak_index] * self.dt)

    @property
    def peak_value(self) -> float:
        return float(self.values[self.peak_index])

    @property
    def significant(self) -> bool:
        """True if the peak lies outside the white-noise band."""
        return abs(self.peak_value) > self.band


def _as_segments(x: ArrayLike | Sequence[ArrayLike], name: str) -> list[np.ndarray]:
    """One or several 1-D finite float64 segments (records)."""
    if isinstance(x, np.ndarray) or not isinstance(x, Sequence) or np.ndim(x[0]) == 0:
        segments = [np.asarray(x, dtype=np.float64)]
    else:
        segments = [np.asarray(s, dtype=np.float64) for s in x]
    for i, s in enumerate(segments):
        if s.ndim != 1 or s.size < 4:
            raise ValueError(f"{name}[{i}] must be 1-D with at least 4 samples, got {s.shape}")
        if not np.all(np.isfinite(s)):
            raise ValueError(f"{name}[{i}] has non-finite values")
    return segments


def _max_lag(max_lag: int | None, n: int) -> int:
    h = min(40, n // 5) if max_lag is None else max_lag
    if isinstance(h, bool) or not isinstance(h, (int, np.integer)) or not 1 <= h < n:
        raise ValueError(f"max_lag={max_lag!r} must be an integer in [1, {n - 1}]")
    return int(h)


def _lagged_sum(a: np.ndarray, b: np.ndarray, k: int) -> float:
    """``Σ_t a_t b_{t−k}`` over the overlap."""
    n = a.size
    if k >= 0:
        return float(a[k:] @ b[: n - k])
    return float(a[: n + k] @ b[-k:])


def autocorrelation(
    residual: ArrayLike | Sequence[ArrayLike], max_lag: int | None = None, dt: float = 1.0
) -> Autocorrelation:
    """Autocorrelation of a residual (or of several records' residuals, pooled) and Ljung–Box.

    Each segment has its mean removed; lagged products never cross segment boundaries, so
    records can be pooled. ``max_lag`` defaults to ``min(40, N/5)`` for the shortest segment.
    """
    segments = [s - s.mean() for s in _as_segments(residual, "residual")]
    n_total = sum(s.size for s in segments)
    h = _max_lag(max_lag, min(s.size for s in segments))
    energy = sum(float(s @ s) for s in segments)
    lags = np.arange(h + 1)
    if energy == 0.0:
        values = np.where(lags == 0, 1.0, 0.0)
    else:
        values = np.array([sum(_lagged_sum(s, s, k) for s in segments) for k in lags]) / energy
    n = float(n_total)
    q = n * (n + 2.0) * float(np.sum(values[1:] ** 2 / (n - lags[1:])))
    return Autocorrelation(
        lags=lags, values=values, band=Z95 / math.sqrt(n), statistic=q, dof=h,
        p_value=chi2_sf(q, h), dt=float(dt),
    )


def cross_correlation(
    residual: ArrayLike | Sequence[ArrayLike],
    input: ArrayLike | Sequence[ArrayLike],
    max_lag: int | None = None,
    dt: float = 1.0,
) -> CrossCorrelation:
    """Residual–input cross-correlation for lags ``−h…h`` (pooled over records).

    The ``±1.96/√N`` band holds when the residual is white; against a smooth input
    (not prewhitened) the correlation of structured residuals spreads over many lags.
    """
    rs = [s - s.mean() for s in _as_segments(residual, "residual")]
    us = [s - s.mean() for s in _as_segments(input, "input")]
    if len(rs) != len(us) or any(a.size != b.size for a, b in zip(rs, us, strict=True)):
        raise ValueError("residual and input must have the same number and lengths of segments")
    n_total = sum(s.size for s in rs)
    h = _max_lag(max_lag, min(s.size for s in rs))
    scale = math.sqrt(sum(float(r @ r) for r in rs) * sum(float(u @ u) for u in us))
    lags = np.arange(-h, h + 1)
    if scale == 0.0:
        values = np.zeros(lags.size)
    else:
        values = np.array(
            [sum(_lagged_sum(r, u, k) for r, u in zip(rs, us, strict=True)) for k in lags]
        ) / scale
    return CrossCorrelation(lags=lags, values=values, band=Z95 / math.sqrt(n_total), dt=float(dt))


# --- frequency ------------------------------------------------------------------------------------


@dataclass(frozen=True)
class ResidualSpectrum:
    """One-sided power spectral density of the residual (Hann-windowed periodograms averaged over
    records, smoothed over ``smooth`` bins) and the white-noise floor ``2σ²·dt``."""

    freqs: np.ndarray  # Hz
    psd: np.ndarray  # unit²/Hz
    noise_psd: float
    peaks_hz: tuple[float, ...]  # frequencies where the PSD rises well above the noise floor
    peak_ratios: tuple[float, ...]  # PSD / noise PSD at those peaks


def residual_spectrum(
    residual: ArrayLike | Sequence[ArrayLike],
    dt: float,
    noise_sigma: float | None = None,
    smooth: int = 5,
    threshold: float = 4.0,
    max_peaks: int = 5,
) -> ResidualSpectrum:
    """PSD of the residual and its peaks above ``threshold`` × the noise floor.

    Averaging ``R`` records and ``smooth`` bins gives a χ² estimate with ``2·R·smooth`` d.o.f.;
    with the defaults a white residual exceeds 4× its floor with probability below 1e-6 per bin.
    ``noise_sigma`` defaults to :func:`white_noise_level` of the residual.
    """
    segments = _as_segments(residual, "residual")
    n = min(s.size for s in segments)
    taper = np.hanning(n)
    power = np.mean(
        [np.abs(np.fft.rfft((s[:n] - s[:n].mean()) * taper)) ** 2 for s in segments], axis=0
    )
    psd = 2.0 * dt * power / float(taper @ taper)
    if smooth > 1:
        psd = np.convolve(psd, np.ones(smooth) / smooth, mode="same")
    freqs = np.fft.rfftfreq(n, dt)
    sigma = white_noise_level(np.concatenate(segments)) if noise_sigma is None else noise_sigma
    floor = 2.0 * sigma**2 * dt
    ratio = psd / floor if floor > 0 else np.full_like(psd, np.inf)
    local_max = np.r_[False, (psd[1:-1] >= psd[:-2]) & (psd[1:-1] > psd[2:]), False]
    candidates = np.flatnonzero(local_max & (ratio > threshold) & (freqs > 0))
    best = candidates[np.argsort(ratio[candidates])[::-1][:max_peaks]]
    return ResidualSpectrum(
        freqs=freqs, psd=psd, noise_psd=floor,
        peaks_hz=tuple(float(freqs[i]) for i in best),
        peak_ratios=tuple(float(ratio[i]) for i in best),
    )


@dataclass(frozen=True)
class ResonanceShift:
    """A resonance seen in the measurement and the model's nearest one."""

    measured_hz: float
    model_hz: float

    @property
    def shift_hz(self) -> float:
        """``model − measured``: positive when the model resonates too high."""
        return self.model_hz - self.measured_hz


@dataclass(frozen=True)
class BandError:
    """FRF magnitude error in one frequency band."""

    lower_hz: float
    upper_hz: float
    nrmse: float  # percent, |H| model vs measured
    gain_ratio: float  # rms |H_model| / rms |H_measured| in the band


@dataclass(frozen=True)
class FrfComparison:
    """Measured and model FRF torque → tip acceleration, their error per band and resonances."""

    freqs: np.ndarray
    measured: np.ndarray  # complex, NaN where the input has no power
    model: np.ndarray
    f_max: float
    nrmse: float  # percent over 0 < f ≤ f_max (the spec's FRF metric)
    bands: tuple[BandError, ...]
    resonances: tuple[ResonanceShift, ...]


def _pooled_frf(torques, outputs, dt: float, pad: int):
    """``H = Σ X̄ Y / Σ |X|²`` over records from zero-padded DFTs (transient records).

    Zero padding interpolates the spectrum of the full, unwindowed transient; pooling records
    with different inputs fills each other's spectral nulls.
    Returns (freqs, H, input power, output power).
    """
    n = max(u.size for u in torques)
    nfft = pad * n
    sxx = np.zeros(nfft // 2 + 1)
    syx = np.zeros(nfft // 2 + 1, dtype=complex)
    syy = np.zeros(nfft // 2 + 1)
    for u, y in zip(torques, outputs, strict=True):
        x_f = np.fft.rfft(u, nfft)
        y_f = np.fft.rfft(y - y.mean(), nfft)
        sxx += np.abs(x_f) ** 2
        syx += np.conj(x_f) * y_f
        syy += np.abs(y_f) ** 2
    freqs = np.fft.rfftfreq(nfft, dt)
    return freqs, syx / np.where(sxx > 0, sxx, np.inf), sxx, syy


def _spectral_peaks(freqs, power, f_lo, f_hi, max_peaks, prominence=0.3, depth=2.0):
    """Peaks of ``power`` in ``[f_lo, f_hi]`` (``scipy.signal.find_peaks`` on log power), each
    refined by a parabola through its bin and the two neighbours.

    A peak must stand ``prominence`` decades above the higher of its two bases (SciPy's
    topographic prominence) and within ``depth`` decades of the highest point, which discards
    the ripples and side lobes of a finite record. The ``max_peaks`` highest are returned by
    frequency.
    """
    band = np.flatnonzero((freqs >= f_lo) & (freqs <= f_hi))
    if band.size < 3:
        return []
    logp = np.log10(np.maximum(power[band], 1e-300))
    idx, props = find_peaks(logp, height=logp.max() - depth, prominence=prominence)
    highest = idx[np.argsort(-props["peak_heights"], kind="stable")[:max_peaks]]
    a, b, c = logp[highest - 1], logp[highest], logp[highest + 1]
    denom = a - 2 * b + c
    offset = np.where(denom != 0, 0.5 * (a - c) / np.where(denom != 0, denom, 1.0), 0.0)
    df = freqs[band[1]] - freqs[band[0]]
    return sorted(float(f) for f in freqs[band[highest]] + offset * df)


def frf_error(
    records: Sequence[Record],
    predictions: Sequence[Mapping[str, ArrayLike]],
    f_max: float = 15.0,
    f_peaks_max: float = 60.0,
    pad: int = 8,
    min_input_power: float = 1e-3,
) -> FrfComparison:
    """Compare the FRF torque → tip acceleration of the records with that of the model.

    Both FRFs are estimated the same way (pooled zero-padded DFTs of the whole transients), so
    truncation affects them alike. Bins where the pooled input power is below
    ``min_input_power`` × its peak are NaN. Bands split ``(0, f_max]`` at the midpoints between
    measured resonances; resonances are peaks of the tip-acceleration power spectrum up to
    ``f_peaks_max``, each paired with the model's nearest peak.
    """
    dt = records[0].dt
    torques = [r.torque for r in records]
    freqs, h_meas, sxx, syy_meas = _pooled_frf(
        torques, [r.tip_acceleration for r in records], dt, pad
    )
    _, h_model, _, syy_model = _pooled_frf(
        torques, [np.asarray(p["tip_acceleration"], dtype=np.float64) for p in predictions],
        dt, pad,
    )
    weak = sxx < min_input_power * sxx.max()
    h_meas = np.where(weak, np.nan, h_meas)
    h_model = np.where(weak, np.nan, h_model)
    f_lo = 1.5 / (records[0].n_samples * dt)  # below ~1.5 bins there is no resonance to see
    measured_peaks = _spectral_peaks(freqs, syy_meas, f_lo, f_peaks_max, max_peaks=6)
    model_peaks = _spectral_peaks(freqs, syy_model, f_lo, f_peaks_max, max_peaks=6)
    resonances = _pair_peaks(measured_peaks, model_peaks)
    edges = [0.0]
    inside = [f for f in measured_peaks if f < f_max]
    edges += [0.5 * (a + b) for a, b in zip(inside[:-1], inside[1:], strict=True)]
    edges.append(f_max)
    bands = tuple(
        band for lo, hi in zip(edges[:-1], edges[1:], strict=True)
        if (band := _band_error(freqs, h_meas, h_model, lo, hi)) is not None
    )
    total = _band_error(freqs, h_meas, h_model, 0.0, f_max)
    return FrfComparison(
        freqs=freqs, measured=h_meas, model=h_model, f_max=f_max,
        nrmse=total.nrmse if total else float("nan"), bands=bands, resonances=resonances,
    )


def _pair_peaks(measured: list[float], model: list[float], rtol: float = 0.1):
    """Pair each measured resonance with the nearest unused model one within ``rtol``."""
    pairs = sorted(
        (abs(g - f) / f, f, g) for f in measured for g in model if abs(g - f) <= rtol * f
    )
    used_f, used_g, shifts = set(), set(), []
    for _, f, g in pairs:
        if f not in used_f and g not in used_g:
            used_f.add(f)
            used_g.add(g)
            shifts.append(ResonanceShift(f, g))
    return tuple(sorted(shifts, key=lambda r: r.measured_hz))


def _band_error(freqs, h_meas, h_model, lo, hi) -> BandError | None:
    sel = (freqs > lo) & (freqs <= hi) & np.isfinite(h_meas) & np.isfinite(h_model)
    if sel.sum() < 2:
        return None
    a, b = np.abs(h_meas[sel]), np.abs(h_model[sel])
    rms_a = math.sqrt(float(np.mean(a**2)))
    return BandError(
        lower_hz=float(lo), upper_hz=float(hi),
        nrmse=100.0 * math.sqrt(float(np.mean((a - b) ** 2))) / rms_a,
        gain_ratio=math.sqrt(float(np.mean(b**2))) / rms_a,
    )


# --- time and operating condition ----------------------------------------------------------------


@dataclass(frozen=True)
class ConditionShare:
    """The misfit in one operating condition or time window.

    ``share`` is the fraction of a channel's residual sum of squares beyond the noise that falls
    in the condition, ``combined`` the same over all channels with each normalised by its noise
    variance, ``time_share`` the fraction of samples; ``concentration = combined/time_share`` is
    above 1 where the misfit concentrates.
    """

    condition: str
    time_share: float
    share: dict[str, float]  # per channel
    combined: float
    rms: dict[str, float]  # per channel, residual RMS in the condition

    @property
    def concentration(self) -> float:
        """``combined / time_share``: how much denser the misfit is here than on average."""
        return self.combined / self.time_share if self.time_share > 0 else 0.0


@dataclass(frozen=True)
class Localisation:
    """Misfit shares by operating condition and by time window (pooled over records)."""

    conditions: tuple[ConditionShare, ...]
    windows: tuple[ConditionShare, ...]  # equal time windows, condition names "t0-t1 s"
    window_edges_s: np.ndarray

    def condition(self, name: str) -> ConditionShare:
        for c in self.conditions + self.windows:
            if c.condition == name:
                return c
        names = [c.condition for c in self.conditions + self.windows]
        raise KeyError(f"no condition {name!r}; conditions: {names}")

    def worst_window(self) -> ConditionShare:
        return max(self.windows, key=lambda c: c.concentration)


def _masks(record: Record, velocity: np.ndarray, v_zero: float, n_angle_bins: int, reversal_s):
    """Boolean masks of the operating conditions of one record."""
    torque_on = np.abs(record.torque) > 1e-3 * max(np.max(np.abs(record.torque)), 1e-300)
    v_peak = max(float(np.max(np.abs(velocity))), 1e-300)
    slow = np.abs(velocity) < v_zero
    sign = np.sign(np.where(slow, 0.0, velocity))
    moving = np.flatnonzero(sign != 0)
    reversal = np.zeros(record.n_samples, dtype=bool)
    half = max(1, int(round(reversal_s / record.dt)))
    for a, b in zip(moving[:-1], moving[1:], strict=True):
        if sign[a] != sign[b]:
            reversal[max(a - half, 0) : b + half + 1] = True
    masks = {
        "torque on": torque_on,
        "free vibration": ~torque_on,
        "near-zero velocity": slow,
        "velocity reversals": reversal,
        "high speed": np.abs(velocity) > 0.5 * v_peak,
    }
    return masks


def localise(
    record: Record | Sequence[Record],
    residual: Mapping[str, ArrayLike] | Sequence[Mapping[str, ArrayLike]],
    *,
    velocity: ArrayLike | Sequence[ArrayLike] | None = None,
    noise: Mapping[str, NoiseLevel] | None = None,
    v_zero: float = 0.05,
    reversal_s: float = 0.02,
    n_angle_bins: int = 4,
    n_windows: int = 10,
) -> Localisation:
    """Where the misfit lies: shares by operating condition and by time window.

    ``residual`` maps channel → residual (one mapping per record). ``velocity`` is the joint
    velocity (rad/s) per record, best the model's (smooth); by default it is the measured angle
    differentiated through a 20 Hz low-pass. Conditions: torque on / free vibration,
    near-zero velocity ``|θ'| < v_zero``, reversals (within ``reversal_s`` of a sign change of a
    moving joint), high speed (``|θ'|`` above half its peak), ``n_angle_bins`` equal angle ranges
    and ``n_windows`` equal time windows. The expected noise power ``σ²`` per sample (from
    ``noise``) is subtracted before sharing (for a quantised channel: only the part beyond
    ``±q/2`` counts), so a residual that is all noise shows no concentration.
    """
    records = [record] if isinstance(record, Record) else list(record)
    residuals = [residual] if isinstance(residual, Mapping) else list(residual)
    if len(residuals) != len(records):
        raise ValueError(f"{len(records)} record(s) but {len(residuals)} residual set(s)")
    if velocity is None:
        velocities = [differentiate(r.joint_angle, r.dt, 1, smooth_hz=20.0) for r in records]
    else:
        velocities = [velocity] if isinstance(record, Record) else list(velocity)
        velocities = [np.asarray(v, dtype=np.float64) for v in velocities]
    channels = [c for c in CHANNELS if c in residuals[0]]
    for i, (rec, res, vel) in enumerate(zip(records, residuals, velocities, strict=True)):
        for c in channels:
            if np.shape(res[c]) != (rec.n_samples,):
                raise ValueError(
                    f"residual {c!r} of record {rec.name!r} has shape {np.shape(res[c])}, "
                    f"expected ({rec.n_samples},)"
                )
        if vel.shape != (rec.n_samples,):
            raise ValueError(f"velocity {i} has shape {vel.shape}, expected ({rec.n_samples},)")
    angle_all = np.concatenate([r.joint_angle for r in records])
    angle_edges = np.linspace(angle_all.min(), angle_all.max(), n_angle_bins + 1)
    duration = max(r.duration for r in records)
    window_edges = np.linspace(0.0, duration, n_windows + 1)

    masks: dict[str, list[np.ndarray]] = {}
    for rec, vel in zip(records, velocities, strict=True):
        m = _masks(rec, vel, v_zero, n_angle_bins, reversal_s)
        for j in range(n_angle_bins):
            lo, hi = angle_edges[j], angle_edges[j + 1]
            name = f"angle {np.degrees(lo):.0f} to {np.degrees(hi):.0f} deg"
            upper = rec.joint_angle <= hi if j == n_angle_bins - 1 else rec.joint_angle < hi
            m[name] = (rec.joint_angle >= lo) & upper
        t = rec.time - rec.time[0]
        for j in range(n_windows):
            lo, hi = window_edges[j], window_edges[j + 1]
            upper = t <= hi if j == n_windows - 1 else t < hi
            m[f"{lo:.2f}-{hi:.2f} s"] = (t >= lo) & upper
        for k, v in m.items():
            masks.setdefault(k, []).append(v)

    res = {c: np.concatenate([np.asarray(r[c], dtype=np.float64) for r in residuals])
           for c in channels}
    excess = {c: _excess(res[c], noise.get(c) if noise else None) for c in channels}
    # a pure-noise residual's white excess sums to 0 ± √(2N): do not share out that scatter
    scatter = {c: 3.0 * math.sqrt(2.0 * res[c].size)
               if noise and c in noise and noise[c].kind == "white" else 0.0 for c in channels}
    total = {c: max(float(excess[c].sum()), scatter[c]) for c in channels}

    def share(name: str) -> ConditionShare:
        mask = np.concatenate(masks[name])
        count = int(mask.sum())
        part = {c: max(float(excess[c][mask].sum()), 0.0) for c in channels}
        return ConditionShare(
            condition=name,
            time_share=count / mask.size,
            share={c: part[c] / total[c] if total[c] > 0 else 0.0 for c in channels},
            combined=sum(part.values()) / sum(total.values()) if sum(total.values()) else 0.0,
            rms={c: _rms(res[c][mask]) if count else 0.0 for c in channels},
        )

    window_names = [f"{a:.2f}-{b:.2f} s" for a, b in zip(window_edges[:-1], window_edges[1:],
                                                         strict=True)]
    return Localisation(
        conditions=tuple(share(k) for k in masks if k not in window_names),
        windows=tuple(share(k) for k in window_names),
        window_edges_s=window_edges,
    )


def _excess(residual: np.ndarray, noise: NoiseLevel | None) -> np.ndarray:
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


@dataclass(frozen=True)
class AmplitudeScaling:
    """How the residual RMS grows with the records' torque amplitude, per channel.

    ``exponent`` is the least-squares slope of log RMS on log amplitude (``None`` with fewer
    than two distinct amplitudes): ≈ 1 means a linear-model error (stiffness, inertia),
    well below 1 an amplitude-independent one (friction, offsets), above 1 a nonlinearity.
    """

    amplitudes: np.ndarray
    rms: dict[str, np.ndarray]
    nrmse: dict[str, np.ndarray]
    exponent: dict[str, float | None]


def amplitude_scaling(
    records: Sequence[Record], residuals: Sequence[Mapping[str, ArrayLike]]
) -> AmplitudeScaling:
    """Residual RMS and NRMSE per record against the record's peak |torque|."""
    amplitudes = np.array([float(np.max(np.abs(r.torque))) for r in records])
    channels = [c for c in CHANNELS if c in residuals[0]]
    rms = {c: np.array([_rms(res[c]) for res in residuals]) for c in channels}
    nrmse = {
        c: np.array([100.0 * _rms(res[c]) / _rms(rec.channel(c))
                     for rec, res in zip(records, residuals, strict=True)])
        for c in channels
    }
    exponent: dict[str, float | None] = {}
    distinct = np.unique(np.round(np.log(amplitudes), 6)).size > 1
    for c in channels:
        if distinct and np.all(rms[c] > 0):
            exponent[c] = float(np.polyfit(np.log(amplitudes), np.log(rms[c]), 1)[0])
        else:
            exponent[c] = None
    return AmplitudeScaling(amplitudes=amplitudes, rms=rms, nrmse=nrmse, exponent=exponent)


# --- the whole picture ---------------------------------------------------------------------------


@dataclass(frozen=True)
class ChannelDiagnosis:
    """Everything about one output channel's residuals, pooled over the records."""

    channel: str
    nrmse: float  # percent, mean over records
    noise_floor_nrmse: float  # percent, the NRMSE that the noise alone would give
    rms: float
    noise: NoiseLevel
    whiteness: Autocorrelation
    input_correlation: CrossCorrelation
    spectrum: ResidualSpectrum
    beyond_quantisation: float | None  # RMS of (|r| − q/2)⁺ in steps q; quantised channels only

    @property
    def rms_ratio(self) -> float:
        """Residual RMS over the noise standard deviation (≈ 1 for a correct model)."""
        return self.rms / self.noise.sigma if self.noise.sigma > 0 else math.inf

    def consistent(self, alpha: float = 0.01) -> bool:
        """Are these residuals explained by the measurement noise?

        White noise: RMS within :data:`RMS_RATIO_LIMIT` × σ and Ljung–Box not rejected at
        ``alpha``. Quantised: the residual stays within ``±q/2`` up to
        :data:`QUANTISED_EXCESS_LIMIT` steps RMS (quantisation error is not white).
        """
        if self.noise.kind == "quantised":
            return self.beyond_quantisation is not None and (
                self.beyond_quantisation <= QUANTISED_EXCESS_LIMIT
            )
        return self.rms_ratio <= RMS_RATIO_LIMIT and self.whiteness.white(alpha)


@dataclass(frozen=True)
class Diagnosis:
    """Residual diagnostics of a model on a set of records (see the module docstring)."""

    channels: dict[str, ChannelDiagnosis]
    frf: FrfComparison | None
    localisation: Localisation
    scaling: AmplitudeScaling
    record_names: tuple[str, ...]
    nrmse_per_record: dict[str, np.ndarray]
    alpha: float = 0.01
    residuals: tuple[dict[str, np.ndarray], ...] = field(default=(), repr=False)

    @property
    def consistent_with_noise(self) -> bool:
        """True if every channel's residuals are explained by its measurement noise."""
        return all(c.consistent(self.alpha) for c in self.channels.values())

    @property
    def nrmse(self) -> dict[str, float]:
        return {c: d.nrmse for c, d in self.channels.items()}

    @property
    def noise_floor(self) -> dict[str, float]:
        return {c: d.noise_floor_nrmse for c, d in self.channels.items()}

    def unexplained(self) -> dict[str, Any] | None:
        """Where structure beyond the noise remains (``None`` if consistent with noise)."""
        if self.consistent_with_noise:
            return None
        bad = [c for c in self.channels.values() if not c.consistent(self.alpha)]
        peaks = sorted(
            ((r, f) for c in bad for f, r in zip(c.spectrum.peaks_hz, c.spectrum.peak_ratios,
                                                 strict=True)),
            reverse=True,
        )
        freqs = list(dict.fromkeys(round(f, 3) for _, f in peaks))
        worst = sorted(self.localisation.windows, key=lambda w: -w.concentration)
        times = [w for w in worst if w.concentration > 1.5][:3] or worst[:1]
        parts = []
        for c in bad:
            parts.append(
                f"{c.channel}: NRMSE {c.nrmse:.3g} % vs noise floor {c.noise_floor_nrmse:.3g} % "
                f"(RMS {c.rms:.3g} {UNITS.get(c.channel, '')}, {c.rms_ratio:.2g}x noise)"
            )
        where_f = ", ".join(f"{f:.1f} Hz" for f in freqs[:4])
        where_t = ", ".join(w.condition for w in times)
        message = "; ".join(parts)
        if where_f:
            message += f"; residual spectrum peaks at {where_f}"
        if where_t:
            message += f"; misfit concentrated in {where_t}"
        return {
            "message": message,
            "frequency_hz": freqs,
            "time_s": [_window_bounds(w.condition) for w in times],
            "nrmse": {c.channel: c.nrmse for c in bad},
            "noise_floor": {c.channel: c.noise_floor_nrmse for c in bad},
        }

    def summary(self) -> list[str]:
        """Human-readable findings, one per line."""
        lines = []
        for c in self.channels.values():
            ok = c.consistent(self.alpha)
            status = "consistent with noise" if ok else "NOT explained by noise"
            white = (
                f"Ljung-Box Q={c.whiteness.statistic:.3g} (p={c.whiteness.p_value:.2g})"
                if c.noise.kind == "white"
                else f"beyond quantisation {c.beyond_quantisation:.3g} steps RMS"
            )
            lines.append(
                f"{c.channel}: NRMSE {c.nrmse:.3g} % (noise floor {c.noise_floor_nrmse:.3g} %), "
                f"{white}: {status}"
            )
            lines.append(f"  noise level σ = {c.noise.sigma:.4g} {UNITS.get(c.channel, '')} "
                         f"({c.noise.describe()})")
            if ok:
                continue
            xc = c.input_correlation
            if xc.significant:
                lines.append(
                    f"  residual correlates with the torque: peak {xc.peak_value:+.2f} at lag "
                    f"{1e3 * xc.peak_lag_s:+.0f} ms"
                )
            if c.spectrum.peaks_hz:
                peaks = ", ".join(
                    f"{f:.1f} Hz ({r:.0f}x)"
                    for f, r in zip(c.spectrum.peaks_hz, c.spectrum.peak_ratios, strict=True)
                )
                lines.append(f"  residual spectrum above noise at {peaks}")
        if self.frf is not None:
            lines.append(f"FRF NRMSE (0-{self.frf.f_max:g} Hz): {self.frf.nrmse:.3g} %")
            for r in self.frf.resonances:
                if abs(r.shift_hz) >= 0.05:
                    lines.append(
                        f"  resonance measured at {r.measured_hz:.2f} Hz, model "
                        f"{r.model_hz:.2f} Hz ({r.shift_hz:+.2f} Hz)"
                    )
        if self.consistent_with_noise:
            return lines
        conds = sorted(self.localisation.conditions, key=lambda c: -c.concentration)
        for c in conds[:3]:
            if c.concentration > 1.5:
                lines.append(
                    f"  misfit concentrated in '{c.condition}': "
                    f"{100 * c.combined:.0f} % of the misfit in "
                    f"{100 * c.time_share:.0f} % of the time"
                )
        for c, e in self.scaling.exponent.items():
            if e is not None:
                lines.append(f"  {c} residual RMS grows with torque amplitude^{e:.2f}")
        return lines

    def to_dict(self) -> dict[str, Any]:
        """Plain numbers for JSON (no arrays longer than the lags of interest)."""
        channels = {}
        for name, c in self.channels.items():
            channels[name] = {
                "nrmse": c.nrmse,
                "noise_floor_nrmse": c.noise_floor_nrmse,
                "rms": c.rms,
                "noise_sigma": c.noise.sigma,
                "noise_kind": c.noise.kind,
                "noise_obtained": c.noise.describe(),
                "rms_ratio": c.rms_ratio,
                "ljung_box": {
                    "statistic": c.whiteness.statistic,
                    "dof": c.whiteness.dof,
                    "p_value": c.whiteness.p_value,
                },
                "beyond_quantisation": c.beyond_quantisation,
                "input_correlation": {
                    "peak_lag_s": c.input_correlation.peak_lag_s,
                    "peak_value": c.input_correlation.peak_value,
                    "band": c.input_correlation.band,
                },
                "spectrum_peaks_hz": list(c.spectrum.peaks_hz),
                "consistent": c.consistent(self.alpha),
            }
        frf = None
        if self.frf is not None:
            frf = {
                "nrmse": self.frf.nrmse,
                "bands": [vars(b) for b in self.frf.bands],
                "resonances": [
                    {"measured_hz": r.measured_hz, "model_hz": r.model_hz, "shift_hz": r.shift_hz}
                    for r in self.frf.resonances
                ],
            }
        return {
            "records": list(self.record_names),
            "consistent_with_noise": self.consistent_with_noise,
            "channels": channels,
            "frf": frf,
            "localisation": {
                c.condition: {"time_share": c.time_share, "share": c.share}
                for c in self.localisation.conditions + self.localisation.windows
            },
            "amplitude_exponent": self.scaling.exponent,
            "unexplained": self.unexplained(),
        }


def _window_bounds(name: str) -> list[float]:
    lo, hi = name.removesuffix(" s").split("-")
    return [float(lo), float(hi)]


def _rms(a: ArrayLike) -> float:
    return math.sqrt(float(np.mean(np.square(np.asarray(a, dtype=np.float64)))))


def _prediction_channels(prediction: Any, n: int, name: str) -> dict[str, np.ndarray]:
    """Output channels of a prediction: an ``Outputs``, a ``Record`` or a mapping."""
    out = {}
    for c in CHANNELS + ("joint_velocity",):
        if isinstance(prediction, Mapping):
            value = prediction.get(c)
        elif isinstance(prediction, Record):
            value = prediction.channel(c) if c in prediction.columns else None
        else:
            value = getattr(prediction, c, None)
        if value is None:
            if c in CHANNELS:
                raise ValueError(f"prediction for record {name!r} has no {c!r} output")
            continue
        a = np.asarray(value, dtype=np.float64)
        if a.shape != (n,):
            raise ValueError(
                f"prediction {c!r} for record {name!r} has shape {a.shape}, expected ({n},)"
            )
        out[c] = a
    return out


def diagnose(
    records: Sequence[Record],
    predictions: Sequence[Any],
    *,
    noise: Noise | None = None,
    alpha: float = 0.01,
    max_lag: int | None = None,
    f_max: float = 15.0,
) -> Diagnosis:
    """Run every diagnostic on the residuals of ``predictions`` (one per record).

    A prediction is an :class:`~jaxflex.simulate.Outputs`, a :class:`Record` or a mapping with
    ``joint_angle`` and ``tip_acceleration`` (``joint_velocity`` is used for localisation when
    present). ``noise`` gives channels' levels (a :class:`NoiseLevel` or a white σ); the others
    are estimated by :func:`estimate_noise`. ``alpha`` is the level of the whiteness test.
    """
    records = list(records)
    predictions = list(predictions)
    if not records:
        raise ValueError("diagnose needs at least one record")
    if len(predictions) != len(records):
        raise ValueError(f"{len(records)} record(s) but {len(predictions)} prediction(s)")
    if not 0 < alpha < 1:
        raise ValueError(f"alpha={alpha!r} must lie in (0, 1)")
    preds = [_prediction_channels(p, r.n_samples, r.name)
             for p, r in zip(predictions, records, strict=True)]
    residuals = tuple(
        {c: r.channel(c) - p[c] for c in CHANNELS} for r, p in zip(records, preds, strict=True)
    )
    levels = estimate_noise(records, residuals, given=noise)
    dt = records[0].dt
    channels = {}
    nrmse_per_record = {}
    for c in CHANNELS:
        res = [r[c] for r in residuals]
        per_record = np.array([100.0 * _rms(x) / _rms(rec.channel(c))
                               for x, rec in zip(res, records, strict=True)])
        nrmse_per_record[c] = per_record
        level = levels[c]
        floor = float(np.mean([100.0 * level.sigma / _rms(rec.channel(c)) for rec in records]))
        beyond = None
        if level.kind == "quantised":
            excess = np.concatenate([np.maximum(np.abs(x) - 0.5 * level.step, 0.0) for x in res])
            beyond = _rms(excess) / level.step
        channels[c] = ChannelDiagnosis(
            channel=c,
            nrmse=float(per_record.mean()),
            noise_floor_nrmse=floor,
            rms=_rms(np.concatenate(res)),
            noise=level,
            whiteness=autocorrelation(res, max_lag, dt),
            input_correlation=cross_correlation(
                res, [r.torque for r in records], max_lag=min(200, records[0].n_samples // 4),
                dt=dt,
            ),
            spectrum=residual_spectrum(res, dt, noise_sigma=level.sigma),
            beyond_quantisation=beyond,
        )
    velocities = [p.get("joint_velocity") for p in preds]
    localisation = localise(
        records, residuals, noise=levels,
        velocity=None if any(v is None for v in velocities) else velocities,
    )
    try:
        frf = frf_error(records, preds, f_max=f_max)
    except ValueError:
        frf = None
    return Diagnosis(
        channels=channels,
        frf=frf,
        localisation=localisation,
        scaling=amplitude_scaling(records, residuals),
        record_names=tuple(r.name for r in records),
        nrmse_per_record=nrmse_per_record,
        alpha=alpha,
        residuals=residuals,
    )


__all__ = [
    "Autocorrelation",
    "AmplitudeScaling",
    "BandError",
    "ChannelDiagnosis",
    "CrossCorrelation",
    "Diagnosis",
    "FrfComparison",
    "Localisation",
    "NoiseLevel",
    "ResidualSpectrum",
    "NOISE_SOURCES",
    "Noise",
    "ResonanceShift",
    "amplitude_scaling",
    "autocorrelation",
    "chi2_sf",
    "cross_correlation",
    "diagnose",
    "estimate_noise",
    "frf_error",
    "localise",
    "noise_levels",
    "quantisation_step",
    "residual_spectrum",
    "resolution",
    "white_noise_level",
    "writing_error",
]
