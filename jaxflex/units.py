"""Unit checks of a loaded record: is time in seconds, the angle in radians, the torque in N m?

A logger's file states no units, and a record in milliseconds or degrees would still fit, to
nonsense parameters. The checks compare what the columns imply (the sampling step, the arm's
length, the joint's inertia) with what any lab arm can be, and stop with the reason and how to
load the file anyway.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Collection, Mapping

import numpy as np

from jaxflex.records import INPUT_COLUMNS, RecordError, RecordWarning

_DEGREE_LIMIT = 8 * math.pi  # four turns: more than that from a one-link arm suggests degrees


def _check_excitation_and_units(columns: Mapping[str, np.ndarray], where: str,
                                own: Collection[str] = ()) -> None:
    """Refuse an input that is zero throughout; warn about a joint angle that looks like degrees
    (unless it is a rig's channel, ``own``: the rig declares its unit and checks it,
    :func:`jaxflex.measured.model_record`)."""
    source = next(c for c in INPUT_COLUMNS if c in columns)
    if not np.any(columns[source]):
        raise RecordError(
            f"{where}: column {source!r} is zero in every row; nothing excites the arm"
        )
    if "joint_angle" not in columns or "joint_angle" in own:
        return
    angle = columns["joint_angle"]
    peak = float(np.max(np.abs(angle)))
    if peak > _DEGREE_LIMIT:
        warnings.warn(
            f"{where}: column 'joint_angle' reaches {peak:.6g}, more than four turns in "
            "radians; is it in degrees? joint_angle must be in rad",
            RecordWarning,
            stacklevel=3,
        )
    elif peak >= 2 and np.all(angle == np.round(angle)):
        warnings.warn(
            f"{where}: column 'joint_angle' holds only whole numbers (up to {peak:.6g}); it "
            "looks like degrees or encoder counts; joint_angle must be in rad",
            RecordWarning,
            stacklevel=3,
        )


def check_units(columns: Mapping[str, np.ndarray], where: str = "record") -> None:
    """Stop (RecordError) on columns whose units are implausible for a lab arm.

    Runs on every loaded record (:func:`jaxflex.record_files.load_record`) unless
    ``unit_check=False``.

    * time: a step of :data:`MAX_PLAUSIBLE_DT` s or more (milliseconds or sample numbers?);
    * joint angle: constant although the torque is not (a warning: stiction, or no encoder);
    * joint angle against tip acceleration integrated twice (the tip's path, up to a drift): their
      ratio is the arm's length; below :data:`MIN_PLAUSIBLE_LENGTH` the angle is in degrees;
    * torque against angular acceleration, speed and direction (least squares): an inertia
      above :data:`MAX_PLAUSIBLE_INERTIA` means a torque far too large (not in N m).

    Each message says how to load the file anyway (``unit_check=False``; CLI: --no-unit-check).
    """
    skip = " (pass unit_check=False to skip this check)"
    time = columns["time"]
    dt = float(time[-1] - time[0]) / (time.shape[0] - 1)
    if dt >= MAX_PLAUSIBLE_DT:
        raise RecordError(
            f"{where}: column 'time': step {dt:.6g} s ({1 / dt:.3g} Hz sampling); is time in "
            f"milliseconds or sample numbers? time must be in s{skip}"
        )
    angle, torque = columns.get("joint_angle"), columns.get("torque")
    if angle is None or torque is None:  # another drive's input: no torque scale to check
        return
    if np.ptp(angle) == 0:  # possible (torque below breakaway friction), but worth a word
        warnings.warn(
            f"{where}: column 'joint_angle' is constant ({float(angle[0])!r}) although the "
            "torque is not: the torque stays below the joint's breakaway friction, or the "
            "encoder is not connected; such a record tells nothing about the arm's dynamics",
            RecordWarning,
            stacklevel=3,
        )
        return
    if "tip_acceleration" in columns:
        length = _effective_length(time, angle, columns["tip_acceleration"])
        if length is not None and abs(length) < MIN_PLAUSIBLE_LENGTH:
            raise RecordError(
                f"{where}: column 'joint_angle' against the twice-integrated 'tip_acceleration' "
                f"implies an arm {abs(length):.3g} m long (below {MIN_PLAUSIBLE_LENGTH:g} m); is "
                f"the angle in degrees? joint_angle must be in rad{skip}"
            )
    inertia = _effective_inertia(time, angle, torque)
    if inertia is not None and inertia > MAX_PLAUSIBLE_INERTIA:
        raise RecordError(
            f"{where}: column 'torque': the record implies a joint inertia of {inertia:.3g} "
            f"kg m^2, above {MAX_PLAUSIBLE_INERTIA:g}; is the torque in N m (and the angle in "
            f"rad, time in s)?{skip}"
        )


MAX_PLAUSIBLE_DT = 0.05
"""A sampling step this long (20 Hz) cannot resolve a flexible arm: time is in ms, or counts."""
MIN_PLAUSIBLE_LENGTH = 0.05
"""Shortest plausible arm (m), tip path over joint angle; a degree angle makes it 57x shorter."""
MAX_PLAUSIBLE_INERTIA = 1e3
"""A joint inertia (kg m²) above any lab arm's: the torque is far too large (not in N m)."""


def _fit_share(basis: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, float]:
    """Least-squares coefficients of ``y`` on the columns of ``basis``, and how much worse the
    fit gets without the first column (residual ratio; large = the first column is needed)."""
    coef, *_ = np.linalg.lstsq(basis, y, rcond=None)
    rest, *_ = np.linalg.lstsq(basis[:, 1:], y, rcond=None)
    with_first = float(np.sum((y - basis @ coef) ** 2))
    without = float(np.sum((y - basis[:, 1:] @ rest) ** 2))
    return coef, without / with_first if with_first > 0 else math.inf


def _integral(x: np.ndarray, time: np.ndarray) -> np.ndarray:
    """Cumulative trapezoidal integral from the first sample (0 there)."""
    return np.concatenate([[0.0], np.cumsum(0.5 * (x[1:] + x[:-1]) * np.diff(time))])


def _effective_inertia(time: np.ndarray, angle: np.ndarray, torque: np.ndarray) -> float | None:
    """``|J|`` of ``J·θ'' + b·θ' + c·sign(θ') = τ`` integrated twice (noise-robust; constants of
    integration fitted), or None when the angle does not determine it."""
    speed = np.gradient(angle, time)
    sign = np.tanh(speed / (1e-3 + 0.01 * float(np.ptp(speed))))
    tau = (time - time[0]) / (time[-1] - time[0])
    theta = angle - angle[0]
    basis = np.column_stack([theta, _integral(theta, time), _integral(_integral(sign, time), time),
                             np.ones_like(tau), tau])
    coef, needed = _fit_share(basis, _integral(_integral(torque, time), time))
    return abs(float(coef[0])) if needed > 4 else None


def _effective_length(time: np.ndarray, angle: np.ndarray, tip: np.ndarray) -> float | None:
    """``L`` in ``∬ tip_acceleration ≈ L·angle + a + b·t + c·t²`` (the quadratic takes the
    drift of an accelerometer offset), or None when that explains less than half the path."""
    path = _integral(_integral(tip, time), time)
    tau = (time - time[0]) / (time[-1] - time[0])
    basis = np.column_stack([angle - angle[0], np.ones_like(tau), tau, tau**2])
    coef, needed = _fit_share(basis, path)
    return float(coef[0]) if needed > 2 else None


__all__ = [
    "MAX_PLAUSIBLE_DT",
    "MIN_PLAUSIBLE_LENGTH",
    "MAX_PLAUSIBLE_INERTIA",
    "check_units",
]
