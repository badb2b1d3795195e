"""A drive whose torque per unit of its input is not the one the arm file states: to identify."""

from __future__ import annotations

import math
from typing import ClassVar

import equinox as eqx
from jaxtyping import Array, Float

from jaxflex.effects._base import AbstractEffect
from jaxflex.effects._channel import _Parameters
from jaxflex.parameters import ParameterSpec, Params


class DriveGain(AbstractEffect):
    """Scales the drive's torque: ``τ ← (torque_per_unit / reference) · τ``.

    A rig that logs a raw command (PWM or DAC counts, :class:`~jaxflex.drives.CommandDrive`)
    rarely knows the torque per count: the amplifier's gain, the motor's torque constant and the
    gear all enter it. Left at a guess, the hub inertia and the viscous friction absorb the
    error. The drive turns the command into torque with ``reference`` (its stated torque per
    unit), so the parameter ``torque_per_unit`` is the true one in N m per command ``unit`` and
    the effect vanishes at ``reference``. The drive's back-EMF (a voltage drive's damping) is
    not scaled. A default instance (reference 1) makes the parameter the ratio of the true gain
    to the drive's.
    """

    reference: float = eqx.field(static=True, default=1.0)
    lower: float = eqx.field(static=True, default=0.5)
    upper: float = eqx.field(static=True, default=2.0)
    unit: str = eqx.field(static=True, default="1")

    name: ClassVar[str] = "drive_gain"
    parameters = _Parameters()  # type: ignore[assignment]
    description: ClassVar[str] = (
        "The drive's torque per unit of its logged input (a PWM or DAC command) differs from "
        "the arm file's: every torque the model applies is a fixed multiple of the true one. "
        "Scaling every inertia, stiffness and friction by the inverse factor would do the "
        "same, so only the link's mass, which the arm file states, tells it apart."
    )
    signature: ClassVar[str] = (
        "every channel's residual, to first order, a multiple of the arm's own response to the "
        "input (in phase with it at every frequency); held at a wrong value, the fitted hub "
        "inertia and viscous friction move by about the same factor; frequencies unchanged"
    )

    def __check_init__(self) -> None:
        for field in ("reference", "lower", "upper"):
            value = getattr(self, field)
            if isinstance(value, bool) or not (
                isinstance(value, (int, float)) and math.isfinite(value) and value > 0
            ):
                raise ValueError(f"{self.name}: {field}={value!r} must be a positive number")
        if not self.lower < self.upper or not self.lower <= self.reference <= self.upper:
            raise ValueError(
                f"{self.name}: bounds [{self.lower!r}, {self.upper!r}] must be increasing and "
                f"hold the reference torque per unit {self.reference!r}"
            )

    def spec(self) -> ParameterSpec:
        """The effect's one parameter: the drive's torque per unit (log-scaled)."""
        return ParameterSpec(
            "torque_per_unit",
            "N m" if self.unit == "1" else f"N m/{self.unit}",
            lower=self.lower,
            upper=self.upper,
            reference=self.reference,
            description="the drive's torque per unit of its logged input, at the joint",
            log_scale=True,
            null=self.reference,
        )

    def input_torque(self, params: Params, torque: Float[Array, " m"], h: float) -> Array:
        return torque * (params["torque_per_unit"] / self.reference)
