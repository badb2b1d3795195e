"""Effects on one output channel after the solve: a sensor's calibration (gain, offset).

A rig's sensor reads ``gain · quantity + offset``; when the gain or offset the arm file states
is not the true one, the arm moves as before and only the reading changes. Such an effect is
built for one channel (``SensorGain(channel="root_strain")``, or by name
``get_effect("sensor_gain:root_strain")``), carries that channel in its name and its parameter's
name, and acts through the :meth:`~jaxflex.effects.AbstractEffect.readings` hook alone.
"""

from __future__ import annotations

import abc
import math
from typing import ClassVar

import equinox as eqx

from jaxflex.effects._base import AbstractEffect
from jaxflex.parameters import ParameterSpec
from jaxflex.records import KNOWN_UNITS

CHANNEL_UNITS: dict[str, str] = {
    name: KNOWN_UNITS[name]
    for name in (
        "joint_angle", "tip_acceleration", "joint_velocity", "tip_deflection", "root_strain",
        "joint_torque",
    )
}
"""Unit of each simulator output channel (:data:`jaxflex.simulation.OUTPUT_NAMES`)."""

CALIBRATED_CHANNELS: tuple[str, ...] = ("joint_angle", "tip_acceleration", "root_strain")
"""The channels rigs log (encoder, accelerometer, strain gauge): the library holds one channel
effect for each."""


class _Name:
    """``name``: the registry key on the class, ``key:channel`` on an instance."""

    def __get__(self, instance: ChannelEffect | None, owner: type[ChannelEffect]) -> str:
        return owner.key if instance is None else f"{owner.key}:{instance.channel}"


class _Parameters:
    """``parameters``: the instance's one spec (on the class, a default instance's)."""

    def __get__(self, instance: ChannelEffect | None, owner: type[ChannelEffect]):
        return ((owner() if instance is None else instance).spec(),)


class ChannelEffect(AbstractEffect):
    """Base of the effects that act on one output ``channel`` after the solve."""

    channel: str = eqx.field(static=True, default="root_strain")

    key: ClassVar[str] = "channel_effect"
    name = _Name()  # type: ignore[assignment]
    parameters = _Parameters()  # type: ignore[assignment]

    def __check_init__(self) -> None:
        if not (isinstance(self.channel, str) and self.channel.isidentifier()):
            raise ValueError(
                f"{self.key}: channel {self.channel!r} must name a simulator output or a "
                "sensor's channel (an identifier)"
            )
        for field in ("reference", "lower", "upper"):
            value = getattr(self, field, 0.0)
            if isinstance(value, bool) or not (
                isinstance(value, (int, float)) and math.isfinite(value)
            ):
                raise ValueError(f"{self.name}: {field}={value!r} must be a finite number")

    @property
    def unit(self) -> str:
        """The channel's unit where jaxflex knows it (a simulator output), else empty: a
        sensor's channel is in the sensor's own unit."""
        return CHANNEL_UNITS.get(self.channel, "")

    @abc.abstractmethod
    def spec(self) -> ParameterSpec:
        """The effect's one parameter."""
