"""Benchmark: how long the ``jaxflex`` command takes to answer ``--help`` and ``--version``.

Each command runs in a fresh interpreter (``python -m jaxflex``, this checkout first on the
path), ``--rounds`` times in interleaved rounds; reported is the median wall time of each, next
to the bare interpreter (``python -c pass``) and to a full import of the library
(``import jaxflex; jaxflex.identify``), which is what a computing command pays on top.

    python benchmarks/cli_startup.py [--rounds 9]

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

from jaxflex._io import OutputError, check_writable, provenance, write_json  # noqa: E402

RESULTS = HERE / "results" / "cli_startup.json"
COMMANDS: dict[str, tuple[list[str], str]] = {
    "python -c pass": (["-c", "pass"], ""),
    "jaxflex --help": (["-m", "jaxflex", "--help"], "usage: jaxflex"),
    "jaxflex --version": (["-m", "jaxflex", "--version"], "jaxflex "),
    "import jaxflex; jaxflex.identify": (["-c", "import jaxflex; jaxflex.identify"], ""),
}
"""Label: (interpreter arguments, what its output must start with)."""


def run_once(arguments: list[str], expected: str, env: dict[str, str]) -> float:
    """Wall time of one run of ``python ARGUMENTS``; its output must start with ``expected``."""
    start = time.perf_counter()
    done = subprocess.run([sys.executable, *arguments], capture_output=True, text=True,
                          env=env, cwd=ROOT, check=False)
    seconds = time.perf_counter() - start
    if done.returncode != 0 or not done.stdout.startswith(expected):
        raise RuntimeError(f"python {' '.join(arguments)} failed ({done.returncode}): "
                           f"{(done.stdout + done.stderr).strip()[-300:]}")
    return seconds


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=9, help="runs of each command (default 9)")
    parser.add_argument("--out", default=str(RESULTS))
    args = parser.parse_args()
    try:  # before any work
        out = check_writable(args.out, overwrite=True, suffixes=(".json",))
    except OutputError as error:
        parser.error(str(error))
    env = os.environ | {"PYTHONPATH": str(ROOT), "JAXFLEX_PROGRESS": "0"}
    times: dict[str, list[float]] = {label: [] for label in COMMANDS}
    load_start = list(os.getloadavg())
    for _ in range(args.rounds):
        for label, (arguments, expected) in COMMANDS.items():
            times[label].append(run_once(arguments, expected, env))
    rows = {
        label: {"median_s": statistics.median(t), "min_s": min(t), "max_s": max(t)}
        for label, t in times.items()
    }
    for label, row in rows.items():
        print(f"{label:<34} median {row['median_s']:.3f} s "
              f"(min {row['min_s']:.3f}, max {row['max_s']:.3f})")
    write_json(
        out,
        {
            "benchmark": "cli_startup",
            "settings": {"rounds": args.rounds, "interpreter": sys.executable,
                         "timing": "wall time of a fresh process, interleaved rounds",
                         "environment": {"PYTHONPATH": "this checkout", "JAXFLEX_PROGRESS": "0"}},
            "rows": rows,
            "load_average_1_5_15min": {"start": load_start, "end": list(os.getloadavg())},
            **provenance(),
        },
        overwrite=True,
    )
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
