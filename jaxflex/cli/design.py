"""``jaxflex design --max-torque T [--rms-torque R] --max-angle A --max-speed S --out input.csv``.

Designs a Fourier-series torque that maximises the information about the parameters (see
:mod:`jaxflex.design`), writes it as a record file (torque plus the model's predicted response,
so that it is a valid spec CSV; a ``# note:`` line says the outputs are predictions) and
optionally a figure, and prints the predicted 95 % intervals against the paper's triangular,
pulse and half-sine inputs at the same RMS torque. ``--rms-torque`` defaults to
:data:`DEFAULT_RMS_FRACTION` of ``--max-torque``: a multisine's peak is about twice its RMS.
"""

from __future__ import annotations

import argparse
import math

from jaxflex.cli import UsageError
from jaxflex.cli._arm import add_arm_arguments, arm_inputs, rig_of
from jaxflex.cli._checks import (
    FIGURE_SUFFIXES,
    RECORD_SUFFIXES,
    add_max_samples,
    check_outputs,
    check_size,
    max_samples,
    positive_float,
    positive_int,
    seed,
)
from jaxflex.cli._options import add_quiet_option

DEFAULT_RMS_FRACTION = 0.5
"""Default ``--rms-torque`` as a fraction of ``--max-torque``."""
HELP = "design an excitation torque that maximises the information about the parameters"
"""One-line summary of ``jaxflex design`` in the command list."""


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser("design", help=HELP, description=HELP)
    p.add_argument(
        "--duration",
        type=positive_float,
        default=2.0,
        metavar="S",
        help="record length in seconds (default: %(default)s)",
    )
    p.add_argument(
        "--max-torque", type=positive_float, required=True, metavar="NM",
        help="peak torque limit (N m); with --arm, the peak of the drive's input in its unit "
        "(V for a voltage drive, A for a current drive, the arm file's unit for a command "
        "drive)",
    )
    p.add_argument(
        "--rms-torque",
        type=positive_float,
        metavar="NM",
        help="RMS torque budget (N m), at most --max-torque; the paper's inputs are compared at "
        f"this RMS (default: {DEFAULT_RMS_FRACTION:g} x --max-torque)",
    )
    p.add_argument(
        "--max-angle", type=positive_float, required=True, metavar="RAD",
        help="joint angle range ±RAD",
    )
    p.add_argument(
        "--max-speed", type=positive_float, required=True, metavar="RAD_S",
        help="joint speed limit (rad/s)",
    )
    p.add_argument(
        "--criterion",
        choices=("D", "E"),
        default="E",
        help="D: log det of the Fisher information; E: its smallest eigenvalue "
        "(the worst-identified parameters; default)",
    )
    p.add_argument(
        "--harmonics",
        type=positive_int,
        metavar="N",
        help="harmonics of 1/duration (default: all up to --max-frequency)",
    )
    p.add_argument(
        "--max-frequency",
        type=positive_float,
        default=20.0,
        metavar="HZ",
        help="highest harmonic when --harmonics is not given (default: %(default)s)",
    )
    p.add_argument(
        "--iterations",
        type=int,
        default=30,
        metavar="K",
        help="ascent iterations (default: %(default)s)",
    )
    p.add_argument("--seed", type=seed, default=0, help="seed of the starting phases")
    p.add_argument(
        "--restarts",
        type=positive_int,
        default=1,
        metavar="R",
        help="random starts to try, keeping the best (default: %(default)s)",
    )
    p.add_argument("--out", required=True, metavar="INPUT.csv", help="record file to write")
    p.add_argument(
        "--plot",
        metavar="FIG.png",
        help="figure of the torque and the predicted response (.png/.pdf/.svg)",
    )
    p.add_argument(
        "--plot-intervals",
        metavar="FIG.png",
        help="bar chart of the predicted intervals against the paper's inputs",
    )
    p.add_argument("--overwrite", action="store_true", help="replace existing output files")
    add_quiet_option(p)
    add_max_samples(p)
    add_arm_arguments(p, window=False)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from jaxflex._io import all_or_nothing
    from jaxflex.data import save_record
    from jaxflex.design import compare_inputs, design_input, interval_table, paper_inputs

    model, source = rig_of(args)
    out, *plots = check_outputs(
        [("--out", args.out, RECORD_SUFFIXES), ("--plot", args.plot, FIGURE_SUFFIXES),
         ("--plot-intervals", args.plot_intervals, FIGURE_SUFFIXES)],
        overwrite=args.overwrite, inputs=arm_inputs(source),
    )
    names = [n for n in model.space.names if n not in model.fixed] if model.fixed else None
    rms_torque = args.rms_torque
    if rms_torque is None:
        rms_torque = DEFAULT_RMS_FRACTION * args.max_torque
    elif rms_torque > args.max_torque:
        raise UsageError(
            f"--rms-torque {rms_torque:g} exceeds --max-torque {args.max_torque:g}; the RMS of "
            "a torque cannot exceed its peak"
        )
    dt = model.testbed.dt
    check_size(args.duration / dt + 1, f"--duration {args.duration:g} s at {dt:g} s",
               n_elements=model.testbed.n_elements, limit=max_samples(args.max_samples))
    result = design_input(
        model=model,
        names=names,
        duration=args.duration,
        max_torque=args.max_torque,
        rms_torque=rms_torque,
        max_angle=args.max_angle,
        max_speed=args.max_speed,
        criterion=args.criterion,
        harmonics=args.harmonics,
        max_frequency=args.max_frequency,
        iterations=args.iterations,
        seed=args.seed,
        restarts=args.restarts,
        progress=not args.quiet,
    )
    unidentifiable = [n for n, v in result.intervals.items() if not math.isfinite(v)]
    if unidentifiable:
        raise UsageError(
            f"the designed input leaves {unidentifiable} unidentifiable (infinite intervals) "
            f"within --max-angle {args.max_angle:g} rad and --max-speed {args.max_speed:g} "
            "rad/s; allow more motion; nothing was written"
        )
    rms = result.achieved["rms_torque"]
    comparison = {"designed": {"intervals": result.intervals, "achieved": result.achieved}}
    comparison |= compare_inputs(
        paper_inputs(rms, duration=args.duration, dt=float(result.settings["dt"])),
        model, names=names,
    )
    record, units = result.to_record(out.stem or "designed"), None
    if model.sensors:  # the record the rig would log
        from jaxflex.measured import logged_record, logged_units

        note = {"note": record.metadata["note"].replace(
            "joint_angle and tip_acceleration are", "the sensor channels are"
        )}
        record = logged_record(model, result.nominal, result.time, result.torque,
                               name=record.name,
                               metadata=record.metadata | note | {"rig": model.name})
        units = logged_units(model)
    with all_or_nothing():
        save_record(record, out, overwrite=args.overwrite, units=units)
        if args.plot:
            from jaxflex.plots._style import save_figure
            from jaxflex.plots.design import plot_design

            save_figure(plot_design(result), args.plot, overwrite=args.overwrite)
        if args.plot_intervals:
            from jaxflex.plots._style import save_figure
            from jaxflex.plots.design import plot_intervals

            fig = plot_intervals(comparison, history=result.history, criterion=result.criterion)
            save_figure(fig, args.plot_intervals, overwrite=args.overwrite)
    print(
        f"criterion {result.criterion}: {result.history[0]:.4g} -> {result.history[-1]:.4g} "
        f"in {len(result.history) - 1} steps ({result.wall_time:.1f} s)"
    )
    print(
        "limits: "
        + ", ".join(f"{k} {result.achieved[k]:.4g} <= {v:g}" for k, v in result.limits.items())
    )
    print(interval_table(comparison))
    print(f"paper inputs scaled to the designed input's RMS torque {rms:.4g} N m")
    for path in (out, *plots):
        print(f"wrote {path}")
    return 0
