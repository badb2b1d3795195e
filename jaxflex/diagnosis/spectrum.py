"""Where in frequency: the residual's power spectral density against the noise floor."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from jaxflex.diagnosis.correlation import as_segments
from jaxflex.diagnosis.noise import white_noise_level


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
    segments = as_segments(residual, "residual")
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


__all__ = [
    "ResidualSpectrum",
    "residual_spectrum",
]
