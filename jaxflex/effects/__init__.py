"""The library of physical effects a model can be extended with, and its registry.

Every module of this package (other than the private ones) defines effects; importing the
package collects each :class:`AbstractEffect` subclass with its own ``name`` into
:data:`EFFECTS`, so a new effect is one new file here and nothing else. Effects on one output
channel (a sensor's gain or offset, :mod:`jaxflex.effects._channel`) are named with their
channel: ``get_effect("sensor_gain:root_strain")``.
"""

from __future__ import annotations

import importlib
import inspect
import pkgutil

from jaxflex.effects._base import AbstractEffect, EffectError, Structure, joint_friction
from jaxflex.effects._channel import CALIBRATED_CHANNELS, ChannelEffect
from jaxflex.effects.delay import Delay
from jaxflex.effects.drive_gain import DriveGain
from jaxflex.effects.formula import FormulaError, FormulaTorque
from jaxflex.effects.gravity import Gravity
from jaxflex.effects.motor_lag import MotorLag
from jaxflex.effects.payload import Payload
from jaxflex.effects.root_compliance import RootCompliance
from jaxflex.effects.sensor_gain import SensorGain
from jaxflex.effects.sensor_offset import SensorOffset
from jaxflex.effects.stribeck import Stribeck
from jaxflex.effects.torque_offset import TorqueOffset
from jaxflex.registry import Registry


def _collect() -> list[type[AbstractEffect]]:
    """Effect classes defined in this package's public modules."""
    found = []
    for info in sorted(pkgutil.iter_modules(__path__), key=lambda m: m.name):
        if info.name.startswith("_"):
            continue
        module = importlib.import_module(f"{__name__}.{info.name}")
        found += [cls for _, cls in inspect.getmembers(module, inspect.isclass)
                  if issubclass(cls, AbstractEffect) and cls.__module__ == module.__name__]
    return found


def _effect_name(cls: type[AbstractEffect]) -> str:
    return cls.key if issubclass(cls, ChannelEffect) else cls.name


EFFECTS: Registry[AbstractEffect] = Registry(
    "effect", AbstractEffect, key=_effect_name, classes=_collect()
)
"""Effect name → class, for every effect in the library (and those registered)."""


def register_effect(cls: type[AbstractEffect]) -> type[AbstractEffect]:
    """Add a user-defined effect class to :data:`EFFECTS` under its ``name`` (also as a class
    decorator), so that arm files, fit files and discovery can name it like the library's own.
    """
    return EFFECTS.register(cls)


def get_effect(name: str, /, **kwargs) -> AbstractEffect:
    """An effect by name, built with ``kwargs`` (e.g. ``get_effect("payload", rotary=True)``);
    ``KEY:CHANNEL`` names a channel effect's channel (``get_effect("sensor_gain:root_strain")``).
    An effect that exists only as declared takes its rig-file table
    (``get_effect("torque", expression="a*theta", a={...})``)."""
    key, sep, channel = name.partition(":")
    if key not in EFFECTS:
        raise ValueError(f"unknown effect {name!r}; known effects: {sorted(EFFECTS)}")
    cls = EFFECTS.lookup(key)
    if cls.needs_declaration:  # built from its declaration: a formula and its parameters
        return cls.from_settings(kwargs)  # type: ignore[attr-defined]
    if sep:
        if not issubclass(cls, ChannelEffect):
            raise ValueError(f"effect {key!r} acts on no channel: name it {key!r}, not {name!r}")
        if kwargs.setdefault("channel", channel) != channel:
            raise ValueError(f"effect {name!r} given another channel, {kwargs['channel']!r}")
    return cls(**kwargs)


def library() -> tuple[AbstractEffect, ...]:
    """One default instance of every effect in the library (in name order); a channel effect
    once for each of :data:`~jaxflex.effects._channel.CALIBRATED_CHANNELS`; none of an effect
    that exists only as declared (a formula torque)."""
    return tuple(
        effect
        for _, cls in sorted(EFFECTS.items())
        if not cls.needs_declaration
        for effect in (
            [cls(channel=c) for c in CALIBRATED_CHANNELS]
            if issubclass(cls, ChannelEffect)
            else [cls()]
        )
    )


__all__ = [
    "CALIBRATED_CHANNELS",
    "EFFECTS",
    "ChannelEffect",
    "Delay",
    "DriveGain",
    "AbstractEffect",
    "EffectError",
    "FormulaError",
    "FormulaTorque",
    "Gravity",
    "MotorLag",
    "Payload",
    "RootCompliance",
    "SensorGain",
    "SensorOffset",
    "Stribeck",
    "Structure",
    "TorqueOffset",
    "get_effect",
    "joint_friction",
    "library",
    "register_effect",
]
