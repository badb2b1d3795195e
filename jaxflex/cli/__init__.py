"""The ``jaxflex`` command: one sub-command per workflow stage, each in its own module.

Each module in :data:`COMMANDS` defines ``register(subparsers)``, which adds its parser and
sets ``func`` to the function that runs it. Errors a user can fix (bad files, bad values) are
printed as one line ``jaxflex <command>: error: …`` with exit status 2, never a traceback.
"""

from __future__ import annotations

import argparse
import importlib
import sys
from collections.abc import Sequence

COMMANDS: tuple[str, ...] = (
    "simulate",
    "identify",
    "study",
    "validate",
    "discover",
    "design",
    "demo",
    "datasets",
)


class UsageError(ValueError):
    """A problem with the command line or its input files that the user can fix."""


def load_records(paths: Sequence[str], *, resample: bool):
    """Records from files and directories; a missing or malformed file is a UsageError."""
    from pathlib import Path

    from jaxflex.data import Dataset, RecordError, load_dataset, load_record

    records = []
    try:
        for name in paths:
            path = Path(name)
            if not path.exists():
                raise UsageError(f"{path}: record file not found")
            if path.is_dir():
                records += list(load_dataset(path, resample=resample))
            else:
                records.append(load_record(path, resample=resample))
        return Dataset(records)
    except RecordError as exc:  # speak the command line's language
        raise UsageError(str(exc).replace("resample=True", "--resample")) from None


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="jaxflex",
        description="Identify flexible-link manipulators by differentiable simulation.",
    )
    subparsers = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name in COMMANDS:
        try:
            module = importlib.import_module(f"jaxflex.cli.{name}")
        except ModuleNotFoundError as exc:
            if exc.name == f"jaxflex.cli.{name}":
                continue  # command not available in this build
            raise
        module.register(subparsers)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except (UsageError, ValueError, FileNotFoundError, FileExistsError, KeyError) as exc:
        message = exc.args[0] if isinstance(exc, KeyError) and exc.args else exc
        print(f"jaxflex {args.command}: error: {message}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
