"""``--arm RIG`` and ``--window T0:T1``: the rig of every command, through one set of helpers.

Every command works on one rig (:class:`~jaxflex.model.Model`): ``--arm`` names an arm file or
a packaged rig; without it, the reference testbed; a command given a fit works on the rig the
fit carries whole (a later ``--arm`` must name the same rig). :func:`rig_of` finds it,
:func:`ready_records` makes records as the rig logged them ready for its model (each cut to
``--window`` (per record or for all, ``auto`` at the rest before the first motion;
:mod:`jaxflex.cli._windows`), its sensors re-zeroed at rest; :mod:`jaxflex.measured`) and
:func:`rig_settings` is what a result records of where its rig came from.
"""

from __future__ import annotations

import argparse
import os
from pathlib import Path
from typing import TYPE_CHECKING

from jaxflex.cli import UsageError, load_records

if TYPE_CHECKING:
    from jaxflex.data import Record
    from jaxflex.model import Model

Window = tuple[float, float] | None
"""``(t0, t1)`` in a record's own time, or None for the whole record."""


def add_arm_arguments(p: argparse.ArgumentParser, *, window: bool = True) -> None:
    """``--arm RIG`` (and ``--window T0:T1`` where records are read) on a command."""
    p.add_argument("--arm", metavar="RIG",
                   help="the rig: a packaged rig's name (see `jaxflex arms list`) or an arm "
                        "file (RIG.toml, see jaxflex.arm); default: the reference testbed, or "
                        "the rig a given fit carries")
    if window:
        from jaxflex.cli._windows import add_windows_argument

        add_windows_argument(p)


def load_arm_file(path: str | os.PathLike) -> Model:
    """The rig ``path`` names (an arm file, or a packaged rig); its errors are one-line usage
    errors."""
    from jaxflex.arm import ArmError, load_arm

    try:
        return load_arm(path)
    except ArmError as err:
        raise UsageError(str(err)) from None


def rig_of(args: argparse.Namespace, fit=None) -> tuple[Model, str | None]:
    """The command's rig and the arm file it came from (None: none read): the one ``fit``
    carries (``--arm``, if given, must describe it), else ``--arm``, else the reference."""
    from jaxflex.model import Model

    given = getattr(args, "arm", None)
    arm = None if given is None else load_arm_file(given)
    source = None if given is None else str(given)
    if fit is None:
        return (Model() if arm is None else arm), source
    carried = fit.model
    if arm is not None:
        own = {e.name for e in arm.effects}
        bare = carried.replace(effects=tuple(e for e in carried.effects if e.name in own))
        if bare != arm:
            raise UsageError(f"--arm {given}: the fit was made with another rig "
                             f"({carried.name!r}), which it carries; leave --arm out")
    return carried, source


def with_effects(model: Model, names: list[str], option: str = "--effect") -> Model:
    """``model`` with the named effects added (an unknown or doubled name, or one the rig
    cannot take, names the option)."""
    from jaxflex.cli._options import effects_from

    added = effects_from(names, option)
    twice = sorted({e.name for e in added} & set(model.effect_names))
    if twice:
        raise UsageError(f"{option} {twice[0]}: the rig {model.name!r} has it already")
    try:
        return model.with_effects(*added)
    except ValueError as err:
        raise UsageError(f"{option}: {err}") from None


def windows_of(args: argparse.Namespace, model: Model, records) -> list[Window]:
    """Each record's window from ``--window`` (checked against the record; ``auto`` found from
    the rig's sensors' rest bands over a span of its link's lowest period,
    :func:`jaxflex.measured.rest_span`), in the records' order."""
    from jaxflex.cli._windows import parse_windows, resolve_window
    from jaxflex.measured import rest_span
    from jaxflex.rest import rest_bands

    given = parse_windows(getattr(args, "window", None), [r.name for r in records])
    span = rest_span(model) if any(w is not None and w.auto for w in given.values()) else None
    return [resolve_window(given.get(r.name), r, rest_bands(model.sensors, r), span)
            for r in records]


def ready_records(model: Model, records, windows: list[Window], *, say: bool = True,
                  at_rest: bool = True) -> list[Record]:
    """Records as the rig logged them, made ready for its model, each cut to its window
    (:func:`jaxflex.measured.prepare`; not ``at_rest``: records that start in motion), with
    command-line errors; for a rig with sensors, one line per record says which of them it
    holds, and for every rig a warning says which of its channels a record does not log and
    which of its columns are ignored (unless not ``say``)."""
    import warnings

    from jaxflex.measured import channel_notes, check_rate, logged_sensors, prepare

    for record in records:
        _speaking_cli(check_rate, model, record)
    ready = _speaking_cli(prepare, model, list(records), windows, at_rest=at_rest)
    for record, window in zip(records, windows, strict=True) if model.sensors and say else ():
        found = logged_sensors(model, record)
        cut = "" if window is None else f", {window[0]:g} to {window[1]:g} s"
        print(f"{record.name}{cut}: {record.input_name} in; "
              + ", ".join(f"{s.channel} ({s.kind}, {s.channel_unit or '-'})" for s in found))
    for note in _speaking_cli(channel_notes, model, list(records)) if say else ():
        warnings.warn(note, stacklevel=2)
    return ready


def rig_settings(model: Model, source: str | None, records, windows: list[Window]) -> dict:
    """What a result records of its rig: its name, the arm file it was read from (absolute;
    for information: the result carries the rig itself) and each record's window."""
    where = str(Path(source).resolve()) if _read_file(source) else None
    return {"rig": model.name, "arm": where or source,
            "windows": {r.name: w for r, w in zip(records, windows, strict=True)}}


def arm_inputs(source: str | None) -> list[str]:
    """The arm file among a command's inputs (outputs may not replace it)."""
    return [source] if _read_file(source) else []


def _read_file(source: str | None) -> bool:
    """Whether ``--arm source`` was read from a file (not a packaged rig's name)."""
    from jaxflex.rigs import is_arm_name

    return source is not None and not is_arm_name(source) and Path(source).is_file()


def refuse_two_link(records) -> None:
    """Refuse records of the Quanser 2-DOF serial flexible link, known by their metadata."""
    from jaxflex.datasets import quanser_2dsfl

    marks = (quanser_2dsfl.SOURCE.name, quanser_2dsfl.SOURCE.repository)
    for r in records:
        if any(m in str(v) for m in marks for v in (*r.metadata.values(), *r.metadata)):
            raise UsageError(
                f"record {r.name!r}: Quanser 2-DOF serial flexible link, a two-link arm (the "
                "second motor and link ride on the first, flexible link); jaxflex models a "
                "single flexible link and cannot fit it"
            )


def load_rig_records(paths, args: argparse.Namespace, model: Model | None = None):
    """The records of ``paths`` (record options of ``args``; columns named as ``model``'s
    sensors are theirs, its drive's input column is read where a file holds several); a
    two-link rig is refused."""
    channels = () if model is None else model.channels
    records = load_records(paths, resample=args.resample, unit_check=args.unit_check,
                           channels=channels, drive=None if model is None else model.drive.name)
    refuse_two_link(records)
    return records


def sensor_noise(model: Model, records) -> dict:
    """The noise levels the rig's sensors state (``--noise`` overrides them)."""
    from jaxflex.measured import fit_noise

    return _speaking_cli(fit_noise, model, records[0])


def _speaking_cli(function, *args, **kwargs):
    """``function(*args, **kwargs)`` with its errors in the command line's words."""
    try:
        return function(*args, **kwargs)
    except (KeyError, ValueError) as err:
        message = err.args[0] if isinstance(err, KeyError) and err.args else str(err)
        raise UsageError(str(message).replace("window=(t0, t1)", "--window T0:T1").replace(
            "initial_state='estimate'", "--initial-state estimate")) from None
