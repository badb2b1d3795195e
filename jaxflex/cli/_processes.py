"""``--processes N [--process-id I --coordinator HOST:PORT]``: one search over several processes.

Shared by ``identify`` and ``study``; :mod:`jaxflex.distributed` says how the processes share the
work (JAX's multi-process runtime), the three ways to start them and what happens when one
fails. ``--processes N`` alone checks everything a process would check first — that N is within
the usable cores, the options, the arm, the records, the outputs — before it starts any.
A process that waits for its group gives up after ``--peer-timeout`` seconds (default 60) with
one line and exit status 2; Ctrl-C and SIGTERM stop the wait (130, 143).
"""

from __future__ import annotations

import argparse
import os
import signal
import sys

from jaxflex.cli._checks import positive_float, positive_int


def add_process_arguments(p: argparse.ArgumentParser) -> None:
    from jaxflex.distributed import PEER_TIMEOUT_S

    group = p.add_argument_group("several processes (JAX's multi-process runtime)")
    group.add_argument("--processes", type=positive_int, metavar="N",
                       help="split each population over N processes; alone: start them here "
                            "(at most one per usable core)")
    group.add_argument("--process-id", type=int, metavar="I",
                       help="this process's place in the group, 0 ... N-1 (one per host)")
    group.add_argument("--coordinator", metavar="HOST:PORT",
                       help="process 0's coordinator (default: $JAX_COORDINATOR_ADDRESS)")
    group.add_argument("--peer-timeout", type=positive_float, default=PEER_TIMEOUT_S,
                       metavar="SECONDS",
                       help="give up when the group has not formed within SECONDS "
                            "(default: %(default)g)")


def enter(args: argparse.Namespace) -> int | None:
    """Start or join the group the options ask for. Returns the group's exit status when this
    process only launched it, else None (run the command; only process 0 prints and writes)."""
    from jaxflex import distributed

    settings = (args.processes, args.process_id, args.coordinator)
    wanted = distributed.wanted(*settings)
    prefix = f"jaxflex {args.command}"
    if wanted == "launch":
        distributed.check_local_group(args.processes)
        check_before_launch(args)
        return distributed.launch_local(args.argv, args.processes, prefix)
    if wanted == "join":
        if distributed.launched():
            signal.signal(signal.SIGTERM, _stopped_by_launcher)
        try:
            distributed.start(*settings, peer_timeout=args.peer_timeout)
        except distributed.PeerTimeout as exc:  # (Ctrl-C while waiting: main's handler ends it)
            # JAX's half-made runtime aborts or complains when the interpreter ends: leave now
            from jaxflex.cli import EXIT_USAGE

            print(f"{prefix}: error: {exc}", file=sys.stderr, flush=True)
            os._exit(EXIT_USAGE)
        args.quiet = args.quiet or not distributed.is_main()
    return None


def check_before_launch(args: argparse.Namespace) -> None:
    """What every process of the group would refuse before it computes, refused once here
    before any starts: a study's methods and seeds, the rig, the records and the outputs."""
    from jaxflex.cli._arm import (
        arm_inputs,
        load_rig_records,
        ready_records,
        rig_of,
        windows_of,
        with_effects,
    )
    from jaxflex.cli._checks import FIGURE_SUFFIXES, JSON_SUFFIXES, check_outputs
    from jaxflex.cli.identify import sources

    if args.command == "study":
        from jaxflex.cli.study import parse_methods, parse_seeds

        parse_methods(args.methods)
        parse_seeds(args.seeds)
    rig, source = rig_of(args)
    model = with_effects(rig, args.effect)
    records = load_rig_records(args.data, args, model)
    check_outputs(
        [("--out", args.out, JSON_SUFFIXES), ("--plot", args.plot, FIGURE_SUFFIXES)],
        overwrite=args.overwrite, inputs=[*sources(records), *arm_inputs(source)],
    )
    ready_records(model, records, windows_of(args, model, records), say=False,
                  at_rest=getattr(args, "initial_state", "rest") == "rest")


def _stopped_by_launcher(signum, frame) -> None:
    """SIGTERM in a process that ``--processes N`` started: the launcher stopped the group and
    says why in one line; this one removes its temporary files and ends without a word."""
    from jaxflex._io import remove_temporaries
    from jaxflex.cli import EXIT_TERMINATED

    remove_temporaries()
    os._exit(EXIT_TERMINATED)
