"""A constant torque bias at the joint: an amplifier or D/A offset, a cable's pull."""

from __future__ import annotations

from typing import ClassVar

from jaxtyping import Array, Float

from jaxflex.effects._base import AbstractEffect
from jaxflex.parameters import ParameterSpec, Params


class TorqueOffset(AbstractEffect):
    """Adds a constant ``tau_0`` to the torque the drive applies: ``τ ← τ + tau_0``.

    With a voltage or current drive the offset is in N m at the joint, so a voltage offset
    ``V_0`` of a DC-motor drive shows as ``tau_0 = gain·V_0``. Its sign is free (bounds on both
    sides of the null 0).
    """

    name: ClassVar[str] = "torque_offset"
    parameters: ClassVar[tuple[ParameterSpec, ...]] = (
        ParameterSpec(
            "tau_0",
            "N m",
            lower=-0.05,
            upper=0.05,
            reference=0.01,
            description="constant torque bias at the joint",
            log_scale=False,
            null=0.0,
        ),
    )
    description: ClassVar[str] = (
        "The joint feels a constant torque besides the commanded one: an offset in the "
        "amplifier, the D/A converter or the current sensor, or a cable pulling the hub. It "
        "acts in both directions of motion alike, so friction (which opposes the motion) "
        "cannot absorb it."
    )
    signature: ClassVar[str] = (
        "joint-angle residual drifting one way whatever the direction of motion: moves in one "
        "direction overshoot and the other fall short by the same amount; independent of the "
        "angle (unlike gravity, which follows cos θ); frequencies unchanged"
    )

    def input_torque(self, params: Params, torque: Float[Array, " m"], h: float) -> Array:
        return torque + params["tau_0"]
