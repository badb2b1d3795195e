"""``jaxflex identify DATA.csv [...] --method de --out fit.json``: identify the arm's parameters.

Loads the records, runs the evolutionary search (paper settings) with one batched evaluation
per generation, refines the best candidate with Levenberg–Marquardt, estimates the intervals,
prints the result table and writes ``fit.json`` (and optionally a figure) atomically.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from jaxflex.cli import UsageError, load_records
from jaxflex.cli._arm import add_window_argument, identify_with_arm

HELP = "identify the parameters from measured records (DE, GA or PSO + refinement)"


def add_search_arguments(p: argparse.ArgumentParser) -> None:
    """Arguments shared by ``identify`` and ``study``: data, model and search settings."""
    p.add_argument("data", nargs="+", metavar="DATA",
                   help="record files (.csv/.npz) or directories of them")
    p.add_argument("--generations", type=int, default=100, metavar="G",
                   help="generations of the search (default: %(default)s)")
    p.add_argument("--population", type=int, metavar="P",
                   help="population size (default: the paper's, 100)")
    p.add_argument("--no-refine", dest="refine", action="store_false",
                   help="skip the Levenberg-Marquardt refinement")
    p.add_argument("--effect", action="append", default=[], metavar="NAME",
                   help="add a physical effect to the model (repeatable), e.g. payload")
    p.add_argument("--bound", action="append", default=[], metavar="NAME=LO:HI",
                   help="search bounds of a parameter (repeatable), e.g. J_h=1e-3:1e-2")
    p.add_argument("--fix", action="append", default=[], metavar="NAME=VALUE",
                   help="hold a parameter at a value (repeatable)")
    p.add_argument("--weight", action="append", default=[], metavar="CHANNEL=W",
                   help="weight of an output channel (repeatable; default 1 each)")
    p.add_argument("--resample", action="store_true",
                   help="resample records whose time column is not uniform")
    p.add_argument("--overwrite", action="store_true", help="replace existing output files")
    p.add_argument("--quiet", action="store_true", help="no progress bar")


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser("identify", help=HELP, description=HELP)
    add_search_arguments(p)
    p.add_argument("--method", choices=("de", "ga", "pso"), default="de",
                   help="evolutionary algorithm (default: %(default)s)")
    p.add_argument("--seed", type=int, default=0, metavar="N",
                   help="random seed of the search (default: %(default)s)")
    p.add_argument("--refine-starts", type=int, default=1, metavar="K",
                   help="refine from the K best candidates (default: %(default)s)")
    p.add_argument("--out", required=True, metavar="FIT.json", help="where to write the fit")
    p.add_argument("--plot", metavar="FIG.png",
                   help="also write a figure: convergence and parameter intervals")
    p.add_argument("--arm", metavar="ARM.toml", help="the rig's arm file (see jaxflex.arm)")
    add_window_argument(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from jaxflex._io import check_writable
    from jaxflex.identify import identify

    if args.arm is not None or args.window is not None:
        if args.arm is None or args.plot is not None:
            raise UsageError("--window needs --arm; --plot is not available with --arm")
        return identify_with_arm(args)
    out = check_writable(args.out, args.overwrite)
    plot = None if args.plot is None else _check_figure(args.plot, args.overwrite)
    records = load_records(args.data, resample=args.resample)
    fit = identify(
        records,
        model_from(args.effect),
        method=args.method,
        seed=args.seed,
        generations=args.generations,
        population=args.population,
        refine=args.refine,
        progress=not args.quiet,
        refine_starts=args.refine_starts,
        **search_options(args),
    )
    print(fit.summary(), end="")
    fit.to_json(out, overwrite=args.overwrite)
    print(f"wrote {out}")
    if plot is not None:
        from jaxflex.plots._style import save_figure
        from jaxflex.plots.identify import plot_fit

        save_figure(plot_fit(fit), plot, overwrite=args.overwrite)
        print(f"wrote {plot}")
    return 0


def model_from(effects: list[str]):
    """The reference model with the named effects added."""
    from jaxflex.effects import get_effect
    from jaxflex.model import Model

    return Model().with_effects(*(get_effect(name) for name in effects))


def _pairs(items: list[str], option: str) -> dict[str, str]:
    pairs = {}
    for item in items:
        name, sep, value = item.partition("=")
        if not sep or not name.strip() or not value.strip():
            raise UsageError(f"{option} {item!r}: expected NAME=VALUE")
        if name.strip() in pairs:
            raise UsageError(f"{option}: {name.strip()!r} given twice")
        pairs[name.strip()] = value.strip()
    return pairs


def _number(text: str, option: str) -> float:
    try:
        return float(text)
    except ValueError:
        raise UsageError(f"{option}: {text!r} is not a number") from None


def search_options(args: argparse.Namespace) -> dict:
    """``bounds``, ``fixed`` and ``weights`` for :func:`identify` from the repeatable options."""
    bounds = {}
    for name, value in _pairs(args.bound, "--bound").items():
        lo, sep, hi = value.partition(":")
        if not sep:
            raise UsageError(f"--bound {name}={value!r}: expected NAME=LO:HI")
        bounds[name] = (_number(lo, "--bound"), _number(hi, "--bound"))
    fixed = {k: _number(v, "--fix") for k, v in _pairs(args.fix, "--fix").items()}
    weights = {k: _number(v, "--weight") for k, v in _pairs(args.weight, "--weight").items()}
    return {"bounds": bounds or None, "fixed": fixed or None, "weights": weights or None}


def _check_figure(path: str, overwrite: bool) -> Path:
    from jaxflex._io import check_writable
    from jaxflex.plots._style import FORMATS

    figure = check_writable(path, overwrite)
    if figure.suffix.lower().lstrip(".") not in FORMATS:
        raise UsageError(f"--plot {path}: use a .png, .pdf or .svg file name")
    return figure
