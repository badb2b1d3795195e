"""Benchmark: how long the ``jaxflex`` command takes to answer ``--help`` and ``--version``.

Each command runs in a fresh interpreter (``python -m jaxflex``, this checkout first on the
path), ``--rounds`` times in interleaved rounds; reported is the median wall time of each, next
to the bare interpreter (``python -c pass``) and to a full import of the library
(``import jaxflex; jaxflex.identify``), which is what a computing command pays on top.
``--baseline DIR`` times another checkout (an older commit, e.g.
``git archive COMMIT jaxflex | tar -x -C DIR``) in the same rounds, recorded under the name
``--baseline-name``; a command it does not know is recorded as failed there.

    python benchmarks/cli_startup.py [--rounds 9] [--baseline DIR --baseline-name COMMIT]

Results go to ``benchmarks/results/cli_startup.json``.
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

HERE = Path(__file__).parent
ROOT = HERE.parent
sys.path.insert(0, str(ROOT))

from _output import checked_out  # noqa: E402

from jaxflex._io import provenance, write_json  # noqa: E402

RESULTS = HERE / "results" / "cli_startup.json"
COMMANDS: dict[str, tuple[list[str], str]] = {
    "python -c pass": (["-c", "pass"], ""),
    "jaxflex --help": (["-m", "jaxflex", "--help"], "usage: jaxflex"),
    "jaxflex --version": (["-m", "jaxflex", "--version"], "jaxflex "),
    "import jaxflex; jaxflex.identify": (["-c", "import jaxflex; jaxflex.identify"], ""),
}
"""Label: (interpreter arguments, what its output must start with)."""


def run_once(arguments: list[str], expected: str, root: Path = ROOT) -> float:
    """Wall time of one run of ``python ARGUMENTS`` in the checkout ``root`` (first on the path);
    its output must start with ``expected``."""
    env = os.environ | {"PYTHONPATH": str(root), "JAXFLEX_PROGRESS": "0"}
    start = time.perf_counter()
    done = subprocess.run([sys.executable, *arguments], capture_output=True, text=True,
                          env=env, cwd=root, check=False)
    seconds = time.perf_counter() - start
    if done.returncode != 0 or not done.stdout.startswith(expected):
        raise RuntimeError(f"python {' '.join(arguments)} failed ({done.returncode}): "
                           f"{(done.stdout + done.stderr).strip()[-300:]}")
    return seconds


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=9, help="runs of each command (default 9)")
    parser.add_argument("--baseline", type=Path, metavar="DIR",
                        help="another checkout to time in the same rounds")
    parser.add_argument("--baseline-name", default="baseline", metavar="NAME",
                        help="what the baseline is, e.g. its commit (default: baseline)")
    parser.add_argument("--out", default=str(RESULTS))
    args = parser.parse_args()
    out = checked_out(parser, args.out)  # before any work
    roots = {"this checkout": ROOT}
    if args.baseline is not None:
        if not (args.baseline / "jaxflex" / "__init__.py").is_file():
            parser.error(f"--baseline {args.baseline}: no jaxflex/__init__.py there")
        roots[args.baseline_name] = args.baseline.resolve()
    times = {(root, label): [] for root in roots for label in COMMANDS}
    failed: dict[tuple[str, str], str] = {}
    load_start = list(os.getloadavg())
    for _ in range(args.rounds):
        for (root, label), seconds in times.items():
            if (root, label) in failed:
                continue
            try:
                seconds.append(run_once(*COMMANDS[label], roots[root]))
            except RuntimeError as error:
                if root == "this checkout":
                    raise
                failed[root, label] = str(error)
    rows = {root: {} for root in roots}
    for (root, label), t in times.items():
        if (root, label) in failed:
            rows[root][label] = {"failed": failed[root, label]}
            print(f"{root}: {label:<34} failed")
            continue
        rows[root][label] = {"median_s": statistics.median(t), "min_s": min(t), "max_s": max(t)}
        print(f"{root}: {label:<34} median {statistics.median(t):.3f} s "
              f"(min {min(t):.3f}, max {max(t):.3f})")
    write_json(
        out,
        {
            "benchmark": "cli_startup",
            "settings": {"rounds": args.rounds, "interpreter": sys.executable,
                         "timing": "wall time of a fresh process, interleaved rounds",
                         "environment": {"PYTHONPATH": "the checkout", "JAXFLEX_PROGRESS": "0"},
                         "baseline": None if args.baseline is None else args.baseline_name},
            "rows": rows,
            "load_average_1_5_15min": {"start": load_start, "end": list(os.getloadavg())},
            **provenance(),
        },
        overwrite=True,
    )
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
