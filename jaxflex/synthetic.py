"""Synthetic "measured" records: simulate the model and add the testbed's measurement noise.

This is the one place where jaxflex makes data that stand in for a real experiment (tests,
demos, notebooks). The noise follows the reference testbed:

* encoder: the joint angle is quantised to ``2π/4096`` rad (round to the nearest count);
* accelerometer: additive white Gaussian noise, ``σ = 0.05 m/s²``.

Noise is drawn from ``numpy.random.default_rng((seed, i))`` for the ``i``-th record, so a data
set is reproducible from its seed and its records carry independent noise.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Mapping, Sequence

import jax.numpy as jnp
import numpy as np
from jaxtyping import ArrayLike, Float

from jaxflex.data import Dataset, Record
from jaxflex.model import Model
from jaxflex.noise import Noise, NoiseLevel, noise_levels
from jaxflex.parameters import Params
from jaxflex.signals import (
    EXCITATION_BREAKAWAY_MULTIPLE,
    INPUT_NAMES,
    REFERENCE_AMPLITUDES,
    reference_input,
)
from jaxflex.simulation import OUTPUT_NAMES, simulate_readings

ENCODER_COUNTS = 4096
"""Encoder counts per revolution."""
ENCODER_STEP = 2.0 * math.pi / ENCODER_COUNTS
"""Quantisation step of the joint angle (rad)."""
ACCELEROMETER_SIGMA = 0.05
"""Standard deviation of the accelerometer noise (m/s²)."""
DEFAULT_INPUTS: tuple[str, ...] = ("triangular", "pulse", "half_sine")
"""The inputs of the synthetic records unless told otherwise: the testbed's three references."""

Seed = int | Sequence[int]
"""A random seed: one integer, or a sequence of them (NumPy's ``SeedSequence`` entropy)."""


def _check_seed(seed: Seed) -> Seed:
    values = [seed] if isinstance(seed, (int, np.integer)) else list(seed)
    if not values or any(
        isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < 0 for v in values
    ):
        raise ValueError(f"seed must be a non-negative int (or a sequence of them), got {seed!r}")
    return seed


def quantise_angle(angle: ArrayLike, step: float = ENCODER_STEP) -> np.ndarray:
    """The angle an encoder with quantisation ``step`` reads: the nearest whole count."""
    return step * np.round(np.asarray(angle, dtype=np.float64) / step)


TESTBED_NOISE: dict[str, NoiseLevel] = {
    "joint_angle": NoiseLevel.quantised(ENCODER_STEP),
    "tip_acceleration": NoiseLevel(ACCELEROMETER_SIGMA),
}
"""The reference testbed's sensors: a 4096-count encoder and the accelerometer's white noise."""


def add_noise(record: Record, seed: Seed, noise: Noise | None = None) -> Record:
    """``record`` as sensors of the given noise levels (:data:`~jaxflex.noise.Noise`; default
    :data:`TESTBED_NOISE`) would log it: a quantised level rounds its channel to the step, a
    white one adds Gaussian noise (drawn in the order given, from ``seed``); channels not named
    are left as they are (extra columns stay noise-free ground truth)."""
    seed = _check_seed(seed)
    levels = noise_levels(TESTBED_NOISE if noise is None else noise, record.columns)
    rng = np.random.default_rng(seed)
    noisy = {
        c: quantise_angle(record.channel(c), v.step) if v.kind == "quantised"
        else record.channel(c) + v.sigma * rng.standard_normal(record.n_samples)
        for c, v in levels.items()
    }
    note = "noise: " + ", ".join(f"{c} {v.describe()}, sigma {v.sigma:.6g}"
                                 for c, v in levels.items())
    logged = record.with_columns({c: record.channel(c) for c in record.columns} | noisy, note)
    return logged.replace(metadata=logged.metadata | {"noise_seed": str(seed)})


def make_records(
    model: Model | None = None,
    params: Mapping[str, ArrayLike] | None = None,
    inputs: Sequence[str] = DEFAULT_INPUTS,
    noise: bool | Noise = True,
    seed: int = 0,
    amplitudes: Mapping[str, float] | None = None,
    *,
    duration: float | None = None,
    dt: float | None = None,
    extras: Sequence[str] = (),
) -> Dataset:
    """Simulate ``model`` at ``params`` for each named input and return the records.

    ``params`` defaults to the model's reference values (missing names are filled from them, so
    ``{"E": 6e10}`` changes only E). ``inputs`` are names known to
    :func:`jaxflex.signals.reference_input`; ``amplitudes`` overrides their default amplitudes
    by name. ``duration``/``dt`` default to the testbed's. ``noise`` adds measurement noise with
    ``seed`` (record ``i`` uses the seed ``(seed, i)``): ``True`` the testbed's sensors',
    ``False`` none, or the channels' levels (:data:`~jaxflex.noise.Noise`, :func:`add_noise`);
    ``extras`` names further simulated outputs (e.g. ``"tip_deflection"``) to store noise-free
    as extra columns.
    """
    model = Model() if model is None else model
    values = true_parameters(model, params)
    inputs = [inputs] if isinstance(inputs, str) else list(inputs)
    if not inputs:
        raise ValueError("inputs must name at least one input")
    amplitudes = dict(amplitudes or {})
    stray = sorted(set(amplitudes) - set(inputs))
    if stray:
        raise ValueError(f"amplitudes given for input(s) {stray} that are not in inputs {inputs}")
    bad_extras = [e for e in extras if e not in OUTPUT_NAMES[2:]]
    if bad_extras:
        raise ValueError(
            f"extras {bad_extras} are not extra outputs; choose from {list(OUTPUT_NAMES[2:])}"
        )
    _check_seed(seed)
    duration = model.testbed.duration if duration is None else duration
    dt = model.testbed.dt if dt is None else dt

    described = ", ".join(f"{k}={float(v)!r}" for k, v in values.items())
    records = []
    for i, name in enumerate(inputs):
        time, torque = reference_input(name, amplitudes.get(name), duration=duration, dt=dt)
        metadata = {
            "synthetic": "jaxflex.synthetic.make_records",
            "parameters": described,
            "effects": ", ".join(model.effect_names) or "none",
        }
        record = simulated_record(model, values, name, time, torque, dt, extras, metadata)
        if noise is not False:
            record = add_noise(record, (seed, i), None if noise is True else noise)
        records.append(record)
    return Dataset(records)


def simulated_record(
    model: Model,
    params: Mapping[str, ArrayLike],
    name: str,
    time: ArrayLike,
    torque: ArrayLike,
    dt: float,
    extras: Sequence[str] = (),
    metadata: Mapping[str, str] | None = None,
) -> Record:
    """A noise-free :class:`Record` of ``model`` at ``params`` driven by ``torque``; ``extras``
    names further simulated outputs stored as extra columns; the model's effects on the
    readings (a sensor gain or offset) act on every column."""
    out = simulate_readings(model, params, torque, dt)
    return Record(
        time=time,
        torque=torque,
        joint_angle=np.asarray(out.joint_angle),
        tip_acceleration=np.asarray(out.tip_acceleration),
        extras={e: np.asarray(out.channel(e)) for e in extras},
        name=name,
        metadata=dict(metadata or {}),
    )


def true_parameters(
    model: Model | None = None, params: Mapping[str, ArrayLike] | None = None
) -> Params:
    """The full, validated parameter set :func:`make_records` simulates with: ``params`` over
    the model's reference values."""
    space = (Model() if model is None else model).space
    params = dict(params or {})
    unknown = sorted(set(params) - set(space.names))
    if unknown:
        raise ValueError(f"unknown parameter(s) {unknown}; known parameters: {list(space.names)}")
    values = dict(space.reference())
    values.update({k: jnp.asarray(v, dtype=jnp.float64) for k, v in params.items()})
    space.validate(values)
    return values




def rig_amplitude(name: str, model: Model, params: Mapping[str, ArrayLike]) -> float:
    """Default amplitude of input ``name`` on a rig, in its drive's unit (N m for a torque drive).

    A reference input keeps the testbed's torque (:data:`REFERENCE_AMPLITUDES`) through the
    drive's gain. An excitation peaks at :data:`EXCITATION_BREAKAWAY_MULTIPLE` times the rig's
    breakaway torque at ``params`` through the gain, within the drive's saturation: it moves
    the hub of any rig, whatever its friction and drive.
    """
    if name not in INPUT_NAMES:
        raise ValueError(f"unknown input {name!r}; choose one of {list(INPUT_NAMES)}")
    gain = model.drive.gain
    if name in REFERENCE_AMPLITUDES:
        return REFERENCE_AMPLITUDES[name] / gain
    amplitude = EXCITATION_BREAKAWAY_MULTIPLE * model.breakaway_torque(params) / gain
    saturation = getattr(model.drive, "saturation", None)
    return amplitude if saturation is None else min(amplitude, saturation)


def warn_if_held(
    name: str, model: Model, params: Mapping[str, ArrayLike], signal: Float[ArrayLike, " n"],
    dt: float,
) -> bool:
    """Warn (and return True) when input ``name``'s torque at the hub never exceeds the rig's
    breakaway torque at ``params``: friction then holds the hub and the record says nothing
    about the arm. ``signal`` is the logged input in the drive's unit, sampled at ``dt``."""
    torque = np.asarray(model.input_torque(dict(params), np.asarray(signal, np.float64), dt))
    peak, breakaway = float(np.max(np.abs(torque), initial=0.0)), model.breakaway_torque(params)
    if peak > breakaway:
        return False
    warnings.warn(
        f"input {name!r} peaks at {peak:.3g} N m at the hub, which never exceeds the joint's "
        f"breakaway friction torque {breakaway:.3g} N m: friction holds the hub still; raise "
        "the amplitude",
        stacklevel=2,
    )
    return True


__all__ = [
    "ACCELEROMETER_SIGMA",
    "DEFAULT_INPUTS",
    "ENCODER_COUNTS",
    "ENCODER_STEP",
    "TESTBED_NOISE",
    "add_noise",
    "make_records",
    "quantise_angle",
    "rig_amplitude",
    "simulated_record",
    "true_parameters",
    "warn_if_held",
]
