"""The rig-file reference (``docs/rig-file.md``), generated from the reader itself.

:func:`read_keys` reads :data:`EXAMPLE`, an arm file that holds every key, through
:func:`jaxflex.arm.arm_from_dict` while watching each look-up of its tables: which key, what
kind of value, its default (none: required) and its limits. The drives' and sensors' keys are
their classes' fields (:data:`jaxflex.drives.DRIVES`, :data:`jaxflex.sensors.SENSORS`), the
parameters' units and reference bounds :data:`jaxflex.parameters.BASE_PARAMETERS`, the drive
constants' units the comments beside their fields. What no code states (a key's unit and what
it means) is in :data:`NOTES`: the tests refuse a key the reader reads that the notes do not
describe, and a note on a key the reader no longer reads, so the page cannot drift.
"""

from __future__ import annotations

import dataclasses
import inspect
import io
import tokenize
from collections.abc import Callable
from contextlib import contextmanager
from typing import Any

from jaxflex import arm
from jaxflex.drives import DRIVES, CommandDrive
from jaxflex.parameters import BASE_PARAMETERS
from jaxflex.sensors import SENSORS

EXAMPLE_SENSORS: dict[str, dict[str, Any]] = {
    "encoder": {"channel": "angle", "counts_per_revolution": 2048, "gain": 1.0,
                "offset": 0.0, "noise": 0.0, "resolution": 0.0030679615757712823,
                "rezero": True, "reading_unit": ""},
    "tachometer": {"channel": "speed", "gain": 0.5, "offset": 0.0, "noise": 0.02,
                   "resolution": 0.0, "rezero": True, "reading_unit": "V"},
    "strain_gauge": {"channel": "strain", "x": 0.05, "calibration": "strain",
                     "gain": {"reference": 1.0, "lower": 0.5, "upper": 2.0}, "offset": 0.0,
                     "noise": 2e-6, "resolution": 0.0, "rezero": True, "reading_unit": ""},
    "accelerometer": {"channel": "acc_mid", "x": 0.4, "gain": 1.0,
                      "offset": {"reference": 0.1, "lower": -0.4, "upper": 0.6},
                      "noise": 0.05, "resolution": 0.0, "rezero": False, "reading_unit": ""},
    "deflection": {"channel": "laser", "x": 0.45, "gain": 1000.0, "offset": 0.0,
                   "noise": 0.0, "resolution": 0.01, "rezero": True, "reading_unit": "mm"},
}
"""One sensor of each type with every key it takes (example values, read by the reader)."""

EXAMPLE_DRIVES: dict[str, dict[str, Any]] = {
    "torque": {},
    "current": {"torque_per_amp": 0.12},
    "voltage": {"resistance": 2.6, "torque_constant": 7.68e-3, "back_emf_constant": 7.68e-3,
                "gear_ratio": 70.0, "gearbox_efficiency": 0.9, "motor_efficiency": 0.69},
    "command": {"unit": "counts", "torque_per_unit": {"reference": 0.002, "lower": 0.001,
                                                      "upper": 0.004}, "saturation": 2047.0},
}
"""One drive of each type with every key it takes."""


def example(drive: str = "voltage") -> dict[str, Any]:
    """An arm file (as parsed TOML) with every key, the drive of type ``drive``."""
    return {
        "name": "strip_rig",
        "description": "0.5 m aluminium strip on a geared DC motor",
        "link": {"length": 0.5, "width": 0.025, "thickness": 0.002, "density": 2700.0,
                 "clamp_offset": 0.01},
        "simulation": {"n_elements": 10, "n_substeps": 2, "friction_smoothing": 0.01,
                       "n_modes": 8},
        "sampling": {"dt": 1e-3, "duration": 2.0},
        "parameters": {spec.name: {"reference": spec.reference, "lower": spec.lower,
                                   "upper": spec.upper, "fixed": False,
                                   "log_scale": spec.log_scale} for spec in BASE_PARAMETERS},
        "drive": {"type": drive, **EXAMPLE_DRIVES[drive]},
        "sensors": [{"type": kind, **keys} for kind, keys in EXAMPLE_SENSORS.items()],
        "effects": [{"name": "payload"},
                    {"type": "torque", "name": "cogging", "expression": "a*sin(8*theta)",
                     "a": {"reference": 0.0, "lower": -0.05, "upper": 0.05}}],
    }


NOTES: dict[str, tuple[str, str]] = {
    "name": ("", "the rig's name, shown in reports and stored in fits"),
    "description": ("", "one line on the rig"),
    "effects": ("", "effects added to the base model: names, or `[[effects]]` tables of "
                    "`name` and the effect's settings, or of `type = \"torque\"`, a `name`, an "
                    "`expression` and its parameters' bounds: a torque written as a formula "
                    "([effects](effects.md#a-torque-written-as-a-formula))"),
    "link": ("", "the flexible link, from the clamp to the tip"),
    "link.length": ("m", "clamp to tip"),
    "link.width": ("m", "across the plane of motion"),
    "link.thickness": ("m", "in the plane of motion"),
    "link.density": ("kg/m³", "give exactly one of `density`, `mass_per_length` or `mass`"),
    "link.mass_per_length": ("kg/m", "instead of `density`"),
    "link.mass": ("kg", "the link's mass, instead of `density`"),
    "link.clamp_offset": ("m", "joint axis to clamp"),
    "simulation": ("", "optional"),
    "simulation.n_elements": ("", "beam elements of the link"),
    "simulation.n_substeps": ("", "integrator steps per sample interval"),
    "simulation.friction_smoothing": ("rad/s", "velocity scale of the smooth Coulomb friction"),
    "simulation.n_modes": ("", "advance only this many lowest modes, at most 2 × "
                               "`n_elements` (default: every mode)"),
    "sampling": ("", "optional: the records' sampling"),
    "sampling.dt": ("s", "sample interval"),
    "sampling.duration": ("s", "record length of simulated inputs"),
    "parameters": ("", "every base parameter, each a table of the keys below"),
    "parameters.*": ("", "one table per base parameter"),
    "parameters.*.reference": ("parameter's", "reference value: where searches start, what "
                                              "a fixed parameter holds"),
    "parameters.*.lower": ("parameter's", "lower bound of the search"),
    "parameters.*.upper": ("parameter's", "upper bound of the search"),
    "parameters.*.fixed": ("", "held at its reference value instead of identified"),
    "parameters.*.log_scale": ("", "searched on a log scale"),
    "drive": ("", "what turns the logged input column into hub torque"),
    "drive.type": ("", "the drive, also the name of the input column"),
    "drive.unit": ("", "the command's unit as logged"),
    "drive.torque_per_unit": ("N m per unit", "torque per command unit at the joint: a "
                                              "number, or a table of `reference`, `lower`, "
                                              "`upper` to identify it (`drive_gain`)"),
    "drive.torque_per_unit.reference": ("N m per unit", "identified torque per command unit"),
    "drive.torque_per_unit.lower": ("N m per unit", "its lower bound"),
    "drive.torque_per_unit.upper": ("N m per unit", "its upper bound"),
    "sensors": ("", "one `[[sensors]]` table per logged channel"),
    "sensors.type": ("", "the sensor"),
    "sensors.channel": ("", "the record column it logs"),
    "sensors.gain": ("reading per quantity", "calibration: reading = gain · quantity + offset; "
                                             "a table of `reference`, `lower`, `upper` is "
                                             "identified (`sensor_gain`)"),
    "sensors.gain.reference": ("reading per quantity", "identified gain: its start"),
    "sensors.gain.lower": ("reading per quantity", "its lower bound"),
    "sensors.gain.upper": ("reading per quantity", "its upper bound"),
    "sensors.offset": ("channel's", "the reading at rest; a table of `reference`, `lower`, "
                                    "`upper` is identified (`sensor_offset`, with "
                                    "`rezero = false`)"),
    "sensors.offset.reference": ("channel's", "stated offset"),
    "sensors.offset.lower": ("channel's", "its lower bound"),
    "sensors.offset.upper": ("channel's", "its upper bound"),
    "sensors.noise": ("channel's", "standard deviation of white measurement noise"),
    "sensors.resolution": ("channel's", "quantisation step of the logged values (0: none)"),
    "sensors.rezero": ("", "re-zero records at rest (removes any offset); false: keep their "
                           "zero, less `offset`"),
    "sensors.reading_unit": ("", "the logged channel's unit (`V`, `counts`) where the gain "
                                 "converts the quantity to it (default: the quantity's)"),
    "sensors.counts_per_revolution": ("", "encoder counts a revolution; the resolution is "
                                          "one count unless given"),
    "sensors.x": ("m", "position on the link from the clamp"),
    "sensors.calibration": ("", "`strain` (surface strain) or `deflection_angle` (rad, as "
                                "Quanser calibrates its gauge)"),
}
"""Unit and meaning of each key no code states (``*``: any parameter's name)."""


OPTIONAL: Any = object()
"""The default of a key the reader reads only where it is given."""


@dataclasses.dataclass
class Key:
    """One key of an arm file as the reader reads it."""

    path: str  # dotted, "sensors." for every [[sensors]] table, "parameters.*." for each
    kind: str  # "number", "whole number", "true/false", "string", "table", ...
    default: Any  # arm._MISSING: required
    limit: str = ""
    example: Any = None
    tables: set[str] = dataclasses.field(default_factory=set)  # drive/sensor types using it


def _generic(path: str) -> str:
    """``sensors[3].x`` → ``sensors.x``, ``parameters.E.lower`` → ``parameters.*.lower``."""
    parts = path.split(".")
    if parts[0].startswith("sensors["):
        parts[0] = "sensors"
    if parts[0] == "parameters" and len(parts) > 1:
        parts[1] = "*"
    return ".".join(parts)


@contextmanager
def _watching(found: list[tuple[str, str, Any, str, Any, Any]]):
    """Every typed look-up of the reader's tables, as (path, kind, default, limit, value,
    table data) into ``found``, while the block runs."""
    original = arm._Table
    kinds = {"number": "number", "integer": "whole number", "boolean": "true or false",
             "string": "string", "strings": "list of strings", "table": "table"}

    class Watched(original):
        pass

    def watch(method: str) -> Callable:
        def looked_up(self, name, default=arm._MISSING, **limits):
            if method == "table":
                default = arm._MISSING if limits.get("required", True) else {}
            value = getattr(original, method)(self, name, *(
                () if method == "table" else (default,)), **limits)
            minimum, top = limits.get("minimum"), limits.get("maximum")
            if method == "number":
                limit = "> 0" if minimum is None else "≥ 0" if minimum == 0 else "any sign"
            elif method == "integer":
                limit = "≥ 1" if top is None else f"1 to {top}"
            else:
                limit = ""
            found.append((self.prefix + name, kinds[method], default, limit,
                          self.data.get(name), self.data))
            return value
        return looked_up

    for method in kinds:
        setattr(Watched, method, watch(method))

    def get(self, name, default):
        value = original._get(self, name, default)
        if isinstance(value, list):
            found.append((self.prefix + name, "array", default, "", None, self.data))
        return value

    Watched._get = get

    def done(self, known=()):
        for name in known:
            found.append((self.prefix + name, "", OPTIONAL, "", None, self.data))
        return original.done(self, known)

    Watched.done = done
    arm._Table = Watched
    try:
        yield
    finally:
        arm._Table = original


def variants() -> list[dict[str, Any]]:
    """:func:`example` with each drive, and with the link's mass given each way."""
    out = [example(drive) for drive in DRIVES]
    out.append(example())
    out[-1]["simulation"]["n_elements"] = 12  # a limit that depends on another key varies
    for key, value in (("mass_per_length", 0.135), ("mass", 0.0675)):
        out.append(example())
        link = out[-1]["link"]
        del link["density"]
        link[key] = value
    return out


def read_keys() -> dict[str, Key]:
    """Every key the reader reads, by generic path, from each of :func:`variants`."""
    keys: dict[str, Key] = {}
    for data in variants():
        found: list = []
        with _watching(found):
            arm.arm_from_dict(data, where="example")
        for path, kind, default, limit, value, table in found:
            generic = _generic(path)
            key = keys.setdefault(generic, Key(generic, kind, default, limit))
            if default is OPTIONAL:  # listed as optional: only a key read without a default
                if key.default is arm._MISSING:
                    key.default = OPTIONAL
                continue
            if not key.kind:
                key.kind, key.limit = kind, limit
            elif limit != key.limit and kind == "whole number":
                key.limit = "≥ 1"
            if key.example is None and not isinstance(value, dict):
                key.example = value
            if generic.startswith(("sensors.", "drive.")) and "type" in table:
                key.tables.add(table["type"])
    return keys


def field_comments(cls: type) -> dict[str, str]:
    """The comment beside each field in ``cls``'s source (``resistance: float = 1.0  # R_m, Ω``)."""
    comments, line_of = {}, {}
    source = inspect.getsource(cls)
    for token in tokenize.generate_tokens(io.StringIO(source).readline):
        if token.type == tokenize.NAME and token.start[1] == 4 and token.start[0] not in line_of:
            line_of[token.start[0]] = token.string
        if token.type == tokenize.COMMENT and token.start[0] in line_of:
            comments[line_of[token.start[0]]] = token.string.lstrip("# ").strip()
    return comments


def _summary(cls: type) -> str:
    """The first paragraph of ``cls``'s docstring, on one line, in Markdown's backticks."""
    return inspect.getdoc(cls).split("\n\n")[0].replace("\n", " ").replace("``", "`")


def _cell(value: Any) -> str:
    if value is arm._MISSING:
        return "required"
    if value is OPTIONAL:
        return "optional"
    if isinstance(value, bool):
        return "`true`" if value else "`false`"
    if isinstance(value, float):
        return f"`{value:.6g}`"
    if isinstance(value, str):
        return f'`"{value}"`'
    if isinstance(value, (list, tuple)):
        return "`[" + ", ".join(f'"{v}"' for v in value) + "]`"
    return "" if value is None else f"`{value!r}`"


def _table(header: list[str], rows: list[list[str]]) -> str:
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    return "\n".join(lines + ["| " + " | ".join(r) + " |" for r in rows]) + "\n"


def _rows(keys: dict[str, Key], prefix: str, *, skip: tuple[str, ...] = ()) -> list[list[str]]:
    rows = []
    for path, key in keys.items():
        parent, _, name = path.rpartition(".")
        if (parent + "." if parent else "") != prefix or path in skip:
            continue
        unit, meaning = note(path)
        if path.startswith("drive.") and key.tables and key.tables != set(DRIVES):
            meaning += " (" + ", ".join(sorted(key.tables)) + ")"
        rows.append([f"`{name}`", key.kind + (f", {key.limit}" if key.limit else ""),
                     unit, _cell(key.default) if key.default != {} else "optional",
                     _cell(key.example) if key.kind != "table" else "", meaning])
    return sorted(rows, key=lambda row: row[1].startswith(("table", "array")))


HEADER = ["key", "value", "unit", "default", "example", "meaning"]


def reference() -> str:
    """The rig-file reference: each table's keys, then each drive's and each sensor's."""
    keys = read_keys()
    full = arm.arm_to_toml(arm.arm_from_dict(example(), where="example"))
    out = ["A rig file with every table, as `arm_to_toml` writes it back (the defaults filled "
           "in):\n", f"```toml\n{full}```\n",
           "### Top level\n", _table(HEADER, _rows(keys, "")),
           "### `[link]`\n", _table(HEADER, _rows(keys, "link.")),
           "### `[simulation]`\n", _table(HEADER, _rows(keys, "simulation.")),
           "### `[sampling]`\n", _table(HEADER, _rows(keys, "sampling.")),
           "### `[parameters]`\n",
           "Each of the six base parameters is a table of these keys "
           "(`E = { reference = 5.7e10, lower = 20e9, upper = 100e9 }`):\n",
           _table(HEADER, _rows(keys, "parameters.*.")),
           _table(["parameter", "unit", "what it is", "reference testbed: reference",
                   "lower", "upper"],
                  [[f"`{s.name}`", s.unit, s.description, f"{s.reference:g}", f"{s.lower:g}",
                    f"{s.upper:g}"] for s in BASE_PARAMETERS]),
           "### `[drive]`\n", _table(HEADER, _rows(keys, "drive.")),
           _drives(keys),
           "### `[[sensors]]`\n",
           "Keys every sensor takes:\n", _table(HEADER, _sensor_rows(keys, common=True)),
           "Keys of some sensors, and each sensor's quantity:\n",
           _table(["key", "value", "unit", "default", "example", "meaning"],
                  _sensor_rows(keys, common=False)),
           _sensors()]
    return "\n".join(out)


def _drives(keys: dict[str, Key]) -> str:
    rows = []
    for name, cls in DRIVES.items():
        fields = [f.name for f in dataclasses.fields(cls)]
        settings = ", ".join(f"`{f}`" for f in fields)
        doc = _summary(cls)
        unit = cls.unit if cls is not CommandDrive else "its `unit`"
        rows.append([f'`"{name}"`', doc, unit, settings or "none"])
    return _table(["`type`", "what it is", "input column's unit", "keys"], rows)


def _sensor_rows(keys: dict[str, Key], *, common: bool) -> list[list[str]]:
    every = set(SENSORS)
    rows = []
    for path, key in keys.items():
        if not path.startswith("sensors.") or path.count(".") != 1:
            continue
        if (key.tables == every) != common:
            continue
        unit, meaning = NOTES[path]
        default = key.default
        if default in (arm._MISSING, OPTIONAL) and path != "sensors.type":
            defaults = {f.default for kind in key.tables for f in dataclasses.fields(SENSORS[kind])
                        if f.name == path.partition(".")[2]}
            default = defaults.pop() if len(defaults) == 1 else None
        where = "" if common else " (" + ", ".join(sorted(key.tables)) + ")"
        rows.append([f"`{path.partition('.')[2]}`",
                     key.kind + (f", {key.limit}" if key.limit else ""), unit,
                     _cell(default) or "per type", _cell(key.example), meaning + where])
    return rows


def _sensors() -> str:
    rows = []
    for name, cls in SENSORS.items():
        channel = next(f.default for f in dataclasses.fields(cls) if f.name == "channel")
        unit = cls.unit if isinstance(cls.unit, str) else "1, or rad (`deflection_angle`)"
        rows.append([f'`"{name}"`', _summary(cls), unit, f'`"{channel}"`'])
    return _table(["`type`", "what it reads", "quantity's unit", "default `channel`"], rows)


def drive_constants() -> dict[str, str]:
    """``drive.KEY`` → the comment beside the field, for every drive's numeric constant."""
    return {f"drive.{name}": comment for cls in DRIVES.values()
            for name, comment in field_comments(cls).items() if not comment.startswith("type:")}


def note(path: str) -> tuple[str, str]:
    """(unit, meaning) of a key: :data:`NOTES`, or a drive constant's comment."""
    constants = drive_constants()
    return NOTES[path] if path in NOTES else ("", constants[path])


def described() -> tuple[set[str], set[str]]:
    """(keys the reader reads that no note describes, notes on keys it does not read)."""
    read = set(read_keys())
    notes = set(NOTES) | set(drive_constants())
    return read - notes, notes - read
