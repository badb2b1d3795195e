"""Sensors: each measured channel of a rig, with its output map, calibration and noise model.

A sensor reads one physical quantity of the simulated arm and reports it in the record's
channel as ``gain · quantity + offset`` (its calibration), with a noise model: a quantisation
step (encoders, digitisers) and a white-noise level. Link sensors sit at a position ``x`` along
the link, measured from the clamp; the model computes the deflection, curvature and acceleration
at those *stations* (:mod:`jaxflex.stations`) as linear maps of its modal state.

* :class:`Encoder` — joint angle, quantised to ``2π/counts_per_revolution``;
* :class:`Tachometer` — joint velocity;
* :class:`StrainGauge` at ``x`` — surface bending strain ``(h/2)·w''(x)``, or, calibrated as
  Quanser's is, the link deflection angle ``α = w(L)/L`` that a static tip load would give:
  ``α = L²/(3(L − x)) · w''(x)``;
* :class:`Accelerometer` at ``x`` — ``(r + x)·θ'' + ẅ(x)`` (``r`` the clamp offset);
* :class:`DeflectionSensor` at ``x`` — ``w(x)`` in the hub frame (a tip laser, a camera).

A rig (:class:`~jaxflex.model.Model`) holds its sensors; a simulation of it gives each sensor's
:meth:`~AbstractSensor.reading` under the sensor's channel name
(``outputs.channel("tip_acc")``). The reading is taken relative to rest, ``gain · quantity``: a
logged record is re-zeroed at rest
(:mod:`jaxflex.measured`), which removes the offset. A calibration that is not known is an effect
on the readings (``sensor_gain``, ``sensor_offset`` in :mod:`jaxflex.effects`), identified with
the physical parameters: :func:`calibrated` applies it to a simulation's outputs.
"""

from __future__ import annotations

import abc
import math
from collections.abc import Sequence
from typing import TYPE_CHECKING, ClassVar

import equinox as eqx
import numpy as np
from jaxtyping import Array, Float

from jaxflex.parameters import Params
from jaxflex.registry import Registry

if TYPE_CHECKING:
    from jaxflex.model import Model
    from jaxflex.simulation import Outputs


class AbstractSensor(eqx.Module):
    """One record channel: the quantity it responds to, its calibration (gain, offset) and
    noise model. Subclasses define :meth:`quantity`; register one of one's own with
    ``SENSORS.register`` to name it in arm files.

    ``resolution`` is the quantisation step of the logged values (0: none) and ``noise`` the
    standard deviation of white measurement noise, both in the channel's units. ``rezero``:
    a record is re-zeroed at rest, which removes any offset (the default); ``False``: the
    record keeps its zero and the reading less the stated ``offset`` is fitted (an unknown
    offset is then a ``sensor_offset`` effect to identify). ``unit`` is the physical
    quantity's unit; ``reading_unit`` the logged channel's (``"V"``, ``"counts"``) where the
    gain converts one to the other (default: the quantity's, gain 1 or a scale of it).
    """

    kind: ClassVar[str] = "sensor"
    unit: ClassVar[str] = ""
    channel: str = "sensor"
    gain: float = 1.0
    offset: float = 0.0
    noise: float = 0.0
    resolution: float = 0.0
    rezero: bool = True
    reading_unit: str = ""

    def __check_init__(self) -> None:
        if not isinstance(self.reading_unit, str):
            raise ValueError(f"{self.kind} {self.channel}: reading_unit={self.reading_unit!r} "
                             "must be a string (e.g. 'V')")
        if not isinstance(self.rezero, bool):
            raise ValueError(f"{self.kind} {self.channel}: rezero={self.rezero!r} must be "
                             "true or false")
        if not isinstance(self.channel, str) or not self.channel.isidentifier():
            raise ValueError(f"{self.kind}: channel {self.channel!r} must be an identifier")
        for name in ("gain", "offset", "noise", "resolution"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value)):
                raise ValueError(f"{self.kind} {self.channel}: {name}={value!r} must be a number")
        if self.gain == 0 or self.noise < 0 or self.resolution < 0:
            raise ValueError(
                f"{self.kind} {self.channel}: gain must be non-zero, noise and resolution >= 0"
            )

    @property
    def channel_unit(self) -> str:
        """The unit of the logged channel (and of its gain times the quantity)."""
        return self.reading_unit or self.unit

    @property
    def gain_unit(self) -> str:
        """The gain's unit: reading per quantity (``"1"`` where the two units are one)."""
        return "1" if not self.reading_unit else f"{self.reading_unit} per {self.unit}"

    @property
    def position(self) -> float | None:
        """Position along the link (m from the clamp), or None for a joint sensor."""
        return None

    def silent_at_clamp(self, clamp_offset: float) -> bool:
        """Whether a link sensor at ``x = 0`` reads zero whatever the motion, on a link clamped
        ``clamp_offset`` m from the joint axis (a gauge there reads the root strain)."""
        return False

    @abc.abstractmethod
    def quantity(self, model: Model, outputs: Outputs) -> Float[Array, "*batch n"]:
        """The physical quantity the sensor responds to, from a simulation of ``model``."""

    def reading(self, model: Model, outputs: Outputs) -> Float[Array, "*batch n"]:
        """The reading relative to rest, ``gain · quantity``, from a simulation of ``model``
        (a sensor at the tip or clamp reads the simulator's own output there)."""
        mapping = self.simulated_output(model)
        if mapping is not None:
            output, factor = mapping
            return self.gain * factor * getattr(outputs, output)
        return self.gain * self.quantity(model, outputs)

    def measure(self, model: Model, outputs: Outputs) -> Float[Array, "*batch n"]:
        """The noise-free reading as logged: ``gain · quantity + offset``."""
        return self.reading(model, outputs) + self.offset

    @property
    def noise_std(self) -> float:
        """Standard deviation of the reading's error: white noise and quantisation (q²/12)."""
        return math.sqrt(self.noise**2 + self.resolution**2 / 12.0)

    def observe(
        self, reading: Float[np.ndarray, " n"], rng: np.random.Generator
    ) -> Float[np.ndarray, " n"]:
        """A logged reading: white noise added, then quantised to the resolution."""
        value = np.asarray(reading, dtype=np.float64) + self.noise * rng.standard_normal(
            np.shape(reading)
        )
        return np.round(value / self.resolution) * self.resolution if self.resolution else value

    def simulated_output(self, model: Model) -> tuple[str, float] | None:
        """``(output, factor)`` when the reading is ``gain·factor·output + offset`` for one of
        the simulator's standard outputs (:data:`~jaxflex.simulation.OUTPUT_NAMES`), else None."""
        return None

    def _station(self, model: Model) -> int:
        if self.position not in model.stations:
            raise ValueError(
                f"{self.kind} {self.channel}: the model has no station at x = {self.position!r} "
                f"m (stations: {list(model.stations)}); give the model the sensor: "
                "Model(sensors=...)"
            )
        return model.stations.index(self.position)


ANGLE_UNITS: dict[str, float] = {"rad": 1.0, "mrad": 1e3, "deg": 180.0 / math.pi}
"""The angle units an encoder's channel may be declared in (``reading_unit``), per rad; and
``"counts"``, ``counts_per_revolution / 2π`` per rad."""


class Encoder(AbstractSensor):
    """Joint angle (rad) from an incremental encoder of ``counts_per_revolution``.

    Its resolution is one count, ``2π/counts_per_revolution``, unless given (0: ideal). A
    channel declared in another angle unit (``reading_unit``: ``"counts"``, ``"mrad"``,
    ``"deg"``, :data:`ANGLE_UNITS`) is converted: the gain becomes that unit per rad and the
    resolution one count in it (a gain given must be that one, to 0.1 %).
    """

    kind: ClassVar[str] = "encoder"
    unit: ClassVar[str] = "rad"
    channel: str = "joint_angle"
    counts_per_revolution: int = 4096
    resolution: float | None = None  # type: ignore[assignment]

    def __post_init__(self) -> None:
        if not (isinstance(self.counts_per_revolution, int) and self.counts_per_revolution > 0):
            raise ValueError(
                f"encoder {self.channel}: counts_per_revolution={self.counts_per_revolution!r} "
                "must be a positive whole number"
            )
        scale = self.angle_scale
        if self.resolution is None:
            object.__setattr__(self, "resolution",
                               2 * math.pi / self.counts_per_revolution * (scale or 1.0))
        if scale is None or math.isclose(self.gain, scale, rel_tol=1e-3):
            return  # nothing to convert, or converted by the gain given
        if self.gain != 1.0:
            raise ValueError(
                f"encoder {self.channel}: gain={self.gain!r} but reading_unit "
                f"{self.reading_unit!r} is {scale:.9g} per rad; leave the gain out"
            )
        object.__setattr__(self, "gain", scale)

    @property
    def angle_scale(self) -> float | None:
        """The declared reading unit per rad (None: no angle unit declared, or one that a
        gain converts, such as ``"V"``)."""
        if self.reading_unit == "counts":
            return self.counts_per_revolution / (2 * math.pi)
        return ANGLE_UNITS.get(self.reading_unit) if self.reading_unit != "rad" else None

    def quantity(self, model: Model, outputs: Outputs) -> Array:
        return outputs.joint_angle

    def simulated_output(self, model: Model) -> tuple[str, float]:
        return "joint_angle", 1.0


class Tachometer(AbstractSensor):
    """Joint velocity (rad/s)."""

    kind: ClassVar[str] = "tachometer"
    unit: ClassVar[str] = "rad/s"
    channel: str = "joint_velocity"

    def quantity(self, model: Model, outputs: Outputs) -> Array:
        return outputs.joint_velocity

    def simulated_output(self, model: Model) -> tuple[str, float]:
        return "joint_velocity", 1.0


class _LinkSensor(AbstractSensor):
    """A sensor on the link at ``x`` metres from the clamp."""

    x: float = 0.0

    def __check_init__(self) -> None:
        super().__check_init__()
        if not (isinstance(self.x, float) and math.isfinite(self.x) and self.x >= 0):
            raise ValueError(f"{self.kind} {self.channel}: x={self.x!r} must be a float >= 0 (m)")

    @property
    def position(self) -> float:
        return self.x


class StrainGauge(_LinkSensor):
    """Bending strain at the surface at ``x`` (``calibration="strain"``), or the link deflection
    angle (rad) that Quanser's calibration reports (``calibration="deflection_angle"``)."""

    kind: ClassVar[str] = "strain_gauge"
    channel: str = "strain"
    calibration: str = "strain"

    def __check_init__(self) -> None:
        super().__check_init__()
        if self.calibration not in ("strain", "deflection_angle"):
            raise ValueError(
                f"strain_gauge {self.channel}: calibration={self.calibration!r} must be "
                "'strain' or 'deflection_angle'"
            )

    @property
    def unit(self) -> str:  # type: ignore[override]
        return "rad" if self.calibration == "deflection_angle" else "m/m"

    def scale(self, model: Model) -> float:
        """Reading per unit curvature: ``h/2`` (strain) or ``L²/(3(L − x))`` (angle)."""
        tb = model.testbed
        if self.calibration == "strain":
            return 0.5 * tb.thickness
        if self.x >= tb.length:
            raise ValueError(f"strain_gauge {self.channel}: a gauge at the tip reads no strain")
        return tb.length**2 / (3.0 * (tb.length - self.x))

    def quantity(self, model: Model, outputs: Outputs) -> Array:
        k = self._station(model)
        return self.scale(model) * outputs.station_curvature[..., k]

    def simulated_output(self, model: Model) -> tuple[str, float] | None:
        if self.x != 0.0:
            return None
        return "root_strain", self.scale(model) / (0.5 * model.testbed.thickness)


class _StationSensor(_LinkSensor):
    """A link sensor that reads one station output as it is; at the tip that output is also one
    of the simulator's standard outputs."""

    station_output: ClassVar[str]
    tip_output: ClassVar[str]

    def quantity(self, model: Model, outputs: Outputs) -> Array:
        k = self._station(model)
        return getattr(outputs, self.station_output)[..., k]

    def simulated_output(self, model: Model) -> tuple[str, float] | None:
        return (self.tip_output, 1.0) if self.x == model.testbed.length else None


class Accelerometer(_StationSensor):
    """Transverse acceleration (m/s²) at ``x``: ``(r + x)·θ'' + ẅ(x)``."""

    kind: ClassVar[str] = "accelerometer"
    unit: ClassVar[str] = "m/s^2"
    channel: str = "acceleration"
    station_output: ClassVar[str] = "station_acceleration"
    tip_output: ClassVar[str] = "tip_acceleration"

    def silent_at_clamp(self, clamp_offset: float) -> bool:
        """On the joint axis (no clamp offset) the point does not move."""
        return clamp_offset == 0.0


class DeflectionSensor(_StationSensor):
    """Link deflection ``w(x)`` (m) in the frame that turns with the hub."""

    kind: ClassVar[str] = "deflection"
    unit: ClassVar[str] = "m"
    channel: str = "tip_deflection"
    station_output: ClassVar[str] = "station_deflection"
    tip_output: ClassVar[str] = "tip_deflection"

    def silent_at_clamp(self, clamp_offset: float) -> bool:
        """The clamp holds the link's root: no deflection there."""
        return True


SENSORS: Registry[AbstractSensor] = Registry(
    "sensor", AbstractSensor, key=lambda cls: cls.kind,
    classes=(Encoder, Tachometer, StrainGauge, Accelerometer, DeflectionSensor),
)
"""Sensor kind (its ``type`` in an arm file) → class."""


def calibrated(model: Model, params: Params, outputs: Outputs) -> Outputs:
    """``outputs`` after the model's effects on the readings (a sensor's gain or offset, see
    :meth:`~jaxflex.effects.AbstractEffect.readings`), on the simulator's outputs and the sensors'
    readings alike; the motion is what the solve gave."""
    from jaxflex.simulation import OUTPUT_NAMES

    own = dict(outputs.readings or {})
    standard = {name: getattr(outputs, name) for name in OUTPUT_NAMES}
    given = standard | own
    changed = model.readings(params, given)
    names = [n for n in OUTPUT_NAMES if changed[n] is not given[n]]
    if own and any(changed[c] is not own[c] for c in own):
        outputs = eqx.tree_at(lambda o: o.readings, outputs, {c: changed[c] for c in own})
    if not names:
        return outputs
    return eqx.tree_at(
        lambda o: [getattr(o, n) for n in names], outputs, [changed[n] for n in names]
    )


def readings(
    model: Model,
    outputs: Outputs,
    channels: Sequence[str] | None = None,
    params: Params | None = None,
) -> dict[str, Array]:
    """The rig's sensor readings relative to rest, by channel (all, or those in ``channels``:
    a record may hold any subset of the rig's sensors). With ``params`` the model's effects on
    the readings act too (:func:`calibrated`)."""
    changed = outputs if params is None else calibrated(model, params, outputs)
    own = changed.readings or {}
    return {c: own[c] for c in model.channels if channels is None or c in channels}
