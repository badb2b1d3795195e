"""``jaxflex study DATA.csv [...] --seeds 0-9 --out study.json``: the paper's seed study.

Runs DE, GA and PSO (or the ``--methods`` given) from every seed on the same records, prints the
paper-like table (mean ± std of each parameter over seeds, final objective, wall time) and writes
the runs as JSON and, with ``--plot``, the convergence curves.
"""

from __future__ import annotations

import argparse

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
from jaxflex.cli._checks import FIGURE_SUFFIXES, JSON_SUFFIXES, MAX_SEED, check_outputs
from jaxflex.cli._options import fit_keywords
from jaxflex.cli._processes import enter
from jaxflex.cli.identify import add_search_arguments, check_finite_cost, sources

MAX_SEEDS = 1000
"""More seeds than this is a typing error (``0-1000000``), not a study."""
HELP = "run each evolutionary method from several seeds and tabulate the spread (paper study)"
"""One-line summary of ``jaxflex study`` in the command list."""


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser("study", help=HELP, description=HELP)
    add_search_arguments(p)
    p.add_argument("--methods", default="de,ga,pso", metavar="LIST",
                   help="comma-separated methods (default: %(default)s)")
    p.add_argument("--seeds", default="0-9", metavar="SEEDS",
                   help="seeds as a range and/or list, e.g. 0-9 or 0,3,7 (default: %(default)s)")
    p.add_argument("--out", required=True, metavar="STUDY.json", help="where to write the runs")
    p.add_argument("--plot", metavar="FIG.png", help="also write the convergence curves")
    add_arm_arguments(p)
    p.set_defaults(func=run)


def parse_seeds(text: str) -> list[int]:
    """``"0-9"`` → 0..9, ``"1,4,7"`` → [1, 4, 7], mixes allowed (``"0-2,9"``)."""
    seeds: list[int] = []
    for part in text.split(","):
        part = part.strip()
        lo, sep, hi = part.partition("-")
        try:
            values = range(int(lo), int(hi) + 1) if sep else [int(part)]
        except ValueError:
            raise UsageError(f"--seeds {text!r}: expected e.g. 0-9 or 0,3,7") from None
        if sep and int(hi) < int(lo):
            raise UsageError(f"--seeds {part!r}: the range runs backwards")
        if len(seeds) + len(values) > MAX_SEEDS:
            raise UsageError(f"--seeds {text!r}: more than {MAX_SEEDS} seeds")
        seeds.extend(values)
    if any(not 0 <= s <= MAX_SEED for s in seeds) or len(set(seeds)) != len(seeds):
        raise UsageError(f"--seeds {text!r}: seeds must be distinct and in [0, {MAX_SEED}]")
    return seeds


def parse_methods(text: str) -> list[str]:
    """``"de,ga"`` → ``["de", "ga"]``; unknown or repeated methods are refused."""
    from jaxflex.identification import METHODS

    methods = [m.strip().lower() for m in text.split(",") if m.strip()]
    if not methods:
        raise UsageError(f"--methods {text!r}: name at least one of {', '.join(METHODS)}")
    for i, m in enumerate(methods):
        if m not in METHODS:
            raise UsageError(f"--methods: unknown method {m!r}; choose from {', '.join(METHODS)}")
        if m in methods[:i]:
            raise UsageError(f"--methods {text!r}: {m!r} given twice; each run would count twice")
    return methods


def run(args: argparse.Namespace) -> int:
    import dataclasses

    from jaxflex import identify
    from jaxflex._io import all_or_nothing
    from jaxflex.distributed import is_main
    from jaxflex.identification import FitError
    from jaxflex.study import run_study

    if (status := enter(args)) is not None:
        return status
    methods = parse_methods(args.methods)
    seeds = parse_seeds(args.seeds)
    rig, source = rig_of(args)
    model = with_effects(rig, args.effect)
    records = load_rig_records(args.data, args, model)
    out, *plot = check_outputs(
        [("--out", args.out, JSON_SUFFIXES), ("--plot", args.plot, FIGURE_SUFFIXES)],
        overwrite=args.overwrite, inputs=[*sources(records), *arm_inputs(source)],
    )
    keywords = fit_keywords(args, identify)
    windows = windows_of(args, model, records)
    ready = ready_records(model, records, windows, at_rest=args.initial_state == "rest")
    try:
        study = run_study(
            ready,
            methods,
            seeds,
            model=model,
            generations=args.generations,
            population=args.population,
            refine=args.refine,
            progress=not args.quiet,
            tol=args.tol,
            **keywords,
        )
    except FitError as err:
        check_finite_cost(err.cost, "bounds" in keywords)
        raise
    for r in study.runs:
        check_finite_cost(r.cost, "bounds" in keywords)
    if not is_main():
        return 0
    rig = rig_settings(model, source, records, windows)
    study = dataclasses.replace(study, settings=study.settings | rig)
    print(study.table(), end="")
    with all_or_nothing():
        study.to_json(out, overwrite=args.overwrite)
        if plot:
            from jaxflex.plots._style import save_figure
            from jaxflex.plots.identify import plot_convergence

            save_figure(plot_convergence(study.histories()), plot[0], overwrite=args.overwrite)
    for path in (out, *plot):
        print(f"wrote {path}")
    return 0
