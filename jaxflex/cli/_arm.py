"""``--arm FILE`` and ``--window T0:T1``: every command on a real rig, through one set of helpers.

:func:`add_arm_arguments` adds the options, :func:`arm_of` finds the arm (``--arm``, or the one
a fit was made with), :func:`model_records` maps records as the rig logged them onto the arm's
model, :func:`arm_fit_keywords` adds the arm's fixed parameters and fitted channels and
:func:`arm_settings` is what a result records of its arm.

With an arm file, ``identify`` takes the records as the rig logged them (the drive's input
column, the sensors' channels; :mod:`jaxflex.measured`), fits the arm's model and records the
arm file and window in the fit's settings; ``validate`` then finds the arm there, scores every
sensor channel of each record over the whole record (or ``--window``) and writes
``{"records": [{"name", "role", "nrmse": {channel: percent}}]}`` with ``--json``.
"""

from __future__ import annotations

import argparse
import dataclasses
import os
from pathlib import Path
from typing import TYPE_CHECKING

from jaxflex._io import same_file
from jaxflex.cli import UsageError, load_records

if TYPE_CHECKING:
    from jaxflex.arm import Arm
    from jaxflex.data import Record


def add_window_argument(p: argparse.ArgumentParser) -> None:
    p.add_argument("--window", metavar="T0:T1",
                   help="use only T0 <= t <= T1 (s, in the records' own time)")


def parse_window(text: str | None) -> tuple[float, float] | None:
    """``"T0:T1"`` → ``(T0, T1)``; None stays None."""
    if text is None:
        return None
    lo, sep, hi = text.partition(":")
    try:
        window = (float(lo), float(hi))
    except ValueError:
        window = None
    if not sep or window is None or not window[0] < window[1]:
        raise UsageError(f"--window {text!r}: expected T0:T1 with T0 < T1, in seconds")
    return window


def add_arm_arguments(p: argparse.ArgumentParser, *, window: bool = True) -> None:
    """``--arm ARM.toml`` (and ``--window T0:T1`` where records are read) on a command."""
    p.add_argument("--arm", metavar="ARM.toml",
                   help="the rig's arm file (see jaxflex.arm): its model, drive and sensors")
    if window:
        add_window_argument(p)


def load_arm_file(path: str | os.PathLike, option: str = "--arm") -> Arm:
    """The arm file ``path``; its errors are one-line usage errors."""
    from jaxflex.arm import ArmError, load_arm

    try:
        return load_arm(path)
    except ArmError as err:
        message = str(err)
        raise UsageError(message if option == "--arm" else f"{option}: {message}") from None


def arm_of(args: argparse.Namespace, fit=None) -> tuple[Arm, str] | None:
    """The arm of a command, and its file: ``--arm``, else the one ``fit`` was made with (a fit
    records its arm, so later commands need no ``--arm``); None when neither names one. A
    ``--window`` without an arm is refused."""
    recorded = with_arm(fit)
    given = getattr(args, "arm", None)
    if given is not None and recorded is not None and not same_file(given, recorded):
        raise UsageError(
            f"--arm {given}: the fit was made with the arm {recorded}; leave --arm out"
        )
    path = given if given is not None else recorded
    if path is None:
        if getattr(args, "window", None) is not None:
            raise UsageError("--window needs --arm (or a fit made with --arm)")
        return None
    return load_arm_file(path, "--arm" if given is not None else "the fit's arm"), str(path)


def model_records(arm: Arm, records, window: tuple[float, float] | None) -> list[Record]:
    """Records as the rig logged them, made ready for the arm's model
    (:func:`jaxflex.measured.model_record`), with command-line errors."""
    from jaxflex.measured import model_record

    return [_speaking_cli(model_record, arm, r, window) for r in records]


def arm_settings(arm_file: str, window: tuple[float, float] | None) -> dict:
    """What a result records about its arm: the file (absolute) and the window."""
    return {"arm": str(Path(arm_file).resolve()), "window": window}


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


def load_rig_records(paths, args: argparse.Namespace):
    """The records of ``paths`` (record options of ``args``); a two-link rig is refused."""
    records = load_records(paths, resample=args.resample, unit_check=args.unit_check)
    refuse_two_link(records)
    return records


def arm_fit_keywords(args: argparse.Namespace, function, arm: Arm, record) -> dict:
    """The fitting keywords of ``identify`` (or ``study``) on an arm's records: the shared
    options, the arm's fixed parameters under ``--fix`` and the channels its sensors give."""
    from jaxflex.cli._options import fit_keywords
    from jaxflex.measured import fit_channels

    options = fit_keywords(args, function)
    options["fixed"] = arm.fixed_values | options.get("fixed", {}) or None
    options["channels"] = _speaking_cli(fit_channels, arm, record)
    return options


def identify_with_arm(args: argparse.Namespace, arm: Arm, arm_file: str) -> int:
    """``jaxflex identify DATA... --arm ARM.toml``: see the module doc."""
    from jaxflex import identify
    from jaxflex._io import all_or_nothing
    from jaxflex.cli._checks import JSON_SUFFIXES, check_outputs
    from jaxflex.cli._options import model_from
    from jaxflex.cli.identify import report_fit, search, sources
    from jaxflex.distributed import is_main

    window = parse_window(args.window)
    records = load_rig_records(args.data, args)
    (out,) = check_outputs([("--out", args.out, JSON_SUFFIXES)], overwrite=args.overwrite,
                           inputs=[*sources(records), arm_file])
    ready = model_records(arm, records, window)
    options = arm_fit_keywords(args, identify, arm, records[0])
    fit = search(args, ready, arm.model(*model_from(args.effect).effects), options)
    if not is_main():
        return 0
    fit = dataclasses.replace(fit, settings=fit.settings | arm_settings(arm_file, window))
    report_fit(fit)
    with all_or_nothing():
        fit.to_json(out, overwrite=args.overwrite)
    print(f"wrote {out}")
    return 0


def validate_with_arm(args: argparse.Namespace, fit, model) -> int:
    """``jaxflex validate DATA... --fit FIT.json`` for a fit made with ``--arm``."""
    from jaxflex._io import write_json
    from jaxflex.cli._checks import JSON_SUFFIXES, check_outputs
    from jaxflex.cli.identify import sources
    from jaxflex.measured import validate

    arm = load_arm_file(fit.settings["arm"], "the fit's arm")
    window = parse_window(args.window)
    # one by one: a held-out record may be sampled at another rate than the fitted one
    records = [r for name in args.data for r in load_rig_records([name], args)]
    (target,) = check_outputs([("--json", args.json, JSON_SUFFIXES)], overwrite=args.overwrite,
                              inputs=[*sources(records), args.fit]) or [None]
    scores = _speaking_cli(
        validate, arm, fit.params, records, [window] * len(records), effects=model.effects
    )
    rows = [
        {
            "name": name,
            "role": "fit" if name in fit.record_names else "held-out",
            "nrmse": channels,
        }
        for name, channels in scores.items()
    ]
    for row in rows:
        cells = ", ".join(f"{c} {v:.2f} %" for c, v in row["nrmse"].items())
        print(f"{row['name']:<20} {row['role']:<9} NRMSE {cells}")
    if target is not None:
        write_json(target, {"arm": fit.settings["arm"], "window": window, "records": rows},
                   overwrite=args.overwrite)
        print(f"wrote {target}")
    return 0


def _speaking_cli(function, *args, **kwargs):
    """``function(*args, **kwargs)`` with its errors in the command line's words."""
    try:
        return function(*args, **kwargs)
    except ValueError as err:
        raise UsageError(str(err).replace("window=(t0, t1)", "--window T0:T1")) from None


def with_arm(fit) -> Path | None:
    """The arm file a fit was made with, or None."""
    settings = getattr(fit, "settings", None)
    arm = settings.get("arm") if isinstance(settings, dict) else None
    return None if arm is None else Path(arm)
