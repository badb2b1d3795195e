"""``jaxflex torque-map DATA [...] --fit FIT.json --out DIR``: the torque a fitted model misses.

Estimates the unmodelled hub torque on each record with the fit's model
(:func:`jaxflex.missing_torque.estimate_missing_torque`), finds its shape among candidate terms
of the hub's angle, velocity and the input (:func:`jaxflex.torque_regression.torque_map`),
prints the map and what it says, and writes ``torque_map.json`` and the figure
``missing_torque.<format>`` into DIR.
"""

from __future__ import annotations

import argparse

from jaxflex.cli._arm import add_arm_arguments, load_rig_records, ready_records, rig_of, windows_of
from jaxflex.cli._checks import (
    add_max_samples,
    check_directory,
    check_outputs,
    check_size,
    max_samples,
    positive_int,
    read_fit,
    seed,
)
from jaxflex.cli._options import add_quiet_option, add_record_options
from jaxflex.cli.identify import sources
from jaxflex.cli.validate import filter_noise

HELP = "estimate the hub torque a fitted model misses and find its shape"
"""One-line summary of ``jaxflex torque-map`` in the command list."""


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser("torque-map", help=HELP, description=HELP)
    p.add_argument(
        "data", nargs="+", metavar="DATA", help="record files (.csv/.npz) or directories of them"
    )
    p.add_argument(
        "--fit", required=True, metavar="FIT.json", help="fit file written by `jaxflex identify`"
    )
    p.add_argument("--out", required=True, metavar="DIR",
                   help="write torque_map.json and the figure missing_torque.<format> into DIR")
    p.add_argument("--overwrite", action="store_true", help="replace existing files in DIR")
    p.add_argument("--format", choices=("png", "pdf", "svg"), default="png",
                   help="figure file format (default: png)")
    p.add_argument("--integrated", action="store_true",
                   help="model the missing torque as an integrated random walk (smoother) "
                        "instead of a random walk")
    p.add_argument("--bootstrap", type=positive_int, default=50, metavar="B",
                   help="subsamples for the terms' inclusion probabilities and bootstrap "
                        "resamples for their intervals (default: %(default)s)")
    p.add_argument("--harmonics", type=positive_int, default=8, metavar="K",
                   help="highest k of the sin(k*theta), cos(k*theta) terms (default: "
                        "%(default)s)")
    p.add_argument("--seed", type=seed, default=0, help="seed of the resamples (default: 0)")
    add_record_options(p)
    add_max_samples(p)
    add_arm_arguments(p)
    add_quiet_option(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    import numpy as np

    from jaxflex._io import all_or_nothing, provenance, write_json
    from jaxflex._progress import stage
    from jaxflex.missing_torque import estimate_missing_torque
    from jaxflex.plots import save_figure
    from jaxflex.plots.missing_torque import plot_missing_torque
    from jaxflex.torque_regression import default_terms, torque_map

    _, params, fit = read_fit("--fit", args.fit)
    model, _ = rig_of(args, fit)
    records = list(load_rig_records(args.data, args, model))
    check_size(sum(r.n_samples for r in records), f"{len(records)} record(s)",
               n_elements=model.testbed.n_elements, limit=max_samples(args.max_samples))
    directory = check_directory("--out", args.out)
    json_path, figure_path = check_outputs(
        [("--out", directory / "torque_map.json", None),
         ("--out", directory / f"missing_torque.{args.format}", None)],
        overwrite=args.overwrite, inputs=[*sources(records), args.fit])
    ready = ready_records(model, records, windows_of(args, model, records))
    estimate = estimate_missing_torque(ready, model, params, integrated=args.integrated,
                                       noise=filter_noise(fit).get("noise"))
    stage(f"estimated the missing torque on {len(ready)} record(s)", not args.quiet)
    found = torque_map(estimate, terms=default_terms(estimate, args.harmonics),
                       bootstrap=args.bootstrap, seed=args.seed)
    unit = model.drive.unit or "-"
    for r in estimate.records:
        print(f"{r.name}: missing torque RMS {np.sqrt(np.mean(r.torque**2)):.3g} N m, "
              f"its standard deviation RMS {np.sqrt(np.mean(r.std**2)):.3g} N m")
    print(f"map: {found.expression}  ({100 * found.explained:.0f} % of its variance)")
    print(found.words)
    with all_or_nothing():
        write_json(json_path, {
            "rig": model.name, "intensity": estimate.intensity,
            "integrated": estimate.integrated, "records": [r.name for r in estimate.records],
            "map": found.to_dict(),
            "settings": {"fit": str(args.fit), "seed": args.seed, "bootstrap": args.bootstrap,
                         "harmonics": args.harmonics},
            "provenance": provenance()}, overwrite=args.overwrite)
        save_figure(plot_missing_torque(estimate, found, input_unit=unit), figure_path,
                    overwrite=args.overwrite)
    print(f"wrote {json_path} and {figure_path}")
    return 0
