"""``jaxflex validate DATA.csv [...] --fit fit.json [--report DIR]``: the model against records.

Simulates the fitted model under each record's measured torque, prints the Table-3-style table
(NRMSE per output, FRF NRMSE, held-out relative error) and, with ``--report``, writes the table,
``comparison.json`` and the figures (one time-domain figure per record and the FRF) into DIR.
"""

from __future__ import annotations

import argparse

from jaxflex.cli import UsageError
from jaxflex.cli._arm import add_window_argument, load_rig_records, validate_with_arm, with_arm
from jaxflex.cli._checks import (
    add_max_samples,
    check_directory,
    check_outputs,
    check_size,
    max_samples,
    positive_float,
    positive_int,
    read_fit,
)
from jaxflex.cli._options import add_quiet_option, add_record_options
from jaxflex.cli.identify import sources

HELP = "compare a fitted model with measured records: metrics table and figures"
"""One-line summary of ``jaxflex validate`` in the command list."""


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser("validate", help=HELP, description=HELP)
    p.add_argument(
        "data", nargs="+", metavar="DATA", help="record files (.csv/.npz) or directories of them"
    )
    p.add_argument(
        "--fit", required=True, metavar="FIT.json", help="fit file written by `jaxflex identify`"
    )
    p.add_argument(
        "--report", metavar="DIR", help="write table.txt, comparison.json and the figures into DIR"
    )
    p.add_argument("--overwrite", action="store_true", help="replace existing report files")
    p.add_argument(
        "--format",
        choices=("png", "pdf", "svg"),
        default="png",
        help="figure file format (default: png)",
    )
    add_record_options(p)
    add_max_samples(p)
    p.add_argument(
        "--t-end",
        type=positive_float,
        metavar="S",
        help="time-domain metrics over 0 <= t <= S seconds (default: 2 s)",
    )
    p.add_argument(
        "--f-max",
        type=positive_float,
        default=15.0,
        metavar="HZ",
        help="upper end of the FRF comparison band (default: %(default)s Hz)",
    )
    p.add_argument(
        "--raw-frf",
        action="store_true",
        help="compare every FRF bin of the band, also those with almost no input "
        "power (default: leave out bins more than 30 dB below the peak)",
    )
    p.add_argument(
        "--encoder-counts",
        type=positive_int,
        metavar="N",
        help="encoder counts per revolution, to report the noise floor",
    )
    p.add_argument(
        "--accel-sigma",
        type=positive_float,
        metavar="S",
        help="accelerometer noise standard deviation (m/s^2), for the noise floor",
    )
    add_window_argument(p)
    add_quiet_option(p)
    p.add_argument("--json", metavar="TABLE.json", help="for a fit made with --arm: the scores")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    import time

    from jaxflex._io import all_or_nothing
    from jaxflex._progress import stage
    from jaxflex.comparison import DEFAULT_T_END, FRFSettings, compare

    model, params, fit = read_fit("--fit", args.fit)
    if with_arm(fit) is not None:
        return validate_with_arm(args, fit, model)
    if args.window is not None or args.json is not None:
        raise UsageError("--window and --json need a fit made with `jaxflex identify --arm`")
    records = load_rig_records(args.data, args)
    check_size(sum(r.n_samples for r in records), f"{len(records)} record(s)",
               n_elements=model.testbed.n_elements, limit=max_samples(args.max_samples))
    nyquist = 0.5 / records.dt
    if args.f_max > nyquist:
        raise UsageError(
            f"--f-max {args.f_max:g} Hz is above the records' Nyquist frequency {nyquist:g} Hz "
            f"(sampled every {records.dt:g} s); give at most --f-max {nyquist:g}"
        )
    targets = []
    if args.report:
        from jaxflex.plots.compare import report_paths

        directory = check_directory("--report", args.report)
        targets = [("--report", p, None) for p in report_paths(records.names, directory,
                                                                args.format)]
    check_outputs(targets, overwrite=args.overwrite, inputs=[*sources(records), args.fit])
    started = time.perf_counter()
    frf = FRFSettings(
        f_max=args.f_max, **({"min_input_db": None, "min_coherence": None} if args.raw_frf else {})
    )
    comparison = compare(
        model,
        params,
        records,
        fit_names=[n for n in fit.record_names if n in records.names],
        t_end=DEFAULT_T_END if args.t_end is None else args.t_end,
        frf=frf,
        encoder_counts=args.encoder_counts,
        accel_sigma=args.accel_sigma,
    )
    seconds = time.perf_counter() - started
    stage(f"compared {len(records)} record(s) with the model ({seconds:.1f} s)", not args.quiet)
    print(comparison.table(), end="")
    if args.report:
        from jaxflex.plots.compare import save_report

        with all_or_nothing():
            paths = save_report(comparison, args.report, overwrite=args.overwrite,
                                fmt=args.format)
        print(f"wrote {len(paths)} files to {args.report}: {', '.join(p.name for p in paths)}")
    return 0
