"""Where in frequency, through the dynamics: the measured and the model's FRF (torque → a link
output: the tip acceleration, or a strain gauge or deflection sensor where the rig has no
accelerometer) per band, and the shift of each resonance."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike
from scipy.signal import find_peaks

from jaxflex.data import Record

LINK_OUTPUTS: tuple[str, ...] = ("tip_acceleration", "root_strain", "tip_deflection")
"""Outputs that see the link's vibration, in the order the FRF comparison prefers them."""


@dataclass(frozen=True)
class ResonanceShift:
    """A resonance seen in the measurement and the model's nearest one.

    ``resolution_hz`` is the frequency resolution of the records, ``1/T`` for the shortest
    record of duration ``T``: two peaks closer than it cannot be told apart, so a shift
    smaller than it is no evidence that the model resonates elsewhere (:attr:`significant`).
    """

    measured_hz: float
    model_hz: float
    resolution_hz: float = 0.0

    @property
    def shift_hz(self) -> float:
        """``model − measured``: positive when the model resonates too high."""
        return self.model_hz - self.measured_hz

    @property
    def significant(self) -> bool:
        """True if the shift exceeds the frequency resolution: the model resonates elsewhere."""
        return abs(self.shift_hz) > self.resolution_hz


@dataclass(frozen=True)
class BandError:
    """FRF magnitude error in one frequency band."""

    lower_hz: float
    upper_hz: float
    nrmse: float  # percent, |H| model vs measured
    gain_ratio: float  # rms |H_model| / rms |H_measured| in the band


@dataclass(frozen=True)
class FrfComparison:
    """Measured and model FRF torque → ``output``, their error per band and resonances."""

    freqs: np.ndarray
    measured: np.ndarray  # complex, NaN where the input has no power
    model: np.ndarray
    f_max: float
    nrmse: float  # percent over 0 < f ≤ f_max (the spec's FRF metric)
    bands: tuple[BandError, ...]
    resonances: tuple[ResonanceShift, ...]
    output: str = "tip_acceleration"


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
    output: str = "tip_acceleration",
) -> FrfComparison:
    """Compare the FRF torque → ``output`` of the records with that of the model.

    Both FRFs are estimated the same way (pooled zero-padded DFTs of the whole transients), so
    truncation affects them alike. Bins where the pooled input power is below
    ``min_input_power`` × its peak are NaN. Bands split ``(0, f_max]`` at the midpoints between
    measured resonances; resonances are peaks of the output's power spectrum up to
    ``f_peaks_max``, each paired with the model's nearest peak.
    """
    dt = records[0].dt
    torques = [r.input for r in records]
    freqs, h_meas, sxx, syy_meas = _pooled_frf(
        torques, [r.channel(output) for r in records], dt, pad
    )
    _, h_model, _, syy_model = _pooled_frf(
        torques, [np.asarray(p[output], dtype=np.float64) for p in predictions],
        dt, pad,
    )
    weak = sxx < min_input_power * sxx.max()
    h_meas = np.where(weak, np.nan, h_meas)
    h_model = np.where(weak, np.nan, h_model)
    f_lo = 1.5 / (records[0].n_samples * dt)  # below ~1.5 bins there is no resonance to see
    measured_peaks = _spectral_peaks(freqs, syy_meas, f_lo, f_peaks_max, max_peaks=6)
    model_peaks = _spectral_peaks(freqs, syy_model, f_lo, f_peaks_max, max_peaks=6)
    resolution = 1.0 / (min(r.n_samples for r in records) * dt)
    resonances = tuple(ResonanceShift(r.measured_hz, r.model_hz, resolution)
                       for r in _pair_peaks(measured_peaks, model_peaks))
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
        output=output,
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


__all__ = [
    "LINK_OUTPUTS",
    "ResonanceShift",
    "BandError",
    "FrfComparison",
    "frf_error",
]
