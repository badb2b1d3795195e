"""Validation metrics: time-domain NRMSE, held-out relative error, and the H1 FRF comparison.

These follow the reference testbed spec (the paper's Eq. 7 style NRMSE in percent, the FRF
torque → tip acceleration compared on 0 < f ≤ 15 Hz, and the dVRK package's held-out relative
error). NumPy float64 with SciPy's spectral estimates; inputs may be any array-like (NumPy,
JAX, lists).
"""

from __future__ import annotations

import numpy as np
from jaxtyping import Float
from numpy.typing import ArrayLike
from scipy import signal

from jaxflex._arguments import finite_float


def nrmse(measured: ArrayLike, model: ArrayLike) -> float:
    """Normalised RMS error in percent, ``100·rms(y − ŷ)/rms(y)``, over the whole arrays."""
    y, y_hat = _pair(measured, model)
    return _nrmse(y, y_hat)


def relative_error(measured: ArrayLike, model: ArrayLike) -> float:
    """``‖y − ŷ‖ / ‖y‖`` (a fraction), the held-out error the dVRK package reports."""
    y, y_hat = _pair(measured, model)
    return float(np.linalg.norm(y - y_hat) / np.linalg.norm(y))


def h1_frf(
    input: ArrayLike,
    output: ArrayLike,
    fs: float,
    *,
    nperseg: int | None = None,
    window: str | None = None,
    overlap: float = 0.5,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """H1 estimate of the FRF input → output: ``(freqs, H, coherence)``, one-sided.

    ``H = S_yx / S_xx`` with ``S_yx = mean(conj(X)·Y)`` over segments (Welch averaging; each
    segment has its mean removed and is windowed), the convention of ``scipy.signal.csd``.

    ``nperseg=None`` uses the whole record as one segment with a boxcar window (unless
    ``window`` says otherwise). That is the right estimate for transient tests such as the 2 s
    pulse records: the arm starts at rest and its response has (nearly) died out by the end,
    so the DFTs of the full records give ``Y/X`` with no leakage, whereas a taper would weight
    away the start where the input acts and short segments would cut the transient apart. (If
    the response has not fully decayed, estimate the model's FRF the same way from simulated
    records so that both carry the same truncation.) With a single segment the coherence is
    identically 1 and carries no information. For long
    stationary excitation (noise, repeated chirps) give ``nperseg`` to average segments
    (default window 'hann', overlap 0.5) and read the coherence.
    Each segment's mean is removed (as ``scipy.signal.csd`` does by default), so the DC bin is
    NaN; so is any frequency where ``S_xx = 0`` (no input power).
    """
    x, y = _pair(input, output, names=("input", "output"))
    if x.ndim != 1:
        raise ValueError(f"input and output must be 1-D signals, got shape {x.shape}")
    fs = finite_float(fs, "fs", minimum=0.0, strict=True)
    n = x.size
    if nperseg is None:
        nperseg, window = n, window or "boxcar"
    elif isinstance(nperseg, bool) or not isinstance(nperseg, (int, np.integer)):
        raise ValueError(f"nperseg={nperseg!r} must be an integer or None")
    elif not 2 <= nperseg <= n:
        raise ValueError(f"nperseg={nperseg!r} must be between 2 and the signal length {n}")
    if not 0 <= finite_float(overlap, "overlap") < 1:
        raise ValueError(f"overlap={overlap!r} must be a fraction in [0, 1)")
    welch = {
        "fs": fs,
        "window": spectral_window(window or "hann", int(nperseg)),
        "nperseg": int(nperseg),
        "noverlap": int(overlap * nperseg),
        "detrend": "constant",
    }
    freqs, s_yx = signal.csd(x, y, **welch)
    s_xx = signal.welch(x, **welch)[1]
    s_yy = signal.welch(y, **welch)[1]
    with np.errstate(divide="ignore", invalid="ignore"):
        h = np.where(s_xx > 0, s_yx / s_xx, np.nan)
        coherence = np.where(s_xx * s_yy > 0, np.abs(s_yx) ** 2 / (s_xx * s_yy), np.nan)
    h[0] = coherence[0] = np.nan  # segment means were removed: the DC bin carries no information
    return freqs, h, coherence


def frf_nrmse(
    freqs: ArrayLike,
    H_measured: ArrayLike,
    H_model: ArrayLike,
    f_max: float = 15.0,
    f_min: float = 0.0,
) -> float:
    """NRMSE (percent) of the FRF magnitude, ``|H|``, over ``f_min < f ≤ f_max``.

    Bins in the band must be finite: an input with no power at some frequency (a pulse has
    spectral nulls at multiples of 1/width) should be excluded by the caller, e.g. by choosing
    ``f_min``/``f_max`` or masking on the coherence.
    """
    f = np.asarray(freqs, dtype=np.float64)
    if f.ndim != 1:
        raise ValueError(f"freqs must be 1-D, got shape {f.shape}")
    h_meas, h_model = np.asarray(H_measured), np.asarray(H_model)
    for name, h in (("H_measured", h_meas), ("H_model", h_model)):
        if h.shape != f.shape:
            raise ValueError(f"{name} has shape {h.shape} but freqs has shape {f.shape}")
    f_min, f_max = float(f_min), float(f_max)
    if not f_min < f_max:
        raise ValueError(f"f_min={f_min!r} must be below f_max={f_max!r}")
    band = (f > f_min) & (f <= f_max)
    if not band.any():
        raise ValueError(
            f"no frequency in ({f_min!r}, {f_max!r}] Hz; freqs span [{f.min()!r}, {f.max()!r}]"
        )
    y, y_hat = _pair(
        np.abs(h_meas[band]), np.abs(h_model[band]), names=("|H_measured|", "|H_model|")
    )
    return _nrmse(y, y_hat)


def _pair(
    measured: ArrayLike, model: ArrayLike, names: tuple[str, str] = ("measured", "model")
) -> tuple[np.ndarray, np.ndarray]:
    """Two finite float64 arrays of equal shape; the first must not be all zero."""
    arrays = []
    for name, value in zip(names, (measured, model), strict=True):
        a = np.asarray(value)
        if a.dtype.kind not in "biuf":
            raise ValueError(f"{name} must hold real numbers, got dtype {a.dtype}")
        a = a.astype(np.float64)
        if a.size == 0:
            raise ValueError(f"{name} is empty")
        if not np.all(np.isfinite(a)):
            raise ValueError(
                f"{name} has non-finite values (first at flat index "
                f"{int(np.flatnonzero(~np.isfinite(a))[0])})"
            )
        arrays.append(a)
    y, y_hat = arrays
    if y.shape != y_hat.shape:
        raise ValueError(f"{names[0]} has shape {y.shape} but {names[1]} has shape {y_hat.shape}")
    if not np.any(y):
        raise ValueError(f"{names[0]} is zero everywhere")
    return y, y_hat


def _nrmse(y: np.ndarray, y_hat: np.ndarray) -> float:
    return 100.0 * _rms(y - y_hat) / _rms(y)


def _rms(a: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.square(a))))


def spectral_window(name: str, n: int) -> Float[np.ndarray, " n"]:
    """Periodic (DFT-even) window of ``n`` samples for spectra, ``scipy.signal.get_window``.

    ``name`` is any window SciPy knows without extra parameters ("hann", "boxcar", "hamming",
    ...).
    """
    try:
        return signal.get_window(name, n, fftbins=True)
    except (ValueError, TypeError):
        raise ValueError(f"window={name!r} is not a window scipy.signal.get_window knows") from None


__all__ = ["frf_nrmse", "h1_frf", "nrmse", "relative_error", "spectral_window"]
