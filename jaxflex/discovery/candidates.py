"""Candidate effects: an effect, or a profile of effects (a Stribeck velocity grid) tested as
one."""

from __future__ import annotations

import dataclasses
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from typing import TYPE_CHECKING

import equinox as eqx
from jaxtyping import Array, Float

from jaxflex.effects import (
    CALIBRATED_CHANNELS,
    AbstractEffect,
    DriveGain,
    SensorGain,
    SensorOffset,
    get_effect,
    library,
)
from jaxflex.effects._base import Structure
from jaxflex.parameters import ParameterSpec, Params
from jaxflex.sensors import Encoder

if TYPE_CHECKING:
    from jaxflex.model import Model


class Variant(AbstractEffect):
    """An effect under a suffixed name with suffixed parameters, so that several settings of one
    effect (e.g. Stribeck velocities) can sit side by side in one model."""

    inner: AbstractEffect
    suffix: str = eqx.field(static=True)

    @property
    def name(self) -> str:  # type: ignore[override]
        return f"{self.inner.name}{self.suffix}"

    @property
    def parameters(self) -> tuple[ParameterSpec, ...]:  # type: ignore[override]
        return tuple(
            dataclasses.replace(p, name=p.name + self.suffix) for p in self.inner.parameters
        )

    def _own(self, params: Params) -> Params:
        return {**params, **{p.name: params[p.name + self.suffix] for p in self.inner.parameters}}

    def structure(self, structure: Structure, params: Params) -> Structure:
        return self.inner.structure(structure, self._own(params))

    def friction(self, params: Params, velocity: Array, omega_s: float) -> Array:
        return self.inner.friction(self._own(params), velocity, omega_s)

    def loads(self, structure: Structure, params: Params) -> Array:
        return self.inner.loads(structure, self._own(params))

    def load_amplitudes(self, params: Params, angle: Array, velocity: Array) -> Array:
        return self.inner.load_amplitudes(self._own(params), angle, velocity)

    def input_torque(self, params: Params, torque: Array, h: float) -> Array:
        return self.inner.input_torque(self._own(params), torque, h)

    def signal_torque(self, params: Params, signal: Array, h: float) -> Array | None:
        return self.inner.signal_torque(self._own(params), signal, h)

    def readings(
        self, params: Params, readings: Mapping[str, Float[Array, "*batch n"]]
    ) -> dict[str, Float[Array, "*batch n"]]:
        return self.inner.readings(self._own(params), readings)


@dataclass(frozen=True)
class Candidate:
    """A candidate effect: one instance, or a profile of instances over a static setting."""

    name: str
    effects: tuple[AbstractEffect, ...]

    @property
    def parameters(self) -> tuple[ParameterSpec, ...]:
        return tuple(self.effects[0].parameters)

    def label(self, i: int) -> str:
        """The setting of profile member ``i``, '' for a single effect; a setting that is also a
        fitted parameter is where its fit started (``"v_s started at 0.1"``)."""
        if len(self.effects) == 1:
            return ""
        member = self.effects[i]
        fitted = {p.name for p in member.parameters}
        parts = []
        for f in dataclasses.fields(member):
            value = getattr(member, f.name)
            varies = len({repr(getattr(e, f.name)) for e in self.effects}) > 1
            if varies and f.name in fitted:
                parts.append(f"{f.name} started at {value:g}")
            elif varies and isinstance(value, (int, float, str)):
                parts.append(f"{f.name}={value:g}" if isinstance(value, float) else
                             f"{f.name}={value}")
        return ", ".join(parts)


def parameter_names(candidate: Candidate) -> tuple[str, ...]:
    """The parameter names of a candidate."""
    return tuple(p.name for p in candidate.parameters)


def as_candidate(item: str | AbstractEffect | Candidate) -> Candidate:
    """A candidate from a name (profiled if its class has ``grid()``), an effect or itself."""
    if isinstance(item, Candidate):
        cand = item
    elif isinstance(item, str):
        effect = get_effect(item)
        grid = getattr(type(effect), "grid", None)
        cand = Candidate(item, tuple(grid()) if callable(grid) else (effect,))
    elif isinstance(item, AbstractEffect):
        cand = Candidate(item.name, (item,))
    else:
        raise TypeError(f"a candidate must be an effect name or an effect, got "
                        f"{type(item).__name__}")
    if not cand.parameters:
        raise ValueError(f"candidate {cand.name!r} has no parameters to test")
    if all(spec.null is None for spec in cand.parameters):
        raise ValueError(
            f"candidate {cand.name!r} has no null value on any parameter (the value at which "
            "the effect vanishes); a score test needs one"
        )
    return cand


def encoder_channels(model: Model | None = None) -> tuple[str, ...]:
    """The channels an encoder reads: those of a rig's :class:`~jaxflex.sensors.Encoder`
    sensors; for a rig without sensors (or none given), ``joint_angle``, the reference
    testbed's encoder."""
    if model is None or not model.sensors:
        return ("joint_angle",)
    return tuple(s.channel for s in model.sensors if isinstance(s, Encoder))


def default_candidates(
    channels: Iterable[str] | None = None, model: Model | None = None
) -> list[str]:
    """The effects discovery tests unless told otherwise: every library effect, with a sensor's
    gain only on the fitted ``channels`` (all when ``None``) that an encoder does not read, no
    sensor offset and no drive gain. ``model`` is the rig whose sensors read the channels
    (:func:`encoder_channels`; ``None``: the reference testbed).

    An encoder's gain is known exactly: one count is ``2π/counts_per_revolution``. A gain on
    its channel is no calibration to find; it only rescales the angle, which mimics a missing
    inertia or load (on a hidden payload or a tilted plane it was added beside the right
    effect). Name ``sensor_gain:CHANNEL`` to test it anyway (a gearbox between the encoder
    and the joint whose ratio is in doubt). A sensor offset is left out because records start
    at rest and are read re-zeroed there (:mod:`jaxflex.measured`): a constant then only soaks
    up the mean of whatever the model misses (on a hidden payload it scored above the payload).
    Name ``sensor_offset:CHANNEL`` to test it on a record whose reading at rest is not zero. A
    drive gain is a constant of the rig's drive, identified when its arm file gives it bounds
    (:mod:`jaxflex.arm`), not a missing physical effect; name ``drive_gain`` to test one.
    """
    wanted = None if channels is None else set(channels)
    exact = {f"{SensorGain.key}:{c}" for c in encoder_channels(model)}
    names = [
        e.name
        for e in library()
        if not isinstance(e, (SensorOffset, DriveGain))
        and (wanted is None or getattr(e, "channel", None) in wanted | {None})
    ]
    own = [c for c in channels or () if c not in CALIBRATED_CHANNELS]  # a rig's sensor channels
    return [n for n in names + [f"{SensorGain.key}:{c}" for c in own] if n not in exact]


def candidate_set(
    candidates: Iterable[str | AbstractEffect | Candidate] | None = None,
    channels: Iterable[str] | None = None,
    model: Model | None = None,
) -> tuple[Candidate, ...]:
    """Candidates by name or instance; ``None``: :func:`default_candidates` for ``channels``
    of ``model`` (Stribeck profiled)."""
    if candidates is None:
        candidates = default_candidates(channels, model)
    elif isinstance(candidates, (str, AbstractEffect)):
        candidates = [candidates]
    result = tuple(as_candidate(c) for c in candidates)
    names = [c.name for c in result]
    if len(set(names)) != len(names):
        raise ValueError(f"a candidate appears twice: {names}")
    if not result:
        raise ValueError("no candidate effects given")
    return result


__all__ = [
    "Candidate",
    "candidate_set",
    "default_candidates",
    "encoder_channels",
]
