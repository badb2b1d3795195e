"""Preprocessing against analytic answers and the transfer-function form of the same filters."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.signal as ss

from jaxflex.data import Record, RecordWarning
from jaxflex.preprocess import (
    butter_lowpass,
    differentiate,
    joint_velocity_acceleration,
    lowpass,
    lowpass_record,
    remove_accelerometer_offset,
    resample,
    trim,
)

FS = 1000.0
DT = 1.0 / FS


def make_record(n: int = 2001, torque_start: int = 100, bias: float = 0.0) -> Record:
    t = DT * np.arange(n)
    rng = np.random.default_rng(3)
    torque = np.where((t >= torque_start * DT) & (t < torque_start * DT + 0.3), 0.25, 0.0)
    return Record(
        time=t,
        torque=torque,
        joint_angle=np.sin(2 * np.pi * 1.5 * t),
        tip_acceleration=bias + 0.05 * rng.standard_normal(n),
        extras={"tip_deflection": np.cos(t)},
        name="rec",
    )


@pytest.mark.parametrize("order", [1, 2, 3, 4, 6, 8])
@pytest.mark.parametrize("cutoff", [2.0, 20.0, 123.4, 450.0])
def test_butter_has_the_bilinear_butterworth_response(order, cutoff):
    # |H|^2 = 1 / (1 + (tan(pi f/fs) / tan(pi fc/fs))^(2N)): maximally flat, -3 dB at the cutoff
    f = np.array([0.0, 0.3 * cutoff, cutoff, 0.5 * (cutoff + FS / 2), 0.49 * FS])
    _, h = ss.sosfreqz(butter_lowpass(order, cutoff, FS), worN=f, fs=FS)
    ratio = np.tan(np.pi * f / FS) / np.tan(np.pi * cutoff / FS)
    expected = 1.0 / (1.0 + ratio ** (2 * order))
    np.testing.assert_allclose(np.abs(h) ** 2, expected, rtol=1e-9, atol=1e-14)


def test_butter_cutoff_is_the_half_power_point():
    _, h = ss.sosfreqz(butter_lowpass(4, 37.0, FS), worN=[37.0], fs=FS)
    assert abs(h[0]) == pytest.approx(2**-0.5, rel=1e-10)


@pytest.mark.parametrize(
    ("args", "name"),
    [
        ((0, 10.0, FS), "order"),
        ((2.5, 10.0, FS), "order"),
        ((4, 500.0, FS), "cutoff_hz"),
        ((4, -1.0, FS), "cutoff_hz"),
        ((4, 10.0, 0.0), "fs"),
        ((4, 10.0, np.nan), "fs"),
    ],
)
def test_butter_validation_names_argument(args, name):
    with pytest.raises(ValueError, match=name):
        butter_lowpass(*args)


@pytest.mark.parametrize(
    ("order", "cutoff"), [(1, 5.0), (2, 10.0), (4, 20.0), (6, 80.0), (8, 200.0)]
)
def test_lowpass_matches_the_transfer_function_form(order, cutoff):
    # the same filter as a polynomial (b, a) through filtfilt, with filtfilt's default padding
    x = np.random.default_rng(order).standard_normal(2001).cumsum()
    b, a = ss.butter(order, cutoff, fs=FS)
    expected = ss.filtfilt(b, a, x)
    smooth = lowpass(x, cutoff, FS, order=order, padlen=3 * (order + 1))
    np.testing.assert_allclose(smooth, expected, rtol=0, atol=1e-10 * abs(x).max())


@pytest.mark.parametrize("axis", [0, 1, -1])
def test_lowpass_along_an_axis(axis):
    x = np.random.default_rng(0).standard_normal((300, 400))
    b, a = ss.butter(3, 30.0, fs=FS)
    np.testing.assert_allclose(
        lowpass(x, 30.0, FS, order=3, axis=axis, padlen=12),
        ss.filtfilt(b, a, x, axis=axis),
        rtol=0,
        atol=1e-10,
    )


def test_lowpass_validation():
    with pytest.raises(ValueError, match="padlen=15"):
        lowpass(np.ones(10), 20.0, FS, padlen=15)
    with pytest.raises(ValueError, match="padlen=-1"):
        lowpass(np.ones(10), 20.0, FS, padlen=-1)
    with pytest.raises(ValueError, match="x has a non-finite value at index"):
        lowpass(np.r_[np.ones(50), np.nan], 20.0, FS)
    with pytest.raises(ValueError, match="axis=2"):
        lowpass(np.ones((50, 50)), 20.0, FS, axis=2)


def test_lowpass_pads_past_the_start_up_transient():
    t = DT * np.arange(2001)
    x = np.sin(2 * np.pi * t) + 0.5 * t  # a ramp: odd extension continues it exactly
    sos = butter_lowpass(4, 5.0, FS)
    smooth = lowpass(x, 5.0, FS)
    padlen = int(np.ceil(10 * FS / (2 * np.pi * 5.0 * np.sin(np.pi / 8))))  # e^-10 decay
    np.testing.assert_array_equal(smooth, ss.sosfiltfilt(sos, x, padlen=padlen))
    expected = x * (1 + (1 / 5.0) ** 8) ** -1  # |H(1 Hz)|^2 on the sine part, 1 on the ramp
    assert np.abs(smooth - expected).max() < 1e-4
    assert np.abs(ss.sosfiltfilt(sos, x) - expected).max() > 1e-3  # SciPy's short default


def test_zero_phase_keeps_peak_time():
    t = DT * np.arange(2001)
    pulse = np.exp(-(((t - 0.8) / 0.05) ** 2))
    noisy = pulse + 0.02 * np.random.default_rng(5).standard_normal(t.size)
    smooth = lowpass(noisy, 15.0, FS)
    assert t[np.argmax(smooth)] == pytest.approx(0.8, abs=2 * DT)
    # a causal filter of the same order would lag by several milliseconds
    causal = ss.sosfilt(butter_lowpass(4, 15.0, FS), pulse)
    assert t[np.argmax(causal)] - 0.8 > 0.01


def test_differentiate_sine():
    omega = 2 * np.pi * 2.0
    t = DT * np.arange(2001)
    x = np.sin(omega * t)
    inner = slice(1, -1)
    v = differentiate(x, DT, 1)
    acc = differentiate(x, DT, 2)
    # central differences: error omega^3 dt^2 / 6 and omega^4 dt^2 / 12 (here ~3e-4, ~2e-3)
    np.testing.assert_allclose(v[inner], omega * np.cos(omega * t[inner]), atol=4e-4)
    np.testing.assert_allclose(acc[inner], -(omega**2) * x[inner], atol=3e-3)
    # one-sided second-order ends: error about omega^3 dt^2 / 3 and 11 omega^4 dt^2 / 12
    assert abs(v[0] - omega) < 8e-4 and abs(v[-1] - omega * np.cos(omega * t[-1])) < 8e-4
    assert abs(acc[0]) < 3e-2 and abs(acc[-1] + omega**2 * x[-1]) < 3e-2


def test_differentiate_is_second_order_accurate():
    t = np.linspace(0.0, 1.0, 201)
    errs = []
    for step in (1, 2):
        x = np.exp(t[::step])
        errs.append(np.abs(differentiate(x, t[step] - t[0], 1) - x).max())
    assert 3.5 < errs[1] / errs[0] < 4.5


def test_differentiate_smoothing_and_2d():
    omega = 2 * np.pi * 1.0
    t = DT * np.arange(2001)
    clean = np.sin(omega * t)
    quantised = np.round(clean / (2 * np.pi / 4096)) * (2 * np.pi / 4096)
    inner = slice(200, -200)
    raw = differentiate(quantised, DT, 2)
    smooth = differentiate(quantised, DT, 2, smooth_hz=5.0)
    exact = -(omega**2) * clean
    assert np.abs(raw - exact)[inner].max() > 100  # quantisation noise dominates
    assert np.abs(smooth - exact)[inner].max() < 0.02 * omega**2
    stacked = np.stack([clean, 2 * clean], axis=1)
    d = differentiate(stacked, DT, 1, axis=0)
    np.testing.assert_allclose(d[:, 1], 2 * differentiate(clean, DT, 1), rtol=1e-12)


def test_differentiate_validation():
    with pytest.raises(ValueError, match="order"):
        differentiate(np.ones(10), DT, 3)
    with pytest.raises(ValueError, match="dt"):
        differentiate(np.ones(10), 0.0)
    with pytest.raises(ValueError, match="at least 4"):
        differentiate(np.ones(3), DT)


def test_joint_velocity_acceleration():
    r = make_record()
    v, acc = joint_velocity_acceleration(r, cutoff_hz=20.0)
    omega = 2 * np.pi * 1.5
    inner = slice(300, -300)  # away from the filter's start-up transients at the ends
    np.testing.assert_allclose(v[inner], omega * np.cos(omega * r.time[inner]), atol=1e-3)
    np.testing.assert_allclose(acc[inner], -(omega**2) * r.joint_angle[inner], atol=1e-2)


def test_lowpass_record_filters_named_channels_only():
    r = make_record()
    f = lowpass_record(r, 10.0)
    np.testing.assert_array_equal(f.torque, r.torque)
    np.testing.assert_array_equal(f.extras["tip_deflection"], r.extras["tip_deflection"])
    np.testing.assert_allclose(f.tip_acceleration, lowpass(r.tip_acceleration, 10.0, FS))
    assert f.tip_acceleration.std() < 0.3 * r.tip_acceleration.std()
    assert "lowpass 10.0 Hz" in f.metadata["history"]
    g = lowpass_record(r, 10.0, channels=["tip_deflection"])
    np.testing.assert_array_equal(g.joint_angle, r.joint_angle)
    with pytest.raises(KeyError, match="did you mean"):
        lowpass_record(r, 10.0, channels=["tip_deflexion"])
    with pytest.raises(ValueError, match="time"):
        lowpass_record(r, 10.0, channels=["time"])


def test_resample_and_trim():
    r = make_record()
    with pytest.warns(RecordWarning, match="anti-alias"):
        s = resample(r, 2 * DT)
    assert s.n_samples == 1001 and s.dt == pytest.approx(2 * DT)
    np.testing.assert_allclose(s.joint_angle, r.joint_angle[::2], atol=1e-12)
    u = resample(r, DT / 2)
    assert u.n_samples == 4001
    np.testing.assert_allclose(u.joint_angle[::2], r.joint_angle, atol=1e-12)
    tr = trim(r, 0.5, 1.0)
    assert tr.n_samples == 501 and tr.time[0] == 0.0
    with pytest.raises(ValueError, match="dt"):
        resample(r, -1.0)


def test_offset_removed_before_torque():
    r = make_record(bias=0.37)
    quiet_mean = r.tip_acceleration[:100].mean()
    fixed = remove_accelerometer_offset(r)
    np.testing.assert_allclose(fixed.tip_acceleration, r.tip_acceleration - quiet_mean)
    assert abs(fixed.tip_acceleration[:100].mean()) < 1e-12
    assert abs(quiet_mean - 0.37) < 0.02  # noise 0.05 averaged over 100 samples
    assert "offset" in fixed.metadata["history"]


def test_offset_with_window_and_without_rest():
    r = make_record(torque_start=0, bias=-0.2)
    with pytest.warns(RecordWarning, match="quiet_window"):
        same = remove_accelerometer_offset(r)
    assert same is r
    fixed = remove_accelerometer_offset(r, quiet_window=(1.5, 2.0))
    window = r.time >= 1.5
    np.testing.assert_allclose(
        fixed.tip_acceleration, r.tip_acceleration - r.tip_acceleration[window].mean()
    )
    with pytest.raises(ValueError, match="holds no samples"):
        remove_accelerometer_offset(r, quiet_window=(3.0, 4.0))
    with pytest.raises(ValueError, match="quiet_window"):
        remove_accelerometer_offset(r, quiet_window=(1.0, 0.5))
    with pytest.warns(RecordWarning, match="only 3 sample"):
        remove_accelerometer_offset(make_record(torque_start=3))
