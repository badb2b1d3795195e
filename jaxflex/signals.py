"""Torque inputs: the testbed's reference inputs and excitation signals, sampled at ``dt``."""

from __future__ import annotations

import numpy as np
from jaxtyping import Float

from jaxflex._arguments import positive

REFERENCE_AMPLITUDES: dict[str, float] = {"triangular": 0.49, "pulse": 0.25, "half_sine": 0.39}
"""Reference inputs of the testbed: shape name → default amplitude (N m), on 0 ≤ t < 0.3 s."""
REFERENCE_WIDTH = 0.3
"""Duration (s) of the reference inputs; the torque is zero after it."""
EXCITATION_BREAKAWAY_MULTIPLE = 3.0
"""Default peak of the excitation signals, in multiples of the rig's breakaway friction torque
(:meth:`jaxflex.model.Model.breakaway_torque`): the hub then slides through most of each cycle,
where a peak below it leaves the hub held by friction and the record without information."""
_REFERENCE_BREAKAWAY = 0.1071  # N m: the reference testbed's tau_c (jaxflex.parameters)
EXCITATION_AMPLITUDES: dict[str, float] = {
    name: EXCITATION_BREAKAWAY_MULTIPLE * _REFERENCE_BREAKAWAY for name in ("chirp", "multisine")
}
"""Default amplitude of the excitation signals (N m) on the reference testbed:
:data:`EXCITATION_BREAKAWAY_MULTIPLE` times its breakaway friction ``tau_c = 0.1071`` N m."""
INPUT_NAMES: tuple[str, ...] = (*REFERENCE_AMPLITUDES, *EXCITATION_AMPLITUDES)
"""Every input shape :func:`reference_input` knows: the references, then the excitations."""


def time_grid(duration: float = 2.0, dt: float = 1e-3) -> Float[np.ndarray, " n"]:
    """Sample instants ``0, dt, …, duration`` (both ends included)."""
    duration, dt = positive(duration, "duration"), positive(dt, "dt")
    n = int(round(duration / dt)) + 1
    return np.arange(n) * dt


def triangular(t, amplitude: float = 0.49, width: float = REFERENCE_WIDTH):
    """Rises linearly to ``amplitude`` at ``width/2`` and back to zero at ``width``."""
    t = np.asarray(t, dtype=np.float64)
    rise = 1.0 - np.abs(2.0 * t / width - 1.0)
    return np.where((t >= 0) & (t < width), amplitude * rise, 0.0)


def pulse(t, amplitude: float = 0.25, width: float = REFERENCE_WIDTH):
    """Constant ``amplitude`` on ``0 ≤ t < width``."""
    t = np.asarray(t, dtype=np.float64)
    return np.where((t >= 0) & (t < width), amplitude, 0.0)


def half_sine(t, amplitude: float = 0.39, width: float = REFERENCE_WIDTH):
    """``amplitude·sin(π t / width)`` on ``0 ≤ t < width``."""
    t = np.asarray(t, dtype=np.float64)
    return np.where((t >= 0) & (t < width), amplitude * np.sin(np.pi * t / width), 0.0)


def chirp(t, amplitude: float = 0.3213, f0: float = 0.5, f1: float = 20.0, duration=None):
    """Linear chirp from ``f0`` to ``f1`` Hz over ``duration`` (default: the whole grid)."""
    t = np.asarray(t, dtype=np.float64)
    duration = float(t[-1]) if duration is None else duration
    duration, f1 = positive(duration, "duration"), positive(f1, "f1")
    phase = 2.0 * np.pi * (f0 * t + 0.5 * (f1 - f0) / duration * t**2)
    return amplitude * np.sin(phase)


def multisine(
    t,
    amplitude: float = 0.3213,
    frequencies=(1.0, 3.0, 6.0, 9.0, 14.0, 20.0),
    phases=None,
    seed: int = 0,
):
    """Sum of sines with Schroeder-like random phases, scaled so its peak is ``amplitude``.

    ``phases`` (radians) default to a seeded uniform draw; the ramp of the first 5 % of the grid
    avoids a torque step at t = 0.
    """
    t = np.asarray(t, dtype=np.float64)
    freqs = np.asarray(frequencies, dtype=np.float64)
    if freqs.ndim != 1 or freqs.size == 0 or np.any(freqs <= 0):
        raise ValueError(f"frequencies must be a non-empty list of positive Hz, got {frequencies}")
    if phases is None:
        phases = np.random.default_rng(seed).uniform(0, 2 * np.pi, freqs.size)
    phases = np.asarray(phases, dtype=np.float64)
    if phases.shape != freqs.shape:
        raise ValueError(
            f"phases must have the shape of frequencies {freqs.shape}, got {phases.shape}"
        )
    signal = np.sin(2 * np.pi * freqs[:, None] * t[None, :] + phases[:, None]).sum(axis=0)
    ramp = np.clip(t / max(0.05 * t[-1], 1e-12), 0.0, 1.0)
    signal = ramp * signal
    peak = np.max(np.abs(signal))
    return amplitude * signal / peak if peak > 0 else signal


_SHAPES = {
    "triangular": triangular,
    "pulse": pulse,
    "half_sine": half_sine,
    "chirp": chirp,
    "multisine": multisine,
}


def reference_input(
    name: str, amplitude: float | None = None, duration: float = 2.0, dt: float = 1e-3
) -> tuple[Float[np.ndarray, " n"], Float[np.ndarray, " n"]]:
    """``(t, torque)`` for a named input; ``amplitude`` defaults to the testbed's value."""
    if name not in _SHAPES:
        raise ValueError(f"unknown input {name!r}; choose one of {list(INPUT_NAMES)}")
    defaults = {**REFERENCE_AMPLITUDES, **EXCITATION_AMPLITUDES}
    amplitude = defaults[name] if amplitude is None else amplitude
    if not np.isfinite(amplitude):
        raise ValueError(f"amplitude must be finite, got {amplitude}")
    t = time_grid(duration, dt)
    return t, _SHAPES[name](t, amplitude)
