"""``jaxflex identify DATA.csv [...] --method de --out fit.json``: identify the arm's parameters.

Loads the records, runs the evolutionary search (paper settings) with one batched evaluation
per generation, refines the best candidate with Levenberg–Marquardt, estimates the intervals,
prints the result table and writes ``fit.json`` (and optionally a figure) atomically.
"""

from __future__ import annotations

import argparse
import math

from jaxflex.cli import UsageError
from jaxflex.cli._arm import (
    add_arm_arguments,
    arm_inputs,
    load_rig_records,
    ready_records,
    rig_of,
    rig_settings,
    windows_of,
    with_effects,
)
from jaxflex.cli._checks import (
    FIGURE_SUFFIXES,
    JSON_SUFFIXES,
    check_outputs,
    positive_float,
    positive_int,
    read_fit,
    seed,
)
from jaxflex.cli._options import (
    add_fit_options,
    add_quiet_option,
    add_record_options,
    fit_keywords,
)
from jaxflex.cli._processes import add_process_arguments, enter

HELP = "identify the parameters from measured records (DE, GA or PSO + refinement)"
"""One-line summary of ``jaxflex identify`` in the command list."""


def add_search_arguments(p: argparse.ArgumentParser) -> None:
    """Arguments shared by ``identify`` and ``study``: data, model and search settings."""
    p.add_argument("data", nargs="+", metavar="DATA",
                   help="record files (.csv/.npz) or directories of them")
    p.add_argument("--generations", type=positive_int, default=100, metavar="G",
                   help="generations of the search (default: %(default)s)")
    p.add_argument("--population", type=positive_int, metavar="P",
                   help="population size (default: the paper's, 100)")
    p.add_argument("--tol", type=positive_float, metavar="T",
                   help="stop the search early once the population's costs agree to T "
                        "(standard deviation <= T x |mean|, as SciPy's differential_evolution); "
                        "default: every generation runs")
    p.add_argument("--no-refine", dest="refine", action="store_false",
                   help="skip the Levenberg-Marquardt refinement")
    add_fit_options(p)
    add_record_options(p)
    p.add_argument("--overwrite", action="store_true", help="replace existing output files")
    add_quiet_option(p)
    add_process_arguments(p)


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser("identify", help=HELP, description=HELP)
    add_search_arguments(p)
    p.add_argument("--method", choices=("de", "ga", "pso"), default="de",
                   help="evolutionary algorithm (default: %(default)s)")
    p.add_argument("--seed", type=seed, default=0, metavar="N",
                   help="random seed of the search (default: %(default)s)")
    p.add_argument("--refine-starts", type=positive_int, default=1, metavar="K",
                   help="refine from the K best candidates (default: %(default)s)")
    p.add_argument("--out", required=True, metavar="FIT.json", help="where to write the fit")
    p.add_argument("--initial", metavar="FIT.json",
                   help="start from a fit (`identify --out` or `discover --out`): its rig and "
                        "effects, its parameters seeding the search")
    p.add_argument("--criterion", choices=("output", "prediction"), default="output",
                   help="fit the free simulation (output error, the default) or the Kalman "
                        "filter's one-step predictions (prediction error: closed-loop records, "
                        "a free rigid-body mode)")
    p.add_argument("--disturbance", type=positive_float, metavar="NM",
                   help="with --criterion prediction: the filter's process-noise torque (N m "
                        "per sample; default: fitted by maximum likelihood)")
    p.add_argument("--plot", metavar="FIG.png",
                   help="also write figures: convergence and parameter intervals in FIG.png, "
                        "and each record against the fit, every channel in its unit, with the "
                        "residual, in FIG_<record>.png")
    add_arm_arguments(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    import dataclasses

    from jaxflex._io import all_or_nothing
    from jaxflex.distributed import is_main
    from jaxflex.identification import identify
    from jaxflex.kalman import check_disturbance

    if args.disturbance is not None and args.criterion != "prediction":
        raise UsageError("--disturbance sets the Kalman filter's noise: give --criterion "
                         "prediction with it")
    check_disturbance(args.disturbance)
    if (status := enter(args)) is not None:
        return status
    initial = None
    if args.initial:
        if args.effect:
            raise UsageError("--effect with --initial: the fit file fixes the model's effects")
        initial = read_fit("--initial", args.initial)[2]
    rig, source = rig_of(args, initial)
    model = with_effects(rig, args.effect)
    records = load_rig_records(args.data, args, model)
    out, *plot = check_outputs(
        [("--out", args.out, JSON_SUFFIXES), ("--plot", args.plot, FIGURE_SUFFIXES)]
        + [("--plot", p, FIGURE_SUFFIXES) for p in record_figures(args.plot, records)],
        overwrite=args.overwrite,
        inputs=[*sources(records), *arm_inputs(source), *([args.initial] if initial else [])],
    )
    windows = windows_of(args, model, records)
    ready = ready_records(model, records, windows, at_rest=args.initial_state == "rest")
    criterion = {} if args.criterion == "output" else {"criterion": args.criterion,
                                                        "disturbance": args.disturbance}
    seeded = {} if initial is None else {"init_population": initial}
    fit = search(args, ready, model, fit_keywords(args, identify) | criterion | seeded)
    if not is_main():
        return 0
    rig = rig_settings(model, source, records, windows)
    fit = dataclasses.replace(fit, settings=fit.settings | rig)
    report_fit(fit)
    with all_or_nothing():
        fit.to_json(out, overwrite=args.overwrite)
        if plot:
            from jaxflex.comparison import compare
            from jaxflex.plots._style import save_figure
            from jaxflex.plots.compare import plot_time
            from jaxflex.plots.identify import plot_fit

            save_figure(plot_fit(fit), plot[0], overwrite=args.overwrite)
            # each record from the state the fit used: rest, or its estimated coordinates
            comparison = compare(ready, fit.model, fit.params, fit_names=fit.record_names,
                                 t_end=None, channels=fit.settings["channels"],
                                 initial_states={n: list(z.values())
                                                 for n, z in fit.initial_states.items()})
            for i, path in enumerate(plot[1:]):
                save_figure(plot_time(comparison, i), path, overwrite=args.overwrite)
    for path in (out, *plot):
        print(f"wrote {path}")
    return 0


def record_figures(plot: str | None, records) -> list[str]:
    """``FIG_<record>.<suffix>`` beside ``--plot FIG.<suffix>``, one per record."""
    if plot is None:
        return []
    from pathlib import Path

    from jaxflex._io import safe_stem

    path = Path(plot)
    return [str(path.with_name(f"{path.stem}_{safe_stem(r.name)}{path.suffix}")) for r in records]


def search(args: argparse.Namespace, records, model, keywords: dict):
    """:func:`jaxflex.identify` with the command's search settings; a fit whose cost is not
    finite is refused before anything is written."""
    from jaxflex.identification import FitError, identify

    try:
        fit = identify(
            records,
            model,
            method=args.method,
            seed=args.seed,
            generations=args.generations,
            population=args.population,
            refine=args.refine,
            progress=not args.quiet,
            refine_starts=args.refine_starts,
            tol=args.tol,
            **keywords,
        )
    except FitError as err:
        check_finite_cost(err.cost, "bounds" in keywords)
        raise
    check_finite_cost(fit.cost, "bounds" in keywords)
    return fit


def report_fit(fit) -> None:
    """Print the fit's table; its warnings (poorly identified parameters, a refinement out of
    steps) go out as the command's one-line warnings, on stderr."""
    import dataclasses
    import warnings

    print(dataclasses.replace(fit, warnings=()).summary(), end="")
    for message in fit.warnings:
        warnings.warn(message, stacklevel=1)


def sources(records) -> list[str]:
    """The files the records were read from (outputs may not replace them)."""
    return [r.source for r in records if r.source is not None]


def check_finite_cost(cost: float, bounded: bool) -> None:
    """Refuse to write a fit whose cost is not finite: the simulation failed everywhere."""
    if not math.isfinite(cost):
        hint = "narrow the --bound ranges" if bounded else "check the records and --effect"
        raise UsageError(
            f"the fit failed: its cost is {cost} (the simulation diverged for every candidate); "
            f"{hint}; nothing was written"
        )
