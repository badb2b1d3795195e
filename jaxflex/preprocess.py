"""Careful processing of measured records: zero-phase low-pass, derivatives, resampling, offsets.

As in the dVRK identification workflow, filtering is zero-phase (forward-backward) so that a
filtered signal is not delayed relative to the torque; a delay would be mistaken for dynamics.
The filters are SciPy's (``scipy.signal.butter`` as second-order sections, ``sosfiltfilt``);
what this module adds is the choice of padding, record bookkeeping and argument checks.
"""

from __future__ import annotations

import math
import operator
import warnings
from collections.abc import Sequence

import numpy as np
from jaxtyping import Float
from numpy.typing import ArrayLike
from scipy import signal

from jaxflex._arguments import finite_float, positive
from jaxflex.data import OUTPUT_COLUMNS, Record, RecordWarning, resample_columns

_MIN_QUIET_SAMPLES = 10


def butter_lowpass(order: int, cutoff_hz: float, fs: float) -> Float[np.ndarray, "sections 6"]:
    """Digital Butterworth low-pass as second-order sections (``scipy.signal.butter``).

    The −3 dB point lies exactly at ``cutoff_hz`` (bilinear transform with pre-warping).
    Second-order sections stay accurate at high orders and low cutoffs, where the polynomial
    ``(b, a)`` form loses digits; filter with ``scipy.signal.sosfiltfilt`` or :func:`lowpass`.
    """
    order = _positive_int(order, "order")
    fs = positive(fs, "fs")
    cutoff_hz = positive(cutoff_hz, "cutoff_hz")
    if not cutoff_hz < fs / 2:
        raise ValueError(
            f"cutoff_hz={cutoff_hz!r} must be below the Nyquist frequency fs/2 = {fs / 2!r} Hz"
        )
    return signal.butter(order, cutoff_hz, fs=fs, output="sos")


def lowpass(
    x: ArrayLike,
    cutoff_hz: float,
    fs: float,
    order: int = 4,
    axis: int = -1,
    padlen: int | None = None,
) -> np.ndarray:
    """Zero-phase Butterworth low-pass of ``x`` sampled at ``fs`` (amplitude response squared).

    ``scipy.signal.sosfiltfilt`` with odd extension. Unlike its default padding (a few samples
    per section), the default here lasts until the filter's slowest mode has decayed by e^-10,
    capped by the signal length: with a low cutoff the short default leaves start-up transients
    that reach well into the record (tenths of a second at 5 Hz).
    """
    sos = butter_lowpass(order, cutoff_hz, fs)
    x = _to_last(_finite(x, "x"), axis)
    n = x.shape[-1]
    if padlen is None:
        decay_rate = 2 * math.pi * cutoff_hz * math.sin(math.pi / (2 * order))  # slowest pole
        padlen = min(n - 1, math.ceil(10 * fs / decay_rate))
    elif not _nonnegative_int(padlen, "padlen") < n:
        raise ValueError(f"x has {n} samples along axis {axis}; lowpass needs more than {padlen=}")
    y = signal.sosfiltfilt(sos, x, axis=-1, padtype="odd", padlen=padlen)
    return np.moveaxis(y, -1, axis)


def lowpass_record(
    record: Record,
    cutoff_hz: float,
    channels: Sequence[str] = OUTPUT_COLUMNS,
    order: int = 4,
) -> Record:
    """``record`` with the named channels zero-phase low-passed (outputs only, by default).

    The torque is left alone by default: it is the model's input, applied as a zero-order hold,
    and filtering it would change what the simulation is driven with.
    """
    _check_record(record)
    channels = [channels] if isinstance(channels, str) else list(channels)
    if "time" in channels:
        raise ValueError("channels: 'time' cannot be filtered")
    columns = record.to_dict()
    for c in channels:
        columns[c] = lowpass(record.channel(c), cutoff_hz, record.sample_rate, order=order)
    note = f"lowpass {cutoff_hz!r} Hz order {order} ({', '.join(channels)})"
    return record.with_columns(columns, note=note)


def differentiate(
    x: ArrayLike, dt: float, order: int = 1, smooth_hz: float | None = None, axis: int = -1
) -> np.ndarray:
    """First or second time derivative of uniformly sampled ``x`` along ``axis``.

    Second-order accurate everywhere: central differences inside, one-sided second-order
    stencils at the two ends. With ``smooth_hz`` the signal is first zero-phase low-passed
    (Butterworth, order 4), which differentiation of noisy or quantised data needs.
    """
    dt = positive(dt, "dt")
    if order not in (1, 2) or isinstance(order, bool):
        raise ValueError(f"order={order!r} must be 1 (velocity) or 2 (acceleration)")
    x = _finite(x, "x")
    if smooth_hz is not None:
        x = lowpass(x, smooth_hz, 1.0 / dt, axis=axis)
    x = _to_last(x, axis)
    if x.shape[-1] < 4:
        raise ValueError(f"x has {x.shape[-1]} samples along axis {axis}; need at least 4")
    if order == 1:
        d = np.gradient(x, dt, axis=-1, edge_order=2)
    else:
        d = np.empty_like(x)
        d[..., 1:-1] = (x[..., 2:] - 2 * x[..., 1:-1] + x[..., :-2]) / dt**2
        d[..., 0] = (2 * x[..., 0] - 5 * x[..., 1] + 4 * x[..., 2] - x[..., 3]) / dt**2
        d[..., -1] = (2 * x[..., -1] - 5 * x[..., -2] + 4 * x[..., -3] - x[..., -4]) / dt**2
    return np.moveaxis(d, -1, axis)


def joint_velocity_acceleration(
    record: Record, *, cutoff_hz: float | None
) -> tuple[np.ndarray, np.ndarray]:
    """(joint velocity, joint acceleration) from the encoder angle, low-passed at ``cutoff_hz``.

    The cutoff is required (``None`` for raw differences): a quantised encoder angle
    differentiated twice without smoothing is mostly noise, and the right cutoff depends on the
    arm's modes.
    """
    _check_record(record)
    theta = record.joint_angle
    return (
        differentiate(theta, record.dt, 1, smooth_hz=cutoff_hz),
        differentiate(theta, record.dt, 2, smooth_hz=cutoff_hz),
    )


def resample(record: Record, dt: float) -> Record:
    """``record`` linearly interpolated onto ``time[0] + k·dt`` (all columns).

    Downsampling this way does not remove content above the new Nyquist frequency (a warning
    says so): low-pass first.
    """
    _check_record(record)
    dt = positive(dt, "dt")
    if dt > record.duration:
        raise ValueError(f"dt={dt!r} s exceeds the record duration {record.duration!r} s")
    if dt > record.dt * (1 + 1e-9):
        warnings.warn(
            f"resample: dt={dt!r} s is coarser than the record's {record.dt!r} s; linear "
            "interpolation does not anti-alias (low-pass below the new Nyquist first)",
            RecordWarning,
            stacklevel=2,
        )
    columns = resample_columns(record.to_dict(), dt)
    return record.with_columns(columns, note=f"resample dt={dt!r} s")


def trim(record: Record, t_start: float | None = None, t_end: float | None = None) -> Record:
    """Samples with ``t_start <= time <= t_end``, time re-zeroed (see :meth:`Record.trim`)."""
    _check_record(record)
    return record.trim(t_start, t_end)


def remove_accelerometer_offset(
    record: Record,
    quiet_window: tuple[float, float] | None = None,
    *,
    torque_threshold: float = 0.0,
) -> Record:
    """``record`` with the accelerometer's constant bias subtracted from ``tip_acceleration``.

    The bias is the mean tip acceleration over ``quiet_window = (t0, t1)`` (record time, inclusive)
    or, by default, over the samples before ``|torque|`` first exceeds ``torque_threshold``, while
    the arm is still at rest. If the torque acts from the first sample there is no such rest:
    pass a window (e.g. the end of the record once the arm has settled); without one the record
    is returned unchanged with a :class:`RecordWarning`. The offset is noted in the history.
    """
    _check_record(record)
    time, accel = record.time, record.tip_acceleration
    if quiet_window is None:
        threshold = _nonnegative(torque_threshold, "torque_threshold")
        active = np.flatnonzero(np.abs(record.input) > threshold)
        end = int(active[0]) if active.size else record.n_samples
        if end == 0:
            warnings.warn(
                f"record {record.name!r}: torque acts from the first sample, so there is no rest "
                "period to estimate the accelerometer offset; pass quiet_window=(t0, t1); "
                "offset left in place",
                RecordWarning,
                stacklevel=2,
            )
            return record
        quiet = np.arange(end)
    else:
        t0, t1 = _window(quiet_window)
        tol = 1e-6 * record.dt
        quiet = np.flatnonzero((time >= t0 - tol) & (time <= t1 + tol))
        if quiet.size == 0:
            raise ValueError(
                f"quiet_window={quiet_window!r} holds no samples of record {record.name!r} "
                f"(time spans [{float(time[0])!r}, {float(time[-1])!r}] s)"
            )
    if quiet.size < _MIN_QUIET_SAMPLES:
        warnings.warn(
            f"record {record.name!r}: accelerometer offset estimated from only {quiet.size} "
            "sample(s); pass a longer quiet_window for a reliable estimate",
            RecordWarning,
            stacklevel=2,
        )
    offset = float(np.mean(accel[quiet]))
    span = f"[{float(time[quiet[0]])!r}, {float(time[quiet[-1]])!r}] s"
    return record.replace(
        tip_acceleration=accel - offset,
        metadata=record.noted_metadata(
            f"tip_acceleration offset {offset!r} m/s^2 removed (mean {span})"
        ),
    )


# --- argument checks ----------------------------------------------------------------------------


def _check_record(record: object) -> None:
    if not isinstance(record, Record):
        raise TypeError(f"record must be a jaxflex.data.Record, got {type(record).__name__}")


def _finite(x: ArrayLike, name: str) -> np.ndarray:
    try:
        arr = np.asarray(x, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be an array of real numbers") from None
    if not np.all(np.isfinite(arr)):
        bad = np.argwhere(~np.isfinite(arr))[0]
        raise ValueError(f"{name} has a non-finite value at index {tuple(int(i) for i in bad)}")
    return arr


def _to_last(x: np.ndarray, axis: int) -> np.ndarray:
    """``x`` with ``axis`` moved last, or a ValueError naming the axis."""
    try:
        return np.moveaxis(x, axis, -1)
    except (ValueError, IndexError, TypeError):
        raise ValueError(f"axis={axis!r} is not an axis of x (shape {x.shape})") from None


def _nonnegative(value: object, name: str) -> float:
    return finite_float(value, name, minimum=0.0)


def _nonnegative_int(value: object, name: str) -> int:
    try:
        n = operator.index(value)  # type: ignore[arg-type]
    except TypeError:
        raise ValueError(f"{name}={value!r} must be an integer") from None
    if isinstance(value, bool) or n < 0:
        raise ValueError(f"{name}={value!r} must be an integer >= 0")
    return n


def _positive_int(value: object, name: str) -> int:
    n = _nonnegative_int(value, name)
    if n < 1:
        raise ValueError(f"{name}={value!r} must be an integer >= 1")
    return n


def _window(window: object) -> tuple[float, float]:
    try:
        t0, t1 = (float(t) for t in window)  # type: ignore[union-attr]
    except (TypeError, ValueError):
        raise ValueError(f"quiet_window={window!r} must be a pair (t0, t1) in seconds") from None
    if not (math.isfinite(t0) and math.isfinite(t1) and t0 <= t1):
        raise ValueError(f"quiet_window={window!r} must satisfy t0 <= t1 (finite, seconds)")
    return t0, t1


__all__ = [
    "butter_lowpass",
    "differentiate",
    "joint_velocity_acceleration",
    "lowpass",
    "lowpass_record",
    "remove_accelerometer_offset",
    "resample",
    "trim",
]
