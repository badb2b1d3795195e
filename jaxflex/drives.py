"""Drives: how the logged input signal becomes the torque on the hub.

A drive reads one record column (named after the drive) and acts on the model in two ways:
the signal is scaled into a torque, and a drive with back-EMF adds a viscous torque that opposes
the joint velocity. Three drives cover the rigs in the lab:

* :class:`TorqueDrive` — the input *is* the joint torque (N m): the reference testbed;
* :class:`CurrentDrive` — a current-mode amplifier, ``τ = k_i·i`` (``k_i`` in N m/A, gear
  ratio and efficiency included);
* :class:`VoltageDrive` — a DC motor and gearbox driven by a voltage,
  ``τ = K_g η_g η_m k_t (V − K_g k_m θ')/R_m``. This is exactly a torque drive with input
  ``g·V`` plus a viscous friction ``g·K_g·k_m·θ'`` (``g = K_g η_g η_m k_t/R_m``), and it is
  implemented so: the back-EMF is the drive's :attr:`~AbstractDrive.damping`;
* :class:`CommandDrive` — a raw command in the rig's own unit (PWM or DAC counts),
  ``τ = torque_per_unit · clip(u, ±saturation)``: the clip is applied to the logged command,
  as the amplifier saturates. The torque per unit is often not known; given with bounds in an
  arm file it is identified: the rig then holds a ``drive_gain`` effect
  (:mod:`jaxflex.effects.drive_gain`).
"""

from __future__ import annotations

import abc
import dataclasses
import math
from typing import ClassVar

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array, Float

from jaxflex.registry import Registry


class AbstractDrive(eqx.Module):
    """What turns a record's input column into hub torque: ``τ = gain·signal − damping·θ'``.

    Subclasses define :attr:`gain` (and :attr:`damping` where the drive adds one); ``name`` is
    the drive's key in an arm file and also the record column it reads. Register a drive of
    one's own with ``DRIVES.register`` to name it in arm files.
    """

    name: ClassVar[str] = "drive"
    unit: ClassVar[str] = ""

    @property
    @abc.abstractmethod
    def gain(self) -> float:
        """Torque per unit of the input signal (N m per unit)."""

    @property
    def damping(self) -> float:
        """Viscous torque per unit joint velocity that the drive adds (N m s/rad)."""
        return 0.0

    def torque(self, signal: Float[Array, " n"]) -> Float[Array, " n"]:
        """The torque the input signal applies before the drive's damping."""
        return self.gain * signal

    def settings(self) -> dict[str, float | str]:
        """The drive's constants by name (for arm files and reports)."""
        return {f.name: getattr(self, f.name) for f in dataclasses.fields(self)}


def _positive(drive: AbstractDrive) -> None:
    for name, value in drive.settings().items():
        if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
            raise ValueError(f"{drive.name} drive: {name}={value!r} must be a positive number")


class TorqueDrive(AbstractDrive):
    """The input is the hub torque itself (N m)."""

    name: ClassVar[str] = "torque"
    unit: ClassVar[str] = "N m"

    @property
    def gain(self) -> float:
        return 1.0

    def torque(self, signal: Float[Array, " n"]) -> Float[Array, " n"]:
        return signal


class CurrentDrive(AbstractDrive):
    """A current-mode amplifier: ``τ = torque_per_amp · i``."""

    name: ClassVar[str] = "current"
    unit: ClassVar[str] = "A"
    torque_per_amp: float = 1.0  # N m/A at the joint (gear ratio and efficiency included)

    def __check_init__(self) -> None:
        _positive(self)

    @property
    def gain(self) -> float:
        return self.torque_per_amp


class VoltageDrive(AbstractDrive):
    """A DC motor and gearbox: ``τ = K_g η_g η_m k_t (V − K_g k_m θ')/R_m``."""

    name: ClassVar[str] = "voltage"
    unit: ClassVar[str] = "V"
    resistance: float = 1.0  # R_m, Ω
    torque_constant: float = 1.0  # k_t, N m/A
    back_emf_constant: float = 1.0  # k_m, V s/rad
    gear_ratio: float = 1.0  # K_g
    gearbox_efficiency: float = 1.0  # η_g
    motor_efficiency: float = 1.0  # η_m

    EFFICIENCIES: ClassVar[tuple[str, ...]] = ("gearbox_efficiency", "motor_efficiency")
    """The settings that are efficiencies: power out over power in, in (0, 1]."""

    def __check_init__(self) -> None:
        _positive(self)
        for name in self.EFFICIENCIES:
            if getattr(self, name) > 1:
                raise ValueError(f"{self.name} drive: {name}={getattr(self, name)!r} must be "
                                 "at most 1 (an efficiency: power out over power in)")

    @property
    def gain(self) -> float:
        """``K_g η_g η_m k_t / R_m`` (N m/V)."""
        return (
            self.gear_ratio
            * self.gearbox_efficiency
            * self.motor_efficiency
            * self.torque_constant
            / self.resistance
        )

    @property
    def damping(self) -> float:
        """The back-EMF as viscous friction, ``gain·K_g·k_m`` (N m s/rad)."""
        return self.gain * self.gear_ratio * self.back_emf_constant


class CommandDrive(AbstractDrive):
    """A raw command (PWM or DAC counts): ``τ = torque_per_unit · clip(u, ±saturation)``.

    ``unit`` is the command's unit as the rig logs it (``"counts"``), shown in reports;
    ``torque_per_unit`` is in N m per that unit at the joint. ``saturation`` (command units;
    ``None``: none) clips the *logged command* before it becomes torque, as an amplifier that
    cannot give more does. To identify the torque per unit, the rig holds a ``drive_gain``
    effect whose reference is ``torque_per_unit``.
    """

    name: ClassVar[str] = "command"
    torque_per_unit: float = 1.0  # N m per command unit at the joint
    saturation: float | None = None  # command units, symmetric
    unit: str = eqx.field(static=True, default="1")  # type: ignore[assignment]

    def __check_init__(self) -> None:
        for key in ("torque_per_unit", "saturation"):
            value = getattr(self, key)
            if key == "saturation" and value is None:
                continue
            if isinstance(value, bool) or not (
                isinstance(value, (int, float)) and math.isfinite(value) and value > 0
            ):
                raise ValueError(f"command drive: {key}={value!r} must be a positive number")
        if not isinstance(self.unit, str) or not self.unit.strip():
            raise ValueError(
                f"command drive: unit={self.unit!r} must name the command's unit, e.g. 'counts'"
            )

    @property
    def gain(self) -> float:
        return self.torque_per_unit

    def torque(self, signal: Float[Array, " n"]) -> Float[Array, " n"]:
        if self.saturation is not None:
            signal = jnp.clip(signal, -self.saturation, self.saturation)
        return self.torque_per_unit * signal

    def settings(self) -> dict[str, float | str]:
        """The unit, the torque per unit (the reference of a ``drive_gain``) and any saturation."""
        values = {"unit": self.unit, "torque_per_unit": self.torque_per_unit}
        return values | ({} if self.saturation is None else {"saturation": self.saturation})


DRIVES: Registry[AbstractDrive] = Registry(
    "drive", AbstractDrive, key=lambda cls: cls.name,
    classes=(TorqueDrive, CurrentDrive, VoltageDrive, CommandDrive),
)
"""Drive name (the record column it reads) → class."""


def get_drive(name: str, **settings: float) -> AbstractDrive:
    """A drive by name with its constants, e.g. ``get_drive("current", torque_per_amp=8.925)``."""
    return DRIVES.create(name, **settings)
