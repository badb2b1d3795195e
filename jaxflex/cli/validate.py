"""``jaxflex validate DATA.csv [...] --fit fit.json [--report DIR]``: the model against records.

Simulates the fit's rig (the fit carries it whole) under each record's logged input, prints the
Table-3-style table (NRMSE per channel, FRF NRMSE, held-out relative error) and, with
``--report``, writes the table, ``comparison.json`` and the figures (one time-domain figure per
record, every channel in its own unit, and the FRF) into DIR; ``--json`` writes the NRMSE of
each channel of each record. Records of a rig with sensors are read as the rig logged them
(cut to ``--window``, re-zeroed at rest) and scored over the whole record or window; records of
the simulator's outputs over the first ``--t-end`` seconds.
"""

from __future__ import annotations

import argparse

from jaxflex.cli import UsageError
from jaxflex.cli._arm import (
    add_arm_arguments,
    load_rig_records,
    ready_records,
    rig_of,
    windows_of,
)
from jaxflex.cli._checks import (
    JSON_SUFFIXES,
    add_max_samples,
    check_directory,
    check_outputs,
    check_size,
    max_samples,
    positive_float,
    positive_int,
    read_fit,
)
from jaxflex.cli._options import (
    add_initial_state_options,
    add_quiet_option,
    add_record_options,
)
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
        help="time-domain metrics over 0 <= t <= S seconds (default: 2 s for records of the "
        "simulator's outputs, the whole record or window for a rig's sensors)",
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
    p.add_argument(
        "--horizon",
        type=positive_float,
        action="append",
        metavar="S",
        help="also predict S seconds ahead with the model's Kalman filter, beside the "
        "simulation (repeatable; the filter's noise levels: the fit's, else fitted by maximum "
        "likelihood on each record)",
    )
    add_arm_arguments(p)
    add_initial_state_options(p, held_out=True)
    add_quiet_option(p)
    p.add_argument("--json", metavar="TABLE.json",
                   help="write the NRMSE of each channel of each record as JSON")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    import time

    from jaxflex._io import all_or_nothing, write_json
    from jaxflex._progress import stage
    from jaxflex.comparison import DEFAULT_T_END, FRFSettings, compare

    _, params, fit = read_fit("--fit", args.fit)
    model, _ = rig_of(args, fit)
    stated = [o for o, v in (("--encoder-counts", args.encoder_counts),
                             ("--accel-sigma", args.accel_sigma)) if v is not None]
    if stated and model.sensors:
        raise UsageError(f"{stated[0]}: rig {model.name!r} states its sensors' noise (their "
                         "resolution and noise in its arm file), which sets the noise floor")
    # one by one: a held-out record may be sampled at another rate than the fitted one
    records = [r for name in args.data for r in load_rig_records([name], args, model)]
    check_size(sum(r.n_samples for r in records), f"{len(records)} record(s)",
               n_elements=model.testbed.n_elements, limit=max_samples(args.max_samples))
    nyquist = 0.5 / max(r.dt for r in records)
    if args.f_max > nyquist:
        raise UsageError(
            f"--f-max {args.f_max:g} Hz is above the records' Nyquist frequency {nyquist:g} Hz "
            f"(sampled every {max(r.dt for r in records):g} s); give at most --f-max {nyquist:g}"
        )
    names = [r.name for r in records]
    targets = [("--json", args.json, JSON_SUFFIXES)]
    if args.report:
        from jaxflex.plots.compare import report_paths

        directory = check_directory("--report", args.report)
        targets += [("--report", p, None) for p in report_paths(names, directory, args.format)]
        if args.horizon:
            targets += [("--report", p, None)
                        for p in prediction_paths(names, directory, args.format)]
    json_target, *_ = check_outputs(
        targets, overwrite=args.overwrite, inputs=[*sources(records), args.fit]
    ) or [None]
    json_target = json_target if args.json is not None else None
    windows = windows_of(args, model, records)
    moving = fit.initial_state != "rest" or args.initial_state != "rest"
    ready = ready_records(model, records, windows, at_rest=not moving)
    horizons = check_horizons(args.horizon or [], ready)
    t_end = args.t_end if args.t_end is not None or model.sensors else DEFAULT_T_END
    frf = FRFSettings(
        f_max=args.f_max, **({"min_input_db": None, "min_coherence": None} if args.raw_frf else {})
    )
    started = time.perf_counter()
    comparison = compare(
        ready,
        model,
        params,
        fit_names=comparison_fit_names(fit, names),
        t_end=t_end,
        frf=frf,
        encoder_counts=args.encoder_counts,
        accel_sigma=args.accel_sigma,
        initial_states={n: list(z.values()) for n, z in fit.initial_states.items()
                        if n in names},
        initial_state=args.initial_state,
        initial_modes=args.initial_modes,
    )
    seconds = time.perf_counter() - started
    stage(f"compared {len(records)} record(s) with the model ({seconds:.1f} s)", not args.quiet)
    print(comparison.table(), end="")
    predictions = []
    if horizons:
        from jaxflex.prediction_report import compare_predictions, prediction_table

        predictions = compare_predictions(
            ready, model, params, horizons, fit_names=comparison_fit_names(fit, names),
            channels=comparison.channels, **filter_noise(fit))
        print(prediction_table(predictions, comparison.units), end="")
    with all_or_nothing():
        if json_target is not None:
            rows = [{"name": r.name, "role": r.role, "nrmse": dict(r.nrmse)}
                    for r in comparison.rows]
            write_json(json_target, {"rig": model.name, "t_end": t_end, "windows": {
                r.name: w for r, w in zip(records, windows, strict=True)},
                                     "records": rows} | ({"prediction": [
                                         p.to_dict() for p in predictions]} if horizons else {}),
                       overwrite=args.overwrite)
        if args.report:
            from jaxflex.plots.compare import save_report

            paths = save_report(comparison, args.report, overwrite=args.overwrite,
                                fmt=args.format)
            if predictions:
                paths += save_predictions(predictions, comparison.units, args.report,
                                          overwrite=args.overwrite, fmt=args.format)
    if json_target is not None:
        print(f"wrote {json_target}")
    if args.report:
        print(f"wrote {len(paths)} files to {args.report}: {', '.join(p.name for p in paths)}")
    return 0


def comparison_fit_names(fit, names) -> list[str]:
    """The records given that the fit was made on."""
    return [n for n in fit.record_names if n in names]


def check_horizons(horizons, records) -> list[float]:
    """``--horizon`` values, each at least one sample and shorter than every record (one line
    naming it)."""
    if not horizons:
        return []
    from jaxflex.kalman import horizon_steps

    for record in records:
        try:
            horizon_steps(horizons, record.dt, [record])
        except ValueError as exc:
            raise UsageError(f"--{exc}") from None
    return list(horizons)


def filter_noise(fit) -> dict[str, object]:
    """The Kalman filter's noise levels a prediction-error fit carries; none otherwise."""
    settings = fit.settings
    if "disturbance" not in settings:
        return {}
    return {"disturbance": settings["disturbance"], "noise": settings["measurement_noise"]}


def prediction_paths(names, directory, fmt: str):
    """``prediction.json`` and one ``<record>_prediction.<fmt>`` figure per record."""
    from pathlib import Path

    from jaxflex._io import safe_stem

    directory = Path(directory)
    return [directory / "prediction.json"] + [
        directory / f"{safe_stem(n)}_prediction.{fmt}" for n in names]


def save_predictions(rows, units, directory, *, overwrite: bool, fmt: str) -> tuple:
    """Write ``prediction.json`` and the prediction figures; returns the paths."""
    from jaxflex._io import write_json
    from jaxflex.plots._style import save_figure
    from jaxflex.plots.prediction import plot_prediction

    paths = prediction_paths([r.name for r in rows], directory, fmt)
    write_json(paths[0], {"records": [r.to_dict() for r in rows]}, overwrite=overwrite)
    for row, path in zip(rows, paths[1:], strict=True):
        save_figure(plot_prediction(row, units=units), path, overwrite=overwrite)
    return tuple(paths)
