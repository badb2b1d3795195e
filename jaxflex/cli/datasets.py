"""``jaxflex datasets list`` and ``jaxflex datasets get NAME --out DIR``: public real-rig data.

The original files come from ``--data-dir`` (or ``JAXFLEX_DATA_DIR``), a folder laid out as
``<folder>/<data set>/<file>``, or else from their pinned upstream URLs into the user cache; each
is checked against its SHA-256 and converted to record CSVs (see :mod:`jaxflex.datasets`).
``JAXFLEX_DATA_URL`` names a mirror of raw.githubusercontent.com to download from. Every record
file is checked before anything is fetched, and they are written together or not at all; a failed
download is one line and leaves nothing in the cache.
"""

from __future__ import annotations

import argparse

from jaxflex.cli import UsageError

HELP = "list the public real-rig data sets, or fetch one and write its records as CSV"
"""One-line summary of ``jaxflex datasets`` in the command list."""


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser("datasets", help=HELP, description=HELP)
    actions = p.add_subparsers(dest="action", required=True, metavar="ACTION")
    listing = actions.add_parser("list", help="list the data sets and their records")
    listing.set_defaults(func=run_list)
    get = actions.add_parser("get", help="fetch a data set and write DIR/<record>.csv")
    get.add_argument("name", metavar="NAME", help="data set name (see `jaxflex datasets list`)")
    get.add_argument("--out", required=True, metavar="DIR", help="directory for the record CSVs")
    get.add_argument(
        "--data-dir",
        metavar="DIR",
        help="local copy of the original files (default: $JAXFLEX_DATA_DIR, else download)",
    )
    get.add_argument("--overwrite", action="store_true", help="replace existing record files")
    get.set_defaults(func=run_get)


def run_list(args: argparse.Namespace) -> int:
    from jaxflex.datasets import available

    for info in available():
        print(f"{info.name}: {info.description}")
        print(f"    source: {info.source.source_line}")
        for record, description in info.records.items():
            print(f"    {record}: {description}")
        if not info.records:
            print("    (no records: outside the one-link model; files can still be fetched)")
    return 0


def run_get(args: argparse.Namespace) -> int:
    from jaxflex.datasets import DatasetError, write

    if not args.out:
        raise UsageError("--out '': names no folder; give the folder for the record files")
    try:
        paths = write(args.name, args.out, args.data_dir, overwrite=args.overwrite)
    except DatasetError as err:
        raise UsageError(str(err)) from None
    for path in paths:
        print(path)
    return 0
