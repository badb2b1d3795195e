"""``jaxflex discover DATA.csv [...]``: find which physical effects the model is missing.

Fits the base model (or starts from ``--initial FIT.json``), then adds one effect at a time
while a score test finds a significant candidate that a refit confirms, and reports what stays
unexplained. Prints the step table; ``--json`` writes the machine-readable result
(``{"steps": [...], "ranking": [...], "unexplained": ...}``), ``--report DIR`` the table, the
JSON and the figures.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from jaxflex._io import check_writable, write_json
from jaxflex.cli import UsageError, load_records
from jaxflex.model import Model

HELP = "find the physical effects the model is missing: score tests, add, refit, report"


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser("discover", help=HELP, description=HELP)
    p.add_argument("data", nargs="+", metavar="DATA",
                   help="record files (.csv/.npz) or directories of them to fit")
    p.add_argument("--holdout", nargs="+", metavar="DATA", default=(),
                   help="records held out to validate every step")
    p.add_argument("--effects", metavar="NAME,...",
                   help="candidate effects, comma-separated (default: the whole library)")
    p.add_argument("--max-steps", type=int, default=4, metavar="N",
                   help="add at most N effects (default: %(default)s)")
    p.add_argument("--alpha", type=float, default=0.01,
                   help="significance level of each step, Bonferroni over the candidates "
                        "(default: %(default)s)")
    p.add_argument("--initial", metavar="FIT.json",
                   help="start from this fit (a fit file of `jaxflex identify`, or a JSON "
                        "object of parameter values) instead of identifying the base model")
    p.add_argument("--generations", type=int, metavar="N",
                   help="differential-evolution generations for the base model (default 100)")
    p.add_argument("--seed", type=int, default=0, help="random seed (default: %(default)s)")
    p.add_argument("--json", metavar="OUT.json", help="write the result as JSON")
    p.add_argument("--report", metavar="DIR", help="write table, JSON and figures into DIR")
    p.add_argument("--format", choices=("png", "pdf", "svg"), default="png",
                   help="figure file format (default: png)")
    p.add_argument("--overwrite", action="store_true", help="replace existing output files")
    p.add_argument("--resample", action="store_true",
                   help="resample records whose time column is not uniform")
    p.add_argument("--progress", action="store_true", help="show progress on the terminal")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from jaxflex.discover import candidate_set, discover

    if args.max_steps < 0:
        raise UsageError(f"--max-steps must be >= 0, got {args.max_steps}")
    if not 0 < args.alpha < 1:
        raise UsageError(f"--alpha must lie in (0, 1), got {args.alpha}")
    if args.generations is not None and args.generations < 1:
        raise UsageError(f"--generations must be >= 1, got {args.generations}")
    candidates = None
    if args.effects:
        candidates = [n.strip() for n in args.effects.split(",") if n.strip()]
        candidate_set(candidates)  # unknown names fail here, listing the known ones
    if args.json:
        check_writable(args.json, args.overwrite)
    records = load_records(args.data, resample=args.resample)
    holdout = load_records(args.holdout, resample=args.resample) if args.holdout else None
    model, initial = None, None
    if args.initial:
        model, initial = _load_fit(Path(args.initial))
    report = discover(
        records, holdout=holdout, model=model, candidates=candidates,
        max_steps=args.max_steps, alpha=args.alpha, seed=args.seed, progress=args.progress,
        initial=initial, budget=args.generations,
    )
    print(report.table(), end="")
    for line in report.explanations():
        print(f"  {line}")
    if args.json:
        write_json(args.json, report.to_dict(), overwrite=args.overwrite)
        print(f"wrote {args.json}")
    if args.report:
        from jaxflex.plots.discover import save_discovery_report

        paths = save_discovery_report(report, args.report, overwrite=args.overwrite,
                                      fmt=args.format)
        print(f"wrote {len(paths)} files to {args.report}: {', '.join(p.name for p in paths)}")
    return 0


def _load_fit(path: Path):
    """(model, parameters) from a fit file of ``jaxflex identify`` or a JSON object mapping
    parameter names to values (the reference testbed's model)."""
    if not path.is_file():
        raise UsageError(f"{path}: fit file not found (write one with `jaxflex identify`)")
    try:
        data = json.loads(path.read_text())
    except (OSError, json.JSONDecodeError) as exc:
        raise UsageError(f"{path}: not a JSON file ({exc})") from None
    try:
        if isinstance(data, dict) and data and all(
            isinstance(v, (int, float)) for v in data.values()
        ):
            model = Model()
            params = {k: float(v) for k, v in data.items()}
        else:
            from jaxflex.identify import load_fit

            fit = load_fit(path)
            model, params = fit.model(), fit.params
        model.space.validate(params)
    except (ValueError, KeyError, TypeError) as exc:
        message = str(exc.args[0] if isinstance(exc, KeyError) and exc.args else exc)
        raise UsageError(f"cannot use the fit {path}: {message}") from None
    return model, params
