"""``jaxflex design --max-torque T --rms-torque R --max-angle A --max-speed S --out input.csv``.

Designs a Fourier-series torque that maximises the information about the parameters (see
:mod:`jaxflex.design`), writes it as a record file (torque plus the model's predicted response,
so that it is a valid spec CSV; a ``# note:`` line says the outputs are predictions) and
optionally a figure, and prints the predicted 95 % intervals against the paper's triangular,
pulse and half-sine inputs at the same RMS torque.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from jaxflex._io import check_writable
from jaxflex.cli import UsageError

HELP = "design an excitation torque that maximises the information about the parameters"


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser("design", help=HELP, description=HELP)
    p.add_argument(
        "--duration",
        type=float,
        default=2.0,
        metavar="S",
        help="record length in seconds (default: %(default)s)",
    )
    p.add_argument(
        "--max-torque", type=float, required=True, metavar="NM", help="peak torque limit (N m)"
    )
    p.add_argument(
        "--rms-torque",
        type=float,
        required=True,
        metavar="NM",
        help="RMS torque budget (N m); the paper's inputs are compared at this RMS",
    )
    p.add_argument(
        "--max-angle", type=float, required=True, metavar="RAD", help="joint angle range ±RAD"
    )
    p.add_argument(
        "--max-speed", type=float, required=True, metavar="RAD_S", help="joint speed limit (rad/s)"
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
        type=int,
        metavar="N",
        help="harmonics of 1/duration (default: all up to --max-frequency)",
    )
    p.add_argument(
        "--max-frequency",
        type=float,
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
    p.add_argument("--seed", type=int, default=0, help="seed of the starting phases")
    p.add_argument(
        "--restarts",
        type=int,
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
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from jaxflex.data import save_record
    from jaxflex.design import compare_inputs, design_input, interval_table, paper_inputs

    outputs = [Path(p) for p in (args.out, args.plot, args.plot_intervals) if p]
    if Path(args.out).suffix.lower() not in (".csv", ".npz"):
        raise UsageError(f"{args.out}: the record file must end in .csv or .npz")
    for plot in (args.plot, args.plot_intervals):
        if plot and Path(plot).suffix.lower().lstrip(".") not in ("png", "pdf", "svg"):
            raise UsageError(f"{plot}: a figure must end in .png, .pdf or .svg")
    for path in outputs:  # refuse before minutes of work, not after
        check_writable(path, args.overwrite)
    if len(set(outputs)) != len(outputs):
        raise UsageError("--out, --plot and --plot-intervals must name different files")

    result = design_input(
        duration=args.duration,
        max_torque=args.max_torque,
        rms_torque=args.rms_torque,
        max_angle=args.max_angle,
        max_speed=args.max_speed,
        criterion=args.criterion,
        harmonics=args.harmonics,
        max_frequency=args.max_frequency,
        iterations=args.iterations,
        seed=args.seed,
        restarts=args.restarts,
        progress=True,
    )
    rms = result.achieved["rms_torque"]
    comparison = {"designed": {"intervals": result.intervals, "achieved": result.achieved}}
    comparison |= compare_inputs(
        paper_inputs(rms, duration=args.duration, dt=float(result.settings["dt"]))
    )
    save_record(
        result.to_record(Path(args.out).stem or "designed"), args.out, overwrite=args.overwrite
    )
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
    print(f"wrote {args.out}")
    if args.plot:
        from jaxflex.plots._style import save_figure
        from jaxflex.plots.design import plot_design

        save_figure(plot_design(result), args.plot, overwrite=args.overwrite)
        print(f"wrote {args.plot}")
    if args.plot_intervals:
        from jaxflex.plots._style import save_figure
        from jaxflex.plots.design import plot_intervals

        fig = plot_intervals(comparison, history=result.history, criterion=result.criterion)
        save_figure(fig, args.plot_intervals, overwrite=args.overwrite)
        print(f"wrote {args.plot_intervals}")
    return 0
