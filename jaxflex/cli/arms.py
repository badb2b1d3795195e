"""``jaxflex arms list`` and ``jaxflex arms show NAME``: the rigs packaged with jaxflex.

Any command's ``--arm`` takes one of these names (see :mod:`jaxflex.rigs`); ``show`` prints the
arm file exactly as packaged, so that ``jaxflex arms show reference > my_rig.toml`` starts a
rig of one's own.
"""

from __future__ import annotations

import argparse
import sys

from jaxflex.cli import UsageError

HELP = "list the rigs packaged with jaxflex, or print one's arm file to start your own"
"""One-line summary of ``jaxflex arms`` in the command list."""


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser("arms", help=HELP, description=HELP)
    actions = p.add_subparsers(dest="action", required=True, metavar="ACTION")
    listing = actions.add_parser("list", help="the packaged rigs: name and description")
    listing.set_defaults(func=run_list)
    show = actions.add_parser("show", help="print a packaged rig's arm file (TOML) as it is")
    show.add_argument("name", metavar="NAME", help="a packaged rig (see `jaxflex arms list`)")
    show.set_defaults(func=run_show)


def run_list(args: argparse.Namespace) -> int:
    from jaxflex.arm import load_arm
    from jaxflex.rigs import packaged_arms

    for name in packaged_arms():
        description = load_arm(name).description.strip().splitlines()
        print(f"{name}: {description[0]}" if description else name)
    return 0


def run_show(args: argparse.Namespace) -> int:
    from jaxflex.arm import ArmError
    from jaxflex.rigs import arm_path

    try:
        path = arm_path(args.name)
    except ArmError as err:
        raise UsageError(str(err)) from None
    sys.stdout.write(path.read_text(encoding="utf-8"))
    return 0
