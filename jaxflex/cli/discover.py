"""``jaxflex discover DATA.csv [...]``: find which physical effects the model is missing.

Fits the base model (or starts from ``--initial FIT.json``), then adds one effect at a time
while a score test finds a significant candidate that a refit confirms, and reports what stays
unexplained. Prints the step table, the explanations and the final model (each parameter with
its 95 % interval and unit, as ``identify`` prints a fit); ``--json`` writes the
machine-readable result (``{"steps": [...], "ranking": [...], "unexplained": ...}``),
``--report DIR`` the table, the JSON and the figures, ``--out FIT.json`` the final model as a
fit file (:meth:`jaxflex.discovery.DiscoveryReport.to_fit`), which ``validate --fit``,
``discover --initial`` and ``identify --initial`` read.
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
    sensor_noise,
    windows_of,
    with_effects,
)
from jaxflex.cli._checks import (
    JSON_SUFFIXES,
    check_directory,
    check_outputs,
    positive_int,
    read_fit,
    seed,
)
from jaxflex.cli._options import (
    add_fit_options,
    add_quiet_option,
    add_record_options,
    add_renamed_option,
    fit_keywords,
)
from jaxflex.cli.identify import sources

HELP = "find the physical effects the model is missing: score tests, add, refit, report"
"""One-line summary of ``jaxflex discover`` in the command list."""


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser("discover", help=HELP, description=HELP)
    p.add_argument("data", nargs="+", metavar="DATA",
                   help="record files (.csv/.npz) or directories of them to fit")
    p.add_argument("--holdout", nargs="+", metavar="DATA", default=(),
                   help="records held out to validate every step")
    p.add_argument("--candidates", metavar="NAME,...",
                   help="candidate effects, comma-separated (default: the whole library)")
    add_renamed_option(p, "--effects", "--candidates")
    p.add_argument("--max-steps", type=int, default=4, metavar="N",
                   help="add at most N effects (default: %(default)s)")
    p.add_argument("--alpha", type=float, default=0.01,
                   help="significance level of each step, Bonferroni over the candidates "
                        "(default: %(default)s)")
    p.add_argument("--initial", metavar="FIT.json",
                   help="start from this fit (a fit file of `jaxflex identify`, or a JSON "
                        "object of parameter values) instead of identifying the base model")
    p.add_argument("--generations", type=positive_int, metavar="N",
                   help="differential-evolution generations for the base model (default 100)")
    p.add_argument("--seed", type=seed, default=0, help="random seed (default: %(default)s)")
    p.add_argument("--no-torque-map", dest="torque_map", action="store_false",
                   help="where the library explains nothing, do not map the missing torque "
                        "nor refit its formula (by default it is mapped, and its formula "
                        "added when it lowers the held-out error)")
    add_fit_options(p)
    p.add_argument("--json", metavar="OUT.json", help="write the result as JSON")
    p.add_argument("--out", metavar="FIT.json",
                   help="write the final model (its effects, parameters and 95 %% intervals) "
                        "as a fit file, as `jaxflex identify --out` does: `validate --fit`, "
                        "`discover --initial` and `identify --initial` read it")
    p.add_argument("--report", metavar="DIR", help="write table, JSON and figures into DIR")
    p.add_argument("--format", choices=("png", "pdf", "svg"), default="png",
                   help="figure file format (default: png)")
    p.add_argument("--overwrite", action="store_true", help="replace existing output files")
    add_record_options(p)
    add_quiet_option(p)
    add_renamed_option(p, "--progress", "the default (--quiet turns it off)")
    add_arm_arguments(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    import dataclasses

    from jaxflex._io import all_or_nothing, same_file, write_json
    from jaxflex.discovery import candidate_set, discover

    if args.max_steps < 0:
        raise UsageError(f"--max-steps must be >= 0, got {args.max_steps}")
    if not 0 < args.alpha < 1:
        raise UsageError(f"--alpha must lie in (0, 1), got {args.alpha}")
    candidates = None
    if args.candidates:
        candidates = [n.strip() for n in args.candidates.split(",") if n.strip()]
        candidate_set(candidates)  # unknown names fail here, listing the known ones
    keywords = fit_keywords(args, discover)
    initial, fit = None, None
    if args.initial:
        if args.effect:
            raise UsageError("--effect with --initial: the fit file fixes the model's effects")
        _, initial, fit = read_fit("--initial", args.initial, plain_parameters=True)
    rig, source = rig_of(args, fit)
    model = with_effects(rig, args.effect)
    records = load_rig_records(args.data, args, model)
    holdout = None
    if args.holdout:
        holdout = load_rig_records(args.holdout, args, model)
        for r in holdout:
            if any(same_file(r.source, f.source) for f in records):
                raise UsageError(f"--holdout {r.source}: is also a record to fit; a held-out "
                                 "record must not be fitted")
    targets = [("--json", args.json, JSON_SUFFIXES), ("--out", args.out, JSON_SUFFIXES)]
    if args.report:
        from jaxflex.plots.discover import report_paths

        directory = check_directory("--report", args.report)
        names = [*records.names, *(holdout.names if holdout else ())]
        targets += [("--report", p, None) for p in report_paths(names, directory, args.format)]
    check_outputs(targets, overwrite=args.overwrite,
                  inputs=[*sources(records), *sources(holdout or ()), args.initial,
                          *arm_inputs(source)])
    at_rest = args.initial_state == "rest"
    windows = windows_of(args, model, records)
    rig = rig_settings(model, source, records, windows)
    records = ready_records(model, records, windows, at_rest=at_rest)
    if holdout is not None:
        holdout = ready_records(model, holdout, windows_of(args, model, holdout),
                                at_rest=at_rest)
    if model.sensors:  # records as logged: the sensors' noise, scored over the whole record
        keywords["noise"] = sensor_noise(model, records) | (
            keywords.get("noise") or {})
        keywords["t_end"] = None
    report = discover(
        records, holdout=holdout, model=model, candidates=candidates,
        max_steps=args.max_steps, alpha=args.alpha, seed=args.seed, progress=not args.quiet,
        initial=initial, budget=args.generations, torque_map=args.torque_map, **keywords,
    )
    print(report.table(), end="")
    for line in report.explanations():
        print(f"  {line}")
    print(report.summary(), end="")
    paths = []
    with all_or_nothing():
        if args.out:
            fit = report.to_fit()
            dataclasses.replace(fit, settings=fit.settings | rig).to_json(
                args.out, overwrite=args.overwrite)
        if args.json:
            paths.append(write_json(args.json, report.to_dict(), overwrite=args.overwrite))
        if args.report:
            from jaxflex.plots.discover import save_discovery_report

            paths += save_discovery_report(report, args.report, overwrite=args.overwrite,
                                           fmt=args.format)
    for path in (args.out, args.json):
        if path:
            print(f"wrote {path}")
    if args.report:
        names = ", ".join(p.name for p in paths[bool(args.json):])
        print(f"wrote {len(paths) - bool(args.json)} files to {args.report}: {names}")
    return 0
