"""Validation metrics: exact values for scaled signals, and H1 FRFs of known linear systems."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.signal as ss

from jaxflex.metrics import frf_nrmse, h1_frf, nrmse, relative_error, spectral_window

FS = 1000.0


def resonator(f0: float = 8.0, zeta: float = 0.1) -> tuple[np.ndarray, np.ndarray]:
    """A discrete second-order resonator (bilinear transform of a mass-spring-damper)."""
    w0 = 2 * np.pi * f0
    return ss.bilinear([w0**2], [1.0, 2 * zeta * w0, w0**2], fs=FS)


def true_frf(b: np.ndarray, a: np.ndarray, freqs: np.ndarray) -> np.ndarray:
    return ss.freqz(b, a, worN=freqs, fs=FS)[1]


@pytest.mark.parametrize("eps", [0.1, -0.03, 1e-4])
def test_scaled_signal_errors_are_exact(eps):
    y = np.sin(np.linspace(0, 7, 501)) + 0.3
    assert nrmse(y, y * (1 + eps)) == pytest.approx(100 * abs(eps), rel=0, abs=1e-12)
    assert relative_error(y, y * (1 + eps)) == pytest.approx(abs(eps), rel=0, abs=1e-14)
    assert nrmse(y, y) == 0.0 and relative_error(y, y) == 0.0


def test_metrics_accept_array_likes_and_2d():
    y = [[1.0, 2.0], [3.0, 4.0]]
    assert nrmse(y, [[1.0, 2.0], [3.0, 5.0]]) == pytest.approx(100 * 0.5 / np.sqrt(7.5))
    assert isinstance(relative_error(np.arange(1, 4), [1, 2, 3]), float)


def test_metric_validation():
    with pytest.raises(ValueError, match="shape"):
        nrmse(np.ones(3), np.ones(4))
    with pytest.raises(ValueError, match="measured is zero everywhere"):
        nrmse(np.zeros(3), np.ones(3))
    with pytest.raises(ValueError, match="model has non-finite"):
        relative_error(np.ones(3), [1.0, np.nan, 1.0])


def test_h1_matches_scipy_welch():
    rng = np.random.default_rng(0)
    x = rng.standard_normal(8192)
    y = ss.lfilter(*resonator(), x) + 0.1 * rng.standard_normal(x.size)
    kw = {"fs": FS, "nperseg": 1024, "noverlap": 512, "window": "hann"}
    f_ref, pxy = ss.csd(x, y, **kw)
    _, pxx = ss.welch(x, **kw)
    _, coh_ref = ss.coherence(x, y, **kw)
    f, h, coh = h1_frf(x, y, FS, nperseg=1024)
    np.testing.assert_allclose(f, f_ref, rtol=1e-14)
    np.testing.assert_allclose(h[1:], (pxy / pxx)[1:], rtol=1e-10)
    np.testing.assert_allclose(coh[1:], coh_ref[1:], rtol=1e-10)
    assert np.isnan(h[0]) and np.isnan(coh[0])  # mean removed: DC carries nothing
    f, h, _ = h1_frf(x, y, FS, nperseg=600, window="boxcar", overlap=0.25)
    kw = {"fs": FS, "nperseg": 600, "noverlap": 150, "window": "boxcar"}
    ref = ss.csd(x, y, **kw)[1] / ss.welch(x, **kw)[1]
    np.testing.assert_allclose(h[1:], ref[1:], rtol=1e-10)


def test_h1_whole_record_matches_scipy():
    x = np.r_[np.full(300, 0.25), np.zeros(1701)]
    y = ss.lfilter(*resonator(), x)
    f, h, coh = h1_frf(x, y, FS)
    kw = {"fs": FS, "nperseg": x.size, "window": "boxcar"}
    with np.errstate(invalid="ignore"):
        ref = ss.csd(x, y, **kw)[1][1:] / ss.welch(x, **kw)[1][1:]
    # bins near the pulse's spectral nulls have little input power: compare on the FRF's scale;
    # at 333 Hz (300 samples = 100 periods) the input has no power at all and both give NaN
    np.testing.assert_allclose(h[1:], ref, rtol=0, atol=1e-10 * np.nanmax(np.abs(ref)))
    assert np.isnan(h[667]) and np.isnan(coh[667])
    np.testing.assert_allclose(coh[1:667], 1.0, rtol=1e-12)
    assert f[1] == pytest.approx(FS / x.size)


def test_h1_recovers_resonator_from_transient():
    b, a = resonator(f0=8.0, zeta=0.1)
    n = 2001
    t = np.arange(n) / FS
    chirp = np.where(t < 1.0, np.sin(2 * np.pi * (1 + 15 * t) * t), 0.0)  # 1 → 31 Hz in 1 s
    y = ss.lfilter(b, a, chirp)
    f, h, _ = h1_frf(chirp, y, FS)
    band = (f > 0) & (f <= 15)
    ref = true_frf(b, a, f[band])
    np.testing.assert_allclose(np.abs(h[band]), np.abs(ref), rtol=0.01)
    assert frf_nrmse(f, h, np.r_[h[:1], true_frf(b, a, f[1:])]) < 1.0


def test_h1_recovers_resonator_from_white_noise():
    b, a = resonator(f0=8.0, zeta=0.1)
    x = np.random.default_rng(4).standard_normal(2**19)
    y = ss.lfilter(b, a, x)
    # long segments: leakage of the response across segment edges is the H1 error here
    f, h, coh = h1_frf(x, y, FS, nperseg=2**15)
    band = (f > 0.5) & (f <= 15)
    np.testing.assert_allclose(np.abs(h[band]), np.abs(true_frf(b, a, f[band])), rtol=0.01)
    assert coh[band].min() > 0.99


def test_h1_validation():
    x = np.ones(100)
    with pytest.raises(ValueError, match="nperseg"):
        h1_frf(x, x, FS, nperseg=1000)
    with pytest.raises(ValueError, match="window"):
        h1_frf(x, x, FS, nperseg=50, window="no-such-window")
    with pytest.raises(ValueError, match="overlap"):
        h1_frf(x, x, FS, nperseg=50, overlap=1.0)
    with pytest.raises(ValueError, match="fs"):
        h1_frf(x, x, 0.0)
    with pytest.raises(ValueError, match="output has shape"):
        h1_frf(x, np.ones(99), FS)


def test_frf_nrmse_identical_and_scaled():
    f = np.linspace(0, 50, 101)
    h = (1 + 1j * f) / (1 + 0.1j * f - 0.01 * f**2)
    assert frf_nrmse(f, h, h) == 0.0
    assert frf_nrmse(f, h, 1.05 * h) == pytest.approx(5.0, abs=1e-12)
    assert frf_nrmse(f, h, 1.05j * h) == pytest.approx(5.0, abs=1e-12)  # magnitude only
    # only 0 < f <= 15 counts: a change outside the band is invisible
    outside = np.where(f > 15, 2 * h, h)
    assert frf_nrmse(f, h, outside) == 0.0
    assert frf_nrmse(f, h, outside, f_max=50.0) > 0.0
    with pytest.raises(ValueError, match="no frequency"):
        frf_nrmse(f, h, h, f_min=20.0, f_max=20.1)
    with pytest.raises(ValueError, match="H_model has shape"):
        frf_nrmse(f, h, h[:-1])


@pytest.mark.parametrize("n", [7, 64, 2001])
def test_spectral_windows_are_periodic(n):
    k = np.arange(n)
    np.testing.assert_allclose(spectral_window("hann", n), 0.5 - 0.5 * np.cos(2 * np.pi * k / n),
                               rtol=0, atol=1e-15)
    np.testing.assert_array_equal(spectral_window("boxcar", n), np.ones(n))
    hamming = 0.54 - 0.46 * np.cos(2 * np.pi * k / n)
    np.testing.assert_allclose(spectral_window("hamming", n), hamming, rtol=0, atol=1e-15)
    with pytest.raises(ValueError, match="window='hannn' is not a window"):
        spectral_window("hannn", n)
