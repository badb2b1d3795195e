"""A constant offset on one sensor channel: a bias the arm file does not remove."""

from __future__ import annotations

from collections.abc import Mapping
from typing import ClassVar

import equinox as eqx
from jaxtyping import Array

from jaxflex.effects._channel import ChannelEffect
from jaxflex.parameters import ParameterSpec, Params

DEFAULT_BOUNDS: dict[str, float] = {
    "joint_angle": 0.05,
    "tip_acceleration": 0.5,
    "joint_velocity": 0.1,
    "tip_deflection": 0.005,
    "root_strain": 1e-4,
    "joint_torque": 0.05,
}
"""Default ``±bound`` of each channel's offset, in its unit (rad, m/s², rad/s, m, 1, N m)."""


class SensorOffset(ChannelEffect):
    """Adds a constant to one output channel: ``y ← y + offset_<channel>`` (either sign).

    A record read through an arm file is re-zeroed at rest (:mod:`jaxflex.measured`), which
    removes any constant offset there; this effect is for records that keep their zero (an
    accelerometer's bias, an encoder zeroed at another pose, a bridge's drift).
    """

    bound: float = eqx.field(static=True, default=0.0)  # 0: the channel's DEFAULT_BOUNDS
    below: float | None = eqx.field(static=True, default=None)
    """The largest offset below zero when it differs from the largest above (``bound``, then
    taken as it is, 0 included): an arm file's offset bounds that are not symmetric about the
    stated offset. None: ``±bound``."""

    key: ClassVar[str] = "sensor_offset"
    description: ClassVar[str] = (
        "A sensor reads a constant besides the quantity the model gives for it: an amplifier "
        "or bridge bias, an accelerometer's zero-g offset, an encoder zeroed at another pose. "
        "The arm moves as before; only that channel's reading is shifted."
    )
    signature: ClassVar[str] = (
        "one channel's residual a constant for the whole record, at rest as in motion, every "
        "other channel's residual unchanged; unlike a torque offset it does not drift"
    )

    def __check_init__(self) -> None:
        super().__check_init__()
        if not (isinstance(self.bound, (int, float)) and self.bound >= 0):
            raise ValueError(f"{self.name}: bound={self.bound!r} must be a number >= 0")
        if self.below is not None:
            if not (isinstance(self.below, (int, float)) and self.below >= 0
                    and self.below + self.bound > 0):
                raise ValueError(f"{self.name}: below={self.below!r} must be a number >= 0, "
                                 "and with bound a range of some width")
        elif not self.bound and self.channel not in DEFAULT_BOUNDS:
            raise ValueError(f"{self.name}: give its bound (the largest offset, in the "
                             f"channel's unit): {self.channel!r} has no default")

    def spec(self) -> ParameterSpec:
        if self.below is None:
            upper = self.bound or DEFAULT_BOUNDS[self.channel]
            lower, reference = -upper, 0.2 * upper
        else:
            upper, lower = float(self.bound), -float(self.below)
            reference = 0.2 * (upper if upper >= -lower else lower)  # on the wider side
        return ParameterSpec(
            f"offset_{self.channel}",
            self.unit,
            lower=lower,
            upper=upper,
            reference=reference,
            description=f"constant offset of the {self.channel} sensor",
            log_scale=False,
            null=0.0,
        )

    def readings(self, params: Params, readings: Mapping[str, Array]) -> dict[str, Array]:
        out = dict(readings)
        if self.channel in out:
            out[self.channel] = out[self.channel] + params[f"offset_{self.channel}"]
        return out
