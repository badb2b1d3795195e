"""A sensor whose gain is not the one the arm file states: a calibration factor to identify."""

from __future__ import annotations

from collections.abc import Mapping
from typing import ClassVar

import equinox as eqx
from jaxtyping import Array

from jaxflex.effects._channel import ChannelEffect
from jaxflex.parameters import ParameterSpec, Params


class SensorGain(ChannelEffect):
    """Scales one output channel: ``y ← (gain_<channel> / reference) · y``.

    A sensor's gain comes from a calibration (a gauge factor and bridge gain, an accelerometer's
    sensitivity, a vendor's factor to a deflection angle, an encoder's counts) and, for a link
    sensor, from where it sits; it is often known to ±20 %, or not at all. The records are read
    with the gain ``reference`` (1: the arm file's own), so the parameter ``gain_<channel>`` is
    the true gain in the same units and the effect vanishes at ``reference``. The motion is
    untouched; only the reading is scaled. The sign is free when ``lower`` is not positive (a
    sensor mounted the other way round).
    """

    reference: float = eqx.field(static=True, default=1.0)
    lower: float = eqx.field(static=True, default=0.5)
    upper: float = eqx.field(static=True, default=2.0)
    gain_unit: str = eqx.field(static=True, default="1")  # reading per quantity: "V per m/s^2"

    key: ClassVar[str] = "sensor_gain"
    description: ClassVar[str] = (
        "A sensor reads a fixed multiple of the quantity the model gives for it: its "
        "calibration factor (gauge factor, sensitivity, vendor's conversion), or its position "
        "on the link, is not what the arm file says. The arm moves as before; only that "
        "channel's reading is scaled."
    )
    signature: ClassVar[str] = (
        "one channel's residual proportional to that channel itself (same shape and phase, "
        "every frequency alike), every other channel's residual unchanged; frequencies "
        "unchanged"
    )

    def __check_init__(self) -> None:
        super().__check_init__()
        if self.reference == 0 or not self.lower <= self.reference <= self.upper:
            raise ValueError(
                f"{self.name}: reference gain {self.reference!r} must be non-zero and lie in "
                f"[{self.lower!r}, {self.upper!r}]"
            )

    def spec(self) -> ParameterSpec:
        return ParameterSpec(
            f"gain_{self.channel}",
            self.gain_unit,
            lower=self.lower,
            upper=self.upper,
            reference=self.reference,
            description=f"gain of the {self.channel} sensor, in units of the gain it was read with",
            log_scale=self.lower > 0,
            null=self.reference,
        )

    def readings(self, params: Params, readings: Mapping[str, Array]) -> dict[str, Array]:
        out = dict(readings)
        if self.channel in out:
            ratio = params[f"gain_{self.channel}"] / self.reference
            out[self.channel] = out[self.channel] * ratio
        return out
