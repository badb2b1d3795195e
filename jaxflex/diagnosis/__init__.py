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

from jaxflex.diagnosis.correlation import (
    Autocorrelation,
    CrossCorrelation,
    autocorrelation,
    chi2_sf,
    cross_correlation,
)
from jaxflex.diagnosis.frf import BandError, FrfComparison, ResonanceShift, frf_error
from jaxflex.diagnosis.localise import Localisation, localise
from jaxflex.diagnosis.noise import (
    NOISE_SOURCES,
    Noise,
    NoiseLevel,
    estimate_noise,
    noise_levels,
    quantisation_step,
    resolution,
    white_noise_level,
    writing_error,
)
from jaxflex.diagnosis.report import ChannelDiagnosis, Diagnosis, diagnose
from jaxflex.diagnosis.scaling import AmplitudeScaling, amplitude_scaling
from jaxflex.diagnosis.spectrum import ResidualSpectrum, residual_spectrum

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
