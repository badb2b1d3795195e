"""``jaxflex study DATA.csv [...] --seeds 0-9 --out study.json``: the paper's seed study.

Runs DE, GA and PSO (or the ``--methods`` given) from every seed on the same records, prints the
paper-like table (mean ± std of each parameter over seeds, final objective, wall time) and writes
the runs as JSON and, with ``--plot``, the convergence curves.
"""

from __future__ import annotations

import argparse

from jaxflex.cli import UsageError, load_records
from jaxflex.cli.identify import (
    _check_figure,
    add_search_arguments,
    model_from,
    search_options,
)

HELP = "run each evolutionary method from several seeds and tabulate the spread (paper study)"


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser("study", help=HELP, description=HELP)
    add_search_arguments(p)
    p.add_argument("--methods", default="de,ga,pso", metavar="LIST",
                   help="comma-separated methods (default: %(default)s)")
    p.add_argument("--seeds", default="0-9", metavar="SEEDS",
                   help="seeds as a range and/or list, e.g. 0-9 or 0,3,7 (default: %(default)s)")
    p.add_argument("--out", required=True, metavar="STUDY.json", help="where to write the runs")
    p.add_argument("--plot", metavar="FIG.png", help="also write the convergence curves")
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
        seeds.extend(values)
    if any(s < 0 for s in seeds) or len(set(seeds)) != len(seeds):
        raise UsageError(f"--seeds {text!r}: seeds must be distinct and >= 0")
    return seeds


def run(args: argparse.Namespace) -> int:
    from jaxflex._io import check_writable
    from jaxflex.study import run_study

    out = check_writable(args.out, args.overwrite)
    plot = None if args.plot is None else _check_figure(args.plot, args.overwrite)
    methods = [m.strip() for m in args.methods.split(",") if m.strip()]
    seeds = parse_seeds(args.seeds)
    records = load_records(args.data, resample=args.resample)
    study = run_study(
        records,
        methods,
        seeds,
        model=model_from(args.effect),
        generations=args.generations,
        population=args.population,
        refine=args.refine,
        progress=not args.quiet,
        **search_options(args),
    )
    print(study.table(), end="")
    study.to_json(out, overwrite=args.overwrite)
    print(f"wrote {out}")
    if plot is not None:
        from jaxflex.plots._style import save_figure
        from jaxflex.plots.identify import plot_convergence

        save_figure(plot_convergence(study.histories()), plot, overwrite=args.overwrite)
        print(f"wrote {plot}")
    return 0
