"""``jaxflex demo --out DIR``: the whole story on synthetic data (see :mod:`jaxflex.demo`)."""

from __future__ import annotations

import argparse

from jaxflex.cli._checks import seed

HELP = "run the demo on synthetic records: identify on one input, validate on the others"
"""One-line summary of ``jaxflex demo`` in the command list."""


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser("demo", help=HELP, description=HELP)
    p.add_argument(
        "--out",
        default="demo-output",
        metavar="DIR",
        help="directory for records, fit, table and figures (default: %(default)s)",
    )
    p.add_argument("--seed", type=seed, default=0, help="seed of noise and search (default: 0)")
    p.add_argument("--overwrite", action="store_true", help="replace files from an earlier run")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from jaxflex.demo import run_demo

    run_demo(args.out, seed=args.seed, overwrite=args.overwrite)
    return 0
