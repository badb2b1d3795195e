"""An arm: everything that describes one rig, from an arm file or built in Python.

An arm file is TOML (read with the standard library's :mod:`tomllib`) in UTF-8; a file saved
with a byte-order mark, UTF-8 or UTF-16, is read as well, and other bytes are refused naming the
line::

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
    [[sensors]]               # see jaxflex.sensors; one table per measured channel
    type = "encoder"
    counts_per_revolution = 4096
    [[sensors]]
    type = "strain_gauge"
    x = 0.0                   # m from the clamp
    calibration = "deflection_angle"
    channel = "deflection_angle"
    gain = { reference = 1.0, lower = 0.5, upper = 2.0 }   # identified (a number: fixed)
    # reading_unit = "V"      # the logged channel's unit, where the gain converts to it

    [[effects]]               # optional: effects added to the base model, by name, with
    name = "payload"          # their settings (or effects = ["payload", ...])
    [[effects]]               # a torque at the hub written as a formula (jaxflex.effects.formula)
    type = "torque"
    name = "cogging"          # its name in fits and reports (default "torque")
    expression = "a*sin(8*theta) + b*omega"
    a = { reference = 0.0, lower = -0.05, upper = 0.05 }   # N m
    b = { reference = 0.0, lower = -0.01, upper = 0.01, unit = "N m s/rad" }

An arm file describes one :class:`~jaxflex.model.Model`, the one rig description every command
uses: :func:`load_arm` reads it (a path, or a packaged rig's name), :func:`arm_to_dict` and
:func:`arm_to_toml` write a model back, exactly (a fit file stores the same content). A rig
without ``[[sensors]]`` is fitted on the simulator's outputs, named as record columns
(``joint_angle``, ``tip_acceleration``, ...): the reference testbed's format.

A sensor's ``gain`` given as a table of ``reference``, ``lower`` and ``upper`` is identified:
the model holds a ``sensor_gain`` effect on the sensor's channel
(:mod:`jaxflex.effects.sensor_gain`). A sensor with ``rezero = false`` (its records keep their
zero) may give its ``offset`` as such a table: the model then holds a ``sensor_offset`` effect
that keeps the offset within those bounds. A command drive's ``torque_per_unit`` given as such a
table is identified the same way: the model holds a ``drive_gain`` effect
(:mod:`jaxflex.effects.drive_gain`). By default records are re-zeroed at rest
(:mod:`jaxflex.measured`), which removes any offset.

Any error (unknown key, missing value, wrong type, bounds that exclude the reference value) is
an :class:`ArmError` whose one-line message names the file and the key.
"""

from __future__ import annotations

import dataclasses
import difflib
import math
import os
import tomllib
from collections.abc import Iterable, Mapping
from typing import Any

from jaxflex._arguments import shown
from jaxflex.drives import DRIVES, AbstractDrive, CommandDrive
from jaxflex.effects import (
    EFFECTS,
    AbstractEffect,
    ChannelEffect,
    DriveGain,
    FormulaError,
    SensorGain,
    SensorOffset,
    get_effect,
)
from jaxflex.model import Model
from jaxflex.parameters import BASE_PARAMETERS, ParameterSpec
from jaxflex.sensors import SENSORS, AbstractSensor
from jaxflex.testbed import Testbed, link_fault

_BASE = {spec.name: spec for spec in BASE_PARAMETERS}
MAX_ELEMENTS = 1000
"""More beam elements than this is a typing error, not a model."""
MAX_SUBSTEPS = 64
"""More integrator steps per sample than this is a typing error (the default is 2)."""


class ArmError(ValueError):
    """An arm file or arm description is wrong; the message names the file and the key."""


def load_arm(path: str | os.PathLike) -> Model:
    """Read and check an arm file (see the module doc), or a packaged one by name
    (``load_arm("quanser_rotflex")``; :mod:`jaxflex.rigs`): the rig it describes."""
    from jaxflex.rigs import locate

    if not isinstance(path, (str, os.PathLike)):
        raise TypeError(f"load_arm: path must be a file path or a packaged rig's name, got "
                        f"{shown(path)}")
    path = locate(path)
    where = os.fspath(path)
    try:
        with open(path, "rb") as f:
            raw = f.read()
    except FileNotFoundError:
        raise ArmError(f"{where}: arm file not found") from None
    try:
        data = tomllib.loads(_arm_text(raw, where))
    except tomllib.TOMLDecodeError as err:
        raise ArmError(f"{where}: not valid TOML ({err})") from None
    return arm_from_dict(data, where)


_BOMS = ((b"\xef\xbb\xbf", "utf-8"), (b"\xff\xfe", "utf-16-le"), (b"\xfe\xff", "utf-16-be"))


def _arm_text(raw: bytes, where: str) -> str:
    """An arm file's text: UTF-8 with or without a byte-order mark, or UTF-16 with one; any
    other encoding is an ArmError naming the file, the line and the encoding."""
    encoding, skipped = "utf-8", 0
    for bom, name in _BOMS:
        if raw.startswith(bom):
            raw, encoding, skipped = raw[len(bom):], name, len(bom)
            break
    else:
        if raw[:2].count(0) == 1:  # an ASCII character and a zero byte: UTF-16, no mark
            raise ArmError(f"{where}: line 1: the file looks like UTF-16 without a byte-order "
                           "mark; save it as UTF-8")
    try:
        return raw.decode(encoding)
    except UnicodeDecodeError as err:
        line = raw[:err.start].count(b"\n" if encoding == "utf-8" else "\n".encode(encoding)) + 1
        name = "UTF-8" if encoding == "utf-8" else "UTF-16"
        guess = " (Latin-1 or Windows-1252?)" if encoding == "utf-8" else ""
        byte = f"byte {skipped + err.start} (0x{raw[err.start]:02x})"
        raise ArmError(f"{where}: line {line}: {byte} is not {name}{guess}; save the arm file "
                       "as UTF-8") from None


def arm_from_dict(data: Mapping[str, Any], where: str = "arm") -> Model:
    """The :class:`~jaxflex.model.Model` an arm file's parsed content describes; ``where``
    names it in errors."""
    top = _Table(data, where, "")
    link = top.table("link")
    length = link.number("length")
    width = link.number("width")
    thickness = link.number("thickness")
    density = _density(link, length, width * thickness)
    clamp_offset = link.number("clamp_offset", 0.0, minimum=0.0)
    link.done(known=_MASS_KEYS)
    simulation = top.table("simulation", required=False)
    n_elements = simulation.integer("n_elements", 10, maximum=MAX_ELEMENTS)
    n_substeps = simulation.integer("n_substeps", 2, maximum=MAX_SUBSTEPS)
    n_modes = (simulation.integer("n_modes", maximum=2 * n_elements)
               if "n_modes" in simulation.data else None)
    omega_s = simulation.number("friction_smoothing", Testbed.omega_s)
    simulation.done(known=("n_modes",))
    sampling = top.table("sampling", required=False)
    dt = sampling.number("dt", Testbed.dt)
    duration = sampling.number("duration", Testbed.duration)
    sampling.done()
    specs, fixed = _parameters(top.table("parameters"))
    modulus = next(spec for spec in specs if spec.name == "E")
    fault = link_fault(length=length, width=width, thickness=thickness, density=density,
                       n_elements=n_elements, clamp_offset=clamp_offset,
                       moduli=(modulus.lower, modulus.upper))
    if fault is not None:
        setting, why = fault
        if setting == "density":  # the mass key the file gives
            setting = next(k for k in _MASS_KEYS if k in link.data)
        raise ArmError(f"{where}: link.{setting}: {link.data[setting]!r} {_UNITS[setting]} "
                       f"{why}")
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
    drive, drive_gain = _drive(top.table("drive"))
    sensors, calibrations = _sensors(top, length, drive, clamp_offset)
    effects = _effects(top) + calibrations + drive_gain
    name = top.string("name")
    description = top.string("description", "")
    top.done()
    try:
        return Model(testbed, effects, n_substeps, base=specs, drive=drive, n_modes=n_modes,
                     sensors=sensors, fixed=fixed, name=name, description=description)
    except (TypeError, ValueError) as err:
        raise ArmError(f"{where}: {err}") from None


def _effects(top: _Table) -> tuple[AbstractEffect, ...]:
    """``effects``: names, or tables of ``name`` and the effect's settings."""
    entries = top._get("effects", [])
    if not isinstance(entries, list):
        raise top._wrong("effects", "a list of effect names or tables ([[effects]])", entries)
    effects = []
    for i, entry in enumerate(entries):
        at = f"{top.where}: effects[{i}]"
        if isinstance(entry, str):
            settings: dict[str, Any] = {"name": entry}
        elif isinstance(entry, Mapping):
            settings = dict(entry)
        else:
            raise ArmError(f"{at}: expected an effect name or table, got {_kind(entry)}")
        key = "type" if "type" in settings else "name"  # a declared effect: type and name
        name = settings.pop(key, None)
        if not isinstance(name, str):
            raise ArmError(f"{at}.{key}: expected the effect's {key} (a string), got {name!r}")
        declared = name in EFFECTS and EFFECTS.lookup(name).needs_declaration
        if key == "type" and name in EFFECTS and not declared:
            raise ArmError(f"{at}.type: {name!r} is a library effect: write name = {name!r}")
        try:
            effects.append(get_effect(name, **settings))
        except FormulaError as err:
            raise ArmError(f"{at}.{err}") from None
        except TypeError as err:
            raise ArmError(f"{at}: {name}: {err}") from None
        except ValueError as err:
            raise ArmError(f"{at}: {err}") from None
        taken = {p.name for e in effects[:-1] for p in e.parameters} | set(_BASE)
        for spec in effects[-1].parameters:
            if spec.name in taken:
                raise ArmError(f"{at}.{spec.name}: parameter name taken by a base parameter or "
                               "an earlier effect; name it otherwise")
    return tuple(effects)


def _gain_effect(
    where: str, sensor: AbstractSensor, bounds: tuple[float, float, float]
) -> SensorGain:
    """The ``sensor_gain`` effect that identifies a sensor's gain within its bounds (in the
    sensor's reading per quantity)."""
    reference, lower, upper = bounds
    try:
        return SensorGain(channel=sensor.channel, reference=reference, lower=lower, upper=upper,
                          gain_unit=sensor.gain_unit)
    except ValueError as err:
        raise ArmError(f"{where}: sensor {sensor.channel}: {err}") from None


def _offset_effect(where: str, channel: str, bounds: tuple[float, float, float]) -> SensorOffset:
    """The ``sensor_offset`` effect that identifies a sensor's offset beyond its stated one,
    within the stated bounds (symmetric ones as ``±bound``)."""
    reference, lower, upper = bounds
    above, below = upper - reference, reference - lower
    try:
        if math.isclose(above, below, rel_tol=1e-9):  # (as written in decimal)
            return SensorOffset(channel=channel, bound=max(above, below))
        return SensorOffset(channel=channel, bound=above, below=below)
    except ValueError as err:
        raise ArmError(f"{where}: sensor {channel}: {err}") from None


def arm_to_dict(model: Model) -> dict[str, Any]:
    """The arm-file content of ``model``, TOML- and JSON-able: :func:`arm_from_dict` gives the
    same model back, field for field (a fit file stores it so)."""
    tb = model.testbed
    fixed = set(model.fixed)
    data: dict[str, Any] = {"name": model.name}
    if model.description:
        data["description"] = model.description
    data["link"] = {"length": tb.length, "width": tb.width, "thickness": tb.thickness,
                    "density": tb.density, "clamp_offset": tb.clamp_offset}
    data["simulation"] = {"n_elements": tb.n_elements, "n_substeps": model.n_substeps,
                          "friction_smoothing": tb.omega_s}
    if model.n_modes is not None:
        data["simulation"]["n_modes"] = model.n_modes
    data["sampling"] = {"dt": tb.dt, "duration": tb.duration}
    data["parameters"] = {
        spec.name: {"reference": spec.reference, "lower": spec.lower, "upper": spec.upper}
        | ({"log_scale": spec.log_scale} if spec.log_scale != _BASE[spec.name].log_scale else {})
        | ({"fixed": True} if spec.name in fixed else {})
        for spec in model.base
    }
    data["drive"] = {"type": model.drive.name} | model.drive.settings()
    if model.sensors:
        data["sensors"] = [_sensor_dict(sensor) for sensor in model.sensors]
    if model.effects:
        data["effects"] = [_effect_dict(effect) for effect in model.effects]
    return data


def _sensor_dict(sensor: AbstractSensor) -> dict[str, Any]:
    return {"type": sensor.kind} | {
        f.name: getattr(sensor, f.name) for f in dataclasses.fields(sensor)
    }


def _effect_dict(effect: AbstractEffect) -> dict[str, Any]:
    if effect.needs_declaration:  # its type, then its declaration (name, formula, parameters)
        return {"type": type(effect).name} | effect.settings()  # type: ignore[attr-defined]
    own = ("channel",) if isinstance(effect, ChannelEffect) else ()
    return {"name": effect.name} | {  # None: a setting left at its default (TOML has no null)
        f.name: getattr(effect, f.name) for f in dataclasses.fields(effect)
        if f.name not in own and getattr(effect, f.name) is not None
    }


def arm_to_toml(model: Model) -> str:
    """``model`` as an arm file (TOML): :func:`load_arm` reads the same model back."""
    data = arm_to_dict(model)
    lines = [f"{key} = {_toml_value(data[key])}" for key in ("name", "description") if key in data]
    for table in ("link", "simulation", "sampling", "parameters", "drive"):
        lines += ["", f"[{table}]"]
        lines += [f"{k} = {_toml_value(v)}" for k, v in data[table].items()]
    for array in ("sensors", "effects"):
        for entry in data.get(array, []):
            lines += ["", f"[[{array}]]"]
            lines += [f"{k} = {_toml_value(v)}" for k, v in entry.items()]
    return "\n".join(lines) + "\n"


_TOML_ESCAPES = {chr(i): f"\\u{i:04x}" for i in (*range(0x20), 0x7F)} | {
    "\b": "\\b", "\t": "\\t", "\n": "\\n", "\f": "\\f", "\r": "\\r", '"': '\\"',
    "\\": "\\\\"}
"""A TOML basic string's escapes: the quote, the backslash and every control character."""


def _toml_value(value: Any) -> str:
    """One TOML value: strings, booleans, numbers (floats exactly, by ``repr``), inline tables."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        if not math.isfinite(value):
            raise ArmError(f"a rig value {value!r} is not finite: it has no arm-file form")
        return repr(value)
    if isinstance(value, str):
        return '"' + "".join(_TOML_ESCAPES.get(c, c) for c in value) + '"'
    if isinstance(value, Mapping):
        return "{ " + ", ".join(f"{k} = {_toml_value(v)}" for k, v in value.items()) + " }"
    raise ArmError(f"a rig value {value!r} ({type(value).__name__}) has no arm-file form")


def _density(link: _Table, length: float, area: float) -> float:
    """Density from exactly one of ``density``, ``mass_per_length`` or ``mass``."""
    given = [k for k in _MASS_KEYS if k in link.data]
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


def _drive(table: _Table) -> tuple[AbstractDrive, tuple[DriveGain, ...]]:
    """The drive named by ``type`` with its constants (all required), and the ``drive_gain``
    effect that identifies a command drive's torque per unit given with bounds."""
    kind = table.string("type")
    if kind not in DRIVES:
        raise ArmError(
            f"{table.where}: {table.key('type')}: unknown drive {kind!r}; drives: {sorted(DRIVES)}"
        )
    cls = DRIVES[kind]
    if cls is CommandDrive:
        return _command_drive(table)
    settings = {f.name: table.number(f.name) for f in dataclasses.fields(cls)}
    for name in getattr(cls, "EFFICIENCIES", ()):
        if settings[name] > 1:
            raise table._wrong(name, "a number in (0, 1] (an efficiency: power out over power "
                                     "in)", table.data[name])
    table.done()
    return cls(**settings), ()


def _command_drive(table: _Table) -> tuple[CommandDrive, tuple[DriveGain, ...]]:
    """A command drive: ``unit``, ``torque_per_unit`` (a table of bounds: identified) and an
    optional ``saturation``."""
    unit = table.string("unit")
    bounds = None
    if isinstance(table.data.get("torque_per_unit"), Mapping):
        entry = table.table("torque_per_unit")
        gain, *bounds = _bounded(entry)
        entry.done()
    else:
        gain = table.number("torque_per_unit")
    saturation = table.number("saturation") if "saturation" in table.data else None
    table.done(known=("saturation",))
    try:
        drive = CommandDrive(torque_per_unit=gain, saturation=saturation, unit=unit)
        if bounds is None:
            return drive, ()
        return drive, (DriveGain(reference=gain, lower=bounds[0], upper=bounds[1], unit=unit),)
    except ValueError as err:
        raise ArmError(f"{table.where}: {table.prefix[:-1]}: {err}") from None


def _sensors(
    top: _Table, length: float, drive: AbstractDrive, clamp_offset: float = 0.0
) -> tuple[tuple[AbstractSensor, ...], tuple[AbstractEffect, ...]]:
    """The ``[[sensors]]`` tables: ``type`` picks the class, the other keys are its fields; and
    the effects that identify each gain or offset given as a table of bounds. Each sensor logs
    its own channel, neither time nor the drive's input, and a link sensor states where it
    sits (:func:`_check_position`)."""
    entries = top._get("sensors", [])
    if not isinstance(entries, list):
        raise top._wrong("sensors", "an array of tables ([[sensors]])", entries)
    sensors: list[AbstractSensor] = []
    calibrations: list[AbstractEffect] = []
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
            bounds = _bounded(gain, signed=True)
            values["gain"] = bounds[0]
            gain.done()
        offset_bounds = None
        rezero = table.boolean("rezero", True)  # checked first: the offset's form depends on it
        if isinstance(table.data.get("offset"), Mapping):
            if rezero:
                raise ArmError(
                    f"{table.where}: {table.key('offset')}: an offset cannot be identified from "
                    "records re-zeroed at rest, which removes it; give a number, or set "
                    "rezero = false for records that keep their zero"
                )
            entry = table.table("offset")
            offset_bounds = _bounded(entry, signed=True)
            values["offset"] = offset_bounds[0]
            entry.done()
        for f in dataclasses.fields(SENSORS[kind]):
            if f.name not in table.data or f.name in values:
                continue
            if isinstance(f.default, str):
                values[f.name] = table.string(f.name)
            elif f.default is None or f.name in ("noise", "resolution", "x"):
                values[f.name] = table.number(f.name, minimum=0.0)
            elif isinstance(f.default, bool):
                values[f.name] = table.boolean(f.name)
            elif not isinstance(f.default, (int, float)):
                continue
            elif isinstance(f.default, int):
                values[f.name] = table.integer(f.name)
            elif f.name in ("gain", "offset"):
                values[f.name] = table.number(f.name, minimum=-math.inf)
            else:
                values[f.name] = table.number(f.name, minimum=0.0)
        table.done(known=["type", *(f.name for f in dataclasses.fields(SENSORS[kind]))])
        try:
            sensors.append(SENSORS[kind](**values))
        except ValueError as err:
            raise ArmError(f"{table.where}: sensors[{i}]: {err}") from None
        _check_position(table, sensors[-1], length, clamp_offset)
        _check_channel(table, sensors, drive)
        if bounds is not None:
            calibrations.append(_gain_effect(top.where, sensors[-1], bounds))
        if offset_bounds is not None:
            calibrations.append(_offset_effect(top.where, sensors[-1].channel, offset_bounds))
    return tuple(sensors), tuple(calibrations)


def _check_position(table: _Table, sensor: AbstractSensor, length: float,
                    clamp_offset: float) -> None:
    """A link sensor states its ``x``, on the link, and not at the clamp where it reads zero
    (:meth:`~jaxflex.sensors.AbstractSensor.silent_at_clamp`)."""
    if sensor.position is None:
        return
    key, what = f"{table.where}: {table.key('x')}", f"the {sensor.kind} {sensor.channel!r}"
    if "x" not in table.data:
        raise ArmError(f"{key}: missing value; {what} sits on the link: give its distance from "
                       "the clamp in m")
    if sensor.position > length:
        raise ArmError(f"{key}: {sensor.position!r} m lies beyond the link (length {length!r} m)")
    if sensor.position == 0.0 and sensor.silent_at_clamp(clamp_offset):
        raise ArmError(f"{key}: {what} at x = 0 sits at the clamp, where it reads zero; give "
                       "its distance from the clamp in m")


def _check_channel(table: _Table, sensors: list[AbstractSensor], drive: AbstractDrive) -> None:
    """The last of ``sensors`` (read from ``table``) logs a channel of its own: not one an
    earlier sensor logs, not time, not the drive's input."""
    channel = sensors[-1].channel
    key = f"{table.where}: {table.key('channel')}"
    for j, other in enumerate(sensors[:-1]):
        if other.channel == channel:
            raise ArmError(f"{key}: sensors[{j}] logs the channel {channel!r} too; each sensor "
                           "logs its own channel")
    if channel in ("time", drive.name):
        what = "time" if channel == "time" else f"the {drive.name} drive's input"
        raise ArmError(f"{key}: {channel!r} is {what}, not a reading; name the sensor's own "
                       "column")


_MISSING: Any = object()
_MASS_KEYS = ("density", "mass_per_length", "mass")
_UNITS = {"length": "m", "width": "m", "thickness": "m", "clamp_offset": "m",
          "density": "kg/m³", "mass_per_length": "kg/m", "mass": "kg"}


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

    def integer(self, name: str, default: Any = _MISSING, *, maximum: int | None = None) -> int:
        """A whole number >= 1 (and <= ``maximum``: a larger one is a typing error)."""
        value = self._get(name, default)
        if isinstance(value, bool) or not isinstance(value, int) or value < 1 or (
                maximum is not None and value > maximum):
            need = "a whole number >= 1" if maximum is None else f"a whole number in [1, {maximum}]"
            raise self._wrong(name, need, value)
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

    def done(self, known: Iterable[str] = ()) -> None:
        """Refuse the first key that nothing read (a misspelling, or a setting jaxflex lacks);
        ``known`` names the keys the table may hold besides those read (optional ones)."""
        keys = sorted(self.used | set(known))
        for name in self.data:
            if name not in self.used:
                close = difflib.get_close_matches(name, keys, n=1, cutoff=0.6)
                hint = f"; did you mean {close[0]!r}?" if close else ""
                listed = f"; known keys: {keys}" if not close else ""
                raise ArmError(f"{self.where}: {self.key(name)}: unknown key{hint}{listed}")


def _kind(value: Any) -> str:
    return {dict: "a table", list: "an array", str: "a string", bool: "a boolean"}.get(
        type(value), type(value).__name__
    )


__all__ = ["ArmError", "arm_from_dict", "arm_to_dict", "arm_to_toml", "load_arm"]
