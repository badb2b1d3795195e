"""``--arm FILE`` and ``--window T0:T1`` for ``identify`` and ``validate``: fit a real rig.

With an arm file, ``identify`` takes the records as the rig logged them (the drive's input
column, the sensors' channels; :mod:`jaxflex.measured`), fits the arm's model and records the
arm file and window in the fit's settings; ``validate`` then finds the arm there, scores every
sensor channel of each record over the whole record (or ``--window``) and writes
``{"records": [{"name", "role", "nrmse": {channel: percent}}]}`` with ``--json``.
"""

from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path

from jaxflex.cli import UsageError, load_records


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


def _arm(path: str):
    from jaxflex.arm import ArmError, load_arm

    try:
        return load_arm(path)
    except ArmError as err:
        raise UsageError(str(err)) from None


def identify_with_arm(args: argparse.Namespace) -> int:
    """``jaxflex identify DATA... --arm ARM.toml``: see the module doc."""
    from jaxflex._io import all_or_nothing
    from jaxflex.cli._checks import JSON_SUFFIXES, check_outputs
    from jaxflex.cli._options import fit_keywords, model_from
    from jaxflex.cli.identify import check_finite_cost, sources
    from jaxflex.identification import identify
    from jaxflex.measured import fit_channels, model_record

    arm = _arm(args.arm)
    window = parse_window(args.window)
    records = load_records(args.data, resample=args.resample, unit_check=args.unit_check)
    (out,) = check_outputs([("--out", args.out, JSON_SUFFIXES)], overwrite=args.overwrite,
                           inputs=[*sources(records), args.arm])
    ready = [_speaking_cli(model_record, arm, r, window) for r in records]
    options = fit_keywords(args, identify)
    options["fixed"] = arm.fixed_values | options.get("fixed", {}) or None
    fit = identify(
        ready,
        arm.model(*model_from(args.effect).effects),
        method=args.method,
        seed=args.seed,
        generations=args.generations,
        population=args.population,
        refine=args.refine,
        progress=not args.quiet,
        refine_starts=args.refine_starts,
        channels=fit_channels(arm, records[0]),
        **options,
    )
    check_finite_cost(fit.cost, "bounds" in options)
    arm_file = str(Path(args.arm).resolve())
    fit = dataclasses.replace(fit, settings=fit.settings | {"arm": arm_file, "window": window})
    print(fit.summary(), end="")
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

    arm = _arm(fit.settings["arm"])
    window = parse_window(args.window)
    # one by one: a held-out record may be sampled at another rate than the fitted one
    records = [r for name in args.data
               for r in load_records([name], resample=args.resample, unit_check=args.unit_check)]
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
