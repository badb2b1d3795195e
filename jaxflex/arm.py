"""An arm: everything that describes one rig, from an arm file or built in Python.

An arm file is TOML (read with the standard library's :mod:`tomllib`)::

    name = "reference"
    [link]                    # from the clamp to the tip
    length = 0.5              # m
    width = 0.025             # m
    thickness = 0.002         # m, in the plane of motion
    density = 2700.0          # kg/m³ — or mass_per_length (kg/m), or mass (kg)
    clamp_offset = 0.0        # m, joint axis to clamp (default 0)
    [simulation]              # optional, these are the defaults
    n_elements = 10
    n_substeps = 2
    friction_smoothing = 0.01 # rad/s, smooth-Coulomb velocity scale
    # n_modes = 8             # advance only the 8 lowest modes (default: every mode)
    [sampling]                # optional, these are the defaults
    dt = 1e-3
    duration = 2.0
    [parameters]              # every base parameter: identified within bounds, or fixed
    E = { reference = 5.7002e10, lower = 20e9, upper = 100e9 }
    b_v = { reference = 0.015, fixed = true }
    ...
    [drive]                   # see jaxflex.drives
    type = "voltage"
    resistance = 2.6
    ...
    # or a raw command (PWM, DAC counts) with an identified torque per unit:
    # type = "command"
    # unit = "counts"         # the command's unit, shown in reports
    # torque_per_unit = { reference = 0.002, lower = 0.001, upper = 0.004 }  # N m per count
    # saturation = 2047       # optional: the command is clipped to ±2047 counts
    [[sensors]]               # see jaxflex.sensors; one table per measured channel
    type = "encoder"
    counts_per_revolution = 4096
    [[sensors]]
    type = "strain_gauge"
    x = 0.0                   # m from the clamp
    calibration = "deflection_angle"
    channel = "deflection_angle"
    gain = { reference = 1.0, lower = 0.5, upper = 2.0 }   # identified (a number: fixed)

A sensor's ``gain`` given as a table of ``reference``, ``lower`` and ``upper`` is identified: the
records are read with the reference gain and the arm's model holds a ``sensor_gain`` effect on
the output the sensor is fitted as (:mod:`jaxflex.effects.sensor_gain`). An ``offset`` is always
fixed: records are re-zeroed at rest (:mod:`jaxflex.measured`), which removes any constant.
A command drive's ``torque_per_unit`` given as such a table is identified the same way: the
drive turns the command into torque with the reference value and the arm's model holds a
``drive_gain`` effect (:mod:`jaxflex.effects.drive_gain`).

Any error (unknown key, missing value, wrong type, bounds that exclude the reference value) is
an :class:`ArmError` whose one-line message names the file and the key.
"""

from __future__ import annotations

import dataclasses
import difflib
import math
import os
import tomllib
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from jaxflex.drives import DRIVES, CommandDrive, Drive, TorqueDrive
from jaxflex.effects import Effect, SensorGain, get_effect
from jaxflex.model import Model
from jaxflex.parameters import BASE_PARAMETERS, ParameterSpace, ParameterSpec, Params
from jaxflex.sensors import SENSORS, Sensor, stations
from jaxflex.testbed import Testbed

_BASE = {spec.name: spec for spec in BASE_PARAMETERS}


class ArmError(ValueError):
    """An arm file or arm description is wrong; the message names the file and the key."""


@dataclass(frozen=True)
class Arm:
    """One rig: link and settings (a :class:`Testbed`), base-parameter specs, drive, sensors.

    ``fixed`` names base parameters held at their reference value when identifying;
    ``identified_gains`` holds ``(channel, lower, upper)`` for each sensor whose gain is
    identified (its ``gain`` the reference); ``n_modes`` advances only that many of the lowest
    modes (:class:`~jaxflex.model.Model`). The defaults are exactly the reference testbed, so
    ``Arm().model()`` is ``Model()``.
    """

    testbed: Testbed = field(default_factory=Testbed)
    parameters: tuple[ParameterSpec, ...] = BASE_PARAMETERS
    fixed: tuple[str, ...] = ()
    drive: Drive = field(default_factory=TorqueDrive)
    sensors: tuple[Sensor, ...] = ()
    effects: tuple[str, ...] = ()
    identified_gains: tuple[tuple[str, float, float], ...] = ()
    n_substeps: int = 2
    n_modes: int | None = None
    name: str = "arm"
    description: str = ""
    source: str | None = None

    def __post_init__(self) -> None:
        names = [p.name for p in self.parameters]
        if names != list(_BASE):
            raise ArmError(f"arm {self.name!r}: parameters must be {list(_BASE)}, got {names}")
        unknown = sorted(set(self.fixed) - set(names))
        if unknown:
            raise ArmError(f"arm {self.name!r}: fixed parameter(s) {unknown} are not parameters")
        channels = [s.channel for s in self.sensors]
        if len(set(channels)) != len(channels):
            raise ArmError(f"arm {self.name!r}: two sensors log the same channel: {channels}")
        for s in self.sensors:
            if s.position is not None and s.position > self.testbed.length:
                raise ArmError(
                    f"arm {self.name!r}: sensor {s.channel} at x = {s.position!r} m lies beyond "
                    f"the link (length {self.testbed.length!r} m)"
                )
        for channel, lower, upper in self.identified_gains:
            if channel not in channels:
                raise ArmError(f"arm {self.name!r}: identified gain of {channel!r}, a channel "
                               f"no sensor logs; channels: {channels}")
            self.calibration(channel, lower, upper)  # checks it
        for spec in self.parameters:
            if not spec.lower <= spec.reference <= spec.upper:
                raise ArmError(
                    f"arm {self.name!r}: parameter {spec.name}: bounds [{spec.lower!r}, "
                    f"{spec.upper!r}] exclude the reference value {spec.reference!r}"
                )

    def calibration(self, channel: str, lower: float, upper: float) -> SensorGain:
        """The ``sensor_gain`` effect that identifies the gain of the sensor logging ``channel``
        within ``[lower, upper]``, on the output the sensor is fitted as."""
        sensor = self.sensor(channel)
        mapping = sensor.simulated_output(Model(self.testbed))
        if mapping is None:
            raise ArmError(
                f"arm {self.name!r}: sensor {channel} ({sensor.kind} at x = {sensor.position!r} "
                "m) has no standard output, so its gain cannot be identified"
            )
        try:
            return SensorGain(channel=mapping[0], reference=sensor.gain, lower=lower, upper=upper)
        except ValueError as err:
            raise ArmError(f"arm {self.name!r}: sensor {channel}: {err}") from None

    def model(self, *effects: Effect) -> Model:
        """The :class:`Model` of this arm (a station at each link sensor), with its own effects,
        its identified sensor gains and any ``effects`` given (an own effect that ``effects``
        names again is taken once, as given there: a fit's model holds the arm's own)."""
        own = tuple(get_effect(name) for name in self.effects) + tuple(
            self.calibration(*gain) for gain in self.identified_gains
        ) + self.drive.effects()
        given = {e.name for e in effects}
        return Model(
            self.testbed,
            tuple(e for e in own if e.name not in given) + effects,
            self.n_substeps,
            self.parameters,
            self.drive,
            stations(self.sensors),
            self.n_modes,
        )

    def sensor(self, channel: str) -> Sensor:
        """The sensor that logs ``channel``."""
        for s in self.sensors:
            if s.channel == channel:
                return s
        raise KeyError(
            f"arm {self.name!r} has no sensor logging {channel!r}; channels: "
            f"{[s.channel for s in self.sensors]}"
        )

    @property
    def space(self) -> ParameterSpace:
        """The base parameters with this arm's bounds and reference values."""
        return ParameterSpace(self.parameters)

    def reference_parameters(self) -> Params:
        """The arm's reference values of the base parameters."""
        return self.space.reference()

    @property
    def fixed_values(self) -> dict[str, float]:
        """Fixed parameters and their values, as ``identify(..., fixed=...)`` takes them."""
        return {s.name: s.reference for s in self.parameters if s.name in self.fixed}

    def replace(self, **changes: Any) -> Arm:
        """A copy with some fields changed (validated)."""
        return dataclasses.replace(self, **changes)


def load_arm(path: str | os.PathLike) -> Arm:
    """Read and check an arm file (see the module doc)."""
    where = os.fspath(path)
    try:
        with open(path, "rb") as f:
            data = tomllib.load(f)
    except FileNotFoundError:
        raise ArmError(f"{where}: arm file not found") from None
    except tomllib.TOMLDecodeError as err:
        raise ArmError(f"{where}: not valid TOML ({err})") from None
    return arm_from_dict(data, where)


def arm_from_dict(data: Mapping[str, Any], where: str = "arm") -> Arm:
    """An :class:`Arm` from the parsed content of an arm file; ``where`` names it in errors."""
    top = _Table(data, where, "")
    link = top.table("link")
    length = link.number("length")
    width = link.number("width")
    thickness = link.number("thickness")
    density = _density(link, length, width * thickness)
    clamp_offset = link.number("clamp_offset", 0.0, minimum=0.0)
    link.done()
    simulation = top.table("simulation", required=False)
    n_elements = simulation.integer("n_elements", 10)
    n_substeps = simulation.integer("n_substeps", 2)
    n_modes = simulation.integer("n_modes") if "n_modes" in simulation.data else None
    omega_s = simulation.number("friction_smoothing", Testbed.omega_s)
    simulation.done()
    sampling = top.table("sampling", required=False)
    dt = sampling.number("dt", Testbed.dt)
    duration = sampling.number("duration", Testbed.duration)
    sampling.done()
    testbed = Testbed(
        length=length,
        width=width,
        thickness=thickness,
        density=density,
        n_elements=n_elements,
        omega_s=omega_s,
        dt=dt,
        duration=duration,
        clamp_offset=clamp_offset,
    )
    specs, fixed = _parameters(top.table("parameters"))
    drive = _drive(top.table("drive"))
    sensors, gains = _sensors(top, length)
    effects = top.strings("effects", ())
    for i, name in enumerate(effects):
        try:
            get_effect(name)
        except ValueError as err:
            raise ArmError(f"{where}: effects[{i}]: {err}") from None
    arm = Arm(
        testbed=testbed,
        parameters=specs,
        fixed=fixed,
        drive=drive,
        sensors=sensors,
        effects=effects,
        identified_gains=gains,
        n_substeps=n_substeps,
        n_modes=n_modes,
        name=top.string("name"),
        description=top.string("description", ""),
        source=where,
    )
    top.done()
    return arm


def _density(link: _Table, length: float, area: float) -> float:
    """Density from exactly one of ``density``, ``mass_per_length`` or ``mass``."""
    given = [k for k in ("density", "mass_per_length", "mass") if k in link.data]
    if len(given) != 1:
        found = f"got {[link.key(k) for k in given]}" if given else "got none"
        raise ArmError(
            f"{link.where}: {link.key('density')}: give exactly one of density (kg/m³), "
            f"mass_per_length (kg/m) or mass (kg); {found}"
        )
    value = link.number(given[0])
    if given[0] == "density":
        return value
    return value / area if given[0] == "mass_per_length" else value / (area * length)


def _parameters(table: _Table) -> tuple[tuple[ParameterSpec, ...], tuple[str, ...]]:
    """Every base parameter's spec (bounds, reference, scale) and the names of fixed ones."""
    specs, fixed = [], []
    for name, base in _BASE.items():
        entry = table.table(name)
        is_fixed = entry.boolean("fixed", False)
        # a fixed parameter's bounds are not searched: the library's, widened to the value
        reference, lower, upper = _bounded(entry, widen=(base.lower, base.upper) if is_fixed
                                           else None)
        log_scale = entry.boolean("log_scale", base.log_scale)
        entry.done()
        specs.append(
            dataclasses.replace(
                base, lower=lower, upper=upper, reference=reference, log_scale=log_scale
            )
        )
        if is_fixed:
            fixed.append(name)
    table.done()
    return tuple(specs), tuple(fixed)


def _bounded(
    entry: _Table, *, widen: tuple[float, float] | None = None, signed: bool = False
) -> tuple[float, float, float]:
    """``(reference, lower, upper)`` of a table of them; missing bounds default to ``widen``
    widened to the reference (else they are required); ``signed`` allows values <= 0."""
    minimum = -math.inf if signed else None
    reference = entry.number("reference", minimum=minimum)
    lower, upper = (min(widen[0], reference), max(widen[1], reference)) if widen else (
        _MISSING, _MISSING)
    lower = entry.number("lower", lower, minimum=minimum)
    upper = entry.number("upper", upper, minimum=minimum)
    if not lower < upper:
        raise ArmError(
            f"{entry.where}: {entry.key('lower')}: lower bound {lower!r} must be below the "
            f"upper bound {upper!r}"
        )
    if not lower <= reference <= upper:
        raise ArmError(
            f"{entry.where}: {entry.prefix[:-1]}: bounds [{lower!r}, {upper!r}] exclude the "
            f"reference value {reference!r}"
        )
    return reference, lower, upper


def _drive(table: _Table) -> Drive:
    """The drive named by ``type`` with its constants (all required)."""
    kind = table.string("type")
    if kind not in DRIVES:
        raise ArmError(
            f"{table.where}: {table.key('type')}: unknown drive {kind!r}; drives: {sorted(DRIVES)}"
        )
    cls = DRIVES[kind]
    if cls is CommandDrive:
        return _command_drive(table)
    settings = {f.name: table.number(f.name) for f in dataclasses.fields(cls)}
    table.done()
    return cls(**settings)


def _command_drive(table: _Table) -> CommandDrive:
    """A command drive: ``unit``, ``torque_per_unit`` (a table of bounds: identified) and an
    optional ``saturation``."""
    unit = table.string("unit")
    identified = None
    if isinstance(table.data.get("torque_per_unit"), Mapping):
        entry = table.table("torque_per_unit")
        gain, *identified = _bounded(entry)
        entry.done()
    else:
        gain = table.number("torque_per_unit")
    saturation = table.number("saturation") if "saturation" in table.data else None
    table.done()
    try:
        return CommandDrive(torque_per_unit=gain, saturation=saturation, unit=unit,
                            identified=None if identified is None else tuple(identified))
    except ValueError as err:
        raise ArmError(f"{table.where}: {table.prefix[:-1]}: {err}") from None


def _sensors(
    top: _Table, length: float
) -> tuple[tuple[Sensor, ...], tuple[tuple[str, float, float], ...]]:
    """The ``[[sensors]]`` tables: ``type`` picks the class, the other keys are its fields; and
    ``(channel, lower, upper)`` of each gain given as a table (identified)."""
    entries = top._get("sensors", [])
    if not isinstance(entries, list):
        raise top._wrong("sensors", "an array of tables ([[sensors]])", entries)
    sensors, gains = [], []
    for i, entry in enumerate(entries):
        table = _Table(entry, top.where, f"sensors[{i}].")
        kind = table.string("type")
        if kind not in SENSORS:
            raise ArmError(
                f"{table.where}: {table.key('type')}: unknown sensor {kind!r}; sensors: "
                f"{sorted(SENSORS)}"
            )
        values: dict[str, Any] = {}
        bounds = None
        if isinstance(table.data.get("gain"), Mapping):
            gain = table.table("gain")
            values["gain"], *bounds = _bounded(gain, signed=True)
            gain.done()
        if isinstance(table.data.get("offset"), Mapping):
            raise ArmError(
                f"{table.where}: {table.key('offset')}: an offset cannot be identified (records "
                "are re-zeroed at rest, which removes it); give a number"
            )
        for f in dataclasses.fields(SENSORS[kind]):
            if f.name not in table.data or f.name in values:
                continue
            if isinstance(f.default, str):
                values[f.name] = table.string(f.name)
            elif f.default is None or f.name in ("noise", "resolution", "x"):
                values[f.name] = table.number(f.name, minimum=0.0)
            elif isinstance(f.default, bool) or not isinstance(f.default, (int, float)):
                continue
            elif isinstance(f.default, int):
                values[f.name] = table.integer(f.name)
            elif f.name in ("gain", "offset"):
                values[f.name] = table.number(f.name, minimum=-math.inf)
            else:
                values[f.name] = table.number(f.name, minimum=0.0)
        table.done()
        if values.get("x", 0.0) > length:
            raise ArmError(
                f"{table.where}: {table.key('x')}: {values['x']!r} m lies beyond the link "
                f"(length {length!r} m)"
            )
        try:
            sensors.append(SENSORS[kind](**values))
        except ValueError as err:
            raise ArmError(f"{table.where}: sensors[{i}]: {err}") from None
        if bounds is not None:
            gains.append((sensors[-1].channel, *bounds))
    return tuple(sensors), tuple(gains)


_MISSING: Any = object()


class _Table:
    """One TOML table being read: typed look-ups that name the file and key in every error."""

    def __init__(self, data: Any, where: str, prefix: str) -> None:
        if not isinstance(data, Mapping):
            raise ArmError(f"{where}: {prefix[:-1]}: expected a table, got {_kind(data)}")
        self.data, self.where, self.prefix = data, where, prefix
        self.used: set[str] = set()

    def key(self, name: str) -> str:
        return f"{self.prefix}{name}"

    def _get(self, name: str, default: Any) -> Any:
        self.used.add(name)
        if name in self.data:
            return self.data[name]
        if default is _MISSING:
            unused = [k for k in self.data if k not in self.used]
            close = difflib.get_close_matches(name, unused, n=1, cutoff=0.6)
            hint = f" (is {self.key(close[0])!r} a misspelling?)" if close else ""
            raise ArmError(f"{self.where}: {self.key(name)}: missing value{hint}")
        return default

    def _wrong(self, name: str, expected: str, value: Any) -> ArmError:
        return ArmError(
            f"{self.where}: {self.key(name)}: expected {expected}, got {value!r} ({_kind(value)})"
        )

    def number(
        self, name: str, default: Any = _MISSING, *, minimum: float | None = None
    ) -> float:
        """A finite number, positive (or ``>= minimum`` when given)."""
        value = self._get(name, default)
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise self._wrong(name, "a number", value)
        value = float(value)
        ok = value >= minimum if minimum is not None else value > 0
        if not (math.isfinite(value) and ok):
            need = f"a number >= {minimum!r}" if minimum is not None else "a positive number"
            raise self._wrong(name, need, value)
        return value

    def integer(self, name: str, default: Any = _MISSING) -> int:
        value = self._get(name, default)
        if isinstance(value, bool) or not isinstance(value, int) or value < 1:
            raise self._wrong(name, "a whole number >= 1", value)
        return value

    def boolean(self, name: str, default: Any = _MISSING) -> bool:
        value = self._get(name, default)
        if not isinstance(value, bool):
            raise self._wrong(name, "true or false", value)
        return value

    def string(self, name: str, default: Any = _MISSING) -> str:
        value = self._get(name, default)
        if not isinstance(value, str):
            raise self._wrong(name, "a string", value)
        return value

    def strings(self, name: str, default: Any = _MISSING) -> tuple[str, ...]:
        value = self._get(name, default)
        if not isinstance(value, (list, tuple)) or not all(isinstance(v, str) for v in value):
            raise self._wrong(name, "a list of strings", value)
        return tuple(value)

    def table(self, name: str, *, required: bool = True) -> _Table:
        value = self._get(name, _MISSING if required else {})
        return _Table(value, self.where, f"{self.prefix}{name}.")

    def done(self) -> None:
        """Refuse the first key that nothing read (a misspelling, or a setting jaxflex lacks)."""
        for name in self.data:
            if name not in self.used:
                close = difflib.get_close_matches(name, sorted(self.used), n=1, cutoff=0.6)
                hint = f"; did you mean {close[0]!r}?" if close else ""
                known = f"; known keys: {sorted(self.used)}" if not close else ""
                raise ArmError(f"{self.where}: {self.key(name)}: unknown key{hint}{known}")


def _kind(value: Any) -> str:
    return {dict: "a table", list: "an array", str: "a string", bool: "a boolean"}.get(
        type(value), type(value).__name__
    )


def reference_arm() -> Arm:
    """The reference testbed as an :class:`Arm` (what ``arms/reference.toml`` describes)."""
    return Arm(name="reference")


__all__ = ["Arm", "ArmError", "arm_from_dict", "load_arm", "reference_arm"]
