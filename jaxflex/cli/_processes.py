"""``--processes N [--process-id I --coordinator HOST:PORT]``: one search over several processes.

Shared by ``identify`` and ``study``; :mod:`jaxflex.distributed` says how the processes share the
work (JAX's multi-process runtime) and the three ways to start them.
"""

from __future__ import annotations

import argparse

from jaxflex.cli._checks import positive_int


def add_process_arguments(p: argparse.ArgumentParser) -> None:
    group = p.add_argument_group("several processes (JAX's multi-process runtime)")
    group.add_argument("--processes", type=positive_int, metavar="N",
                       help="split each population over N processes; alone: start them here")
    group.add_argument("--process-id", type=int, metavar="I",
                       help="this process's place in the group, 0 ... N-1 (one per host)")
    group.add_argument("--coordinator", metavar="HOST:PORT",
                       help="process 0's coordinator (default: $JAX_COORDINATOR_ADDRESS)")


def enter(args: argparse.Namespace) -> int | None:
    """Start or join the group the options ask for. Returns the group's exit status when this
    process only launched it, else None (run the command; only process 0 prints and writes)."""
    from jaxflex import distributed

    settings = (args.processes, args.process_id, args.coordinator)
    wanted = distributed.wanted(*settings)
    if wanted == "launch":
        return distributed.launch_local(args.argv, args.processes)
    if wanted == "join":
        distributed.start(*settings)
        args.quiet = args.quiet or not distributed.is_main()
    return None
