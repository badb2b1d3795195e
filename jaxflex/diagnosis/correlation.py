"""Whiteness and what the input explains: the residual's autocorrelation with the Ljung–Box
portmanteau test, and its cross-correlation with the torque over lags."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike
from scipy.stats import chi2

Z95 = 1.959963984540054

"""Two-sided 95 % normal quantile: the band ``±Z95/√N`` of a white sequence's correlations."""


def chi2_sf(x: float, dof: float) -> float:
    """Survival function ``P(χ²_dof > x)`` (``scipy.stats.chi2.sf``)."""
    if dof <= 0:
        raise ValueError(f"chi-square degrees of freedom must be positive, got {dof!r}")
    if not x > 0:
        return 1.0
    return float(chi2.sf(x, dof))


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


def as_segments(x: ArrayLike | Sequence[ArrayLike], name: str) -> list[np.ndarray]:
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
    segments = [s - s.mean() for s in as_segments(residual, "residual")]
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
    rs = [s - s.mean() for s in as_segments(residual, "residual")]
    us = [s - s.mean() for s in as_segments(input, "input")]
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


__all__ = [
    "chi2_sf",
    "Autocorrelation",
    "CrossCorrelation",
    "autocorrelation",
    "cross_correlation",
]
