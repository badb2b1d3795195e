"""Benchmark: how long a user waits, command by command, cold and warm.

Each command runs as a new user runs it: a fresh process, the installed ``jaxflex`` command
line with its own compilation cache (``JAXFLEX_CACHE_DIR``), empty (``cold``) and then as the
cold run left it (``warm``). Measured:

* ``discover`` on ROTFLEX: fitted on the square wave, held out on run 985, default budget;
* ``discover`` on the bundled example (``jaxflex demo``'s data), from scratch;
* ``identify`` on ROTFLEX: the square wave, differential evolution, default budget;
* ``jaxflex --help``.

``--tree PATH`` (repeatable) runs the commands from other checkouts (each one's ``jaxflex``
package on ``PYTHONPATH``), so that revisions are measured beside each other in one session on
the same machine, labelled by ``--label`` (one per tree; default: the tree's git revision). The
machine is shared and a run's time varies by a fifth from one run to the next, so the
revisions take turns: ``--rounds`` rounds, each running every command cold then warm from
every tree in turn; each stored time is the median of the rounds, beside every round's. The
real-rig records come from ``jaxflex datasets`` (``JAXFLEX_DATA_DIR`` or the network).

    python benchmarks/time_to_answer.py [--tree PATH ...] [--label NAME ...] [--rounds N]
                                        [--only NAME ...] [--breakdown]

``--breakdown`` also runs the warm ``discover`` on ROTFLEX once more in a process of its own with
its phases timed (:func:`breakdown`): where the time goes, stored beside the timings.

Results go to ``benchmarks/results/time_to_answer.json`` (merged with the labels already there).
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from jaxflex._io import provenance, write_json

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results" / "time_to_answer.json"
TARGETS = {  # seconds, on the project's 2-core machine
    "discover_rotflex": {"cold": 45.0, "warm": 15.0},
    "discover_example": {"cold": 30.0},
    "identify_rotflex": {"cold": 20.0},
}


def commands(tree: Path, data: Path, out: Path) -> dict[str, list[str]]:
    """The measured command lines (without the leading ``jaxflex``)."""
    rotflex = ["--arm", "quanser_rotflex"]
    example = sorted((tree / "jaxflex" / "data").glob("example_*.csv"))
    fitted = [str(p) for p in example if "holdout" not in p.name]
    held_out = [str(p) for p in example if "holdout" in p.name]
    return {
        "help": ["--help"],
        "identify_rotflex": ["identify", str(data / "rotflex" / "square_wave.csv"), *rotflex,
                             "--method", "de", "--out", str(out / "fit.json"), "--overwrite"],
        "discover_rotflex": ["discover", str(data / "rotflex" / "square_wave.csv"), "--holdout",
                             str(data / "rotflex" / "random_985.csv"), *rotflex,
                             "--json", str(out / "discover.json"), "--overwrite"],
        "discover_example": ["discover", *fitted, "--holdout", *held_out,
                             "--json", str(out / "discover_example.json"), "--overwrite"],
    }


def prepare_data(tree: Path, data: Path, env: dict[str, str]) -> None:
    """The ROTFLEX runs as CSV files under ``data``."""
    subprocess.run([sys.executable, "-m", "jaxflex", "datasets", "get", "quanser_rotflex",
                    "--out", str(data / "rotflex")],
                   check=True, env=env, cwd=tree, stdout=subprocess.DEVNULL)


def timed(argv: list[str], env: dict[str, str], tree: Path) -> dict:
    """Wall and child CPU seconds of one command; its exit status and last line."""
    before = os.times()
    t0 = time.perf_counter()
    done = subprocess.run([sys.executable, "-m", "jaxflex", *argv], env=env, cwd=tree,
                          capture_output=True, text=True)
    wall = time.perf_counter() - t0
    after = os.times()
    cpu = (after.children_user - before.children_user) + (after.children_system
                                                          - before.children_system)
    lines = (done.stdout + done.stderr).strip().splitlines()
    return {"seconds": round(wall, 2), "cpu_seconds": round(cpu, 2), "exit": done.returncode,
            "last_line": lines[-1] if lines else "", "load_average_before": os.getloadavg()[0]}


PHASES = {  # phase of a discovery run → (module, object, attribute or "a|b": the first present)
    "Levenberg–Marquardt refits": ("jaxflex.discovery._engine", "Engine", "_lm"),
    "profile scans and starts": ("jaxflex.discovery._engine", "Engine",
                                 "profile_starts|profile_start"),
    "score tests": ("jaxflex.discovery._engine", "Engine", "score_tests"),
    "base model's search and refinement": ("jaxflex.identification", None, "identify"),
    "runs of the refits, batched": ("jaxflex.discovery._engine", "Engine", "predictions_many"),
    "runs of the step's fit": ("jaxflex.discovery._engine", "Engine", "predictions"),
}

BREAKDOWN = """
import collections, importlib, json, sys, time
import jax.monitoring
phases, compiled = json.loads(sys.argv[1]), collections.defaultdict(float)
jax.monitoring.register_event_duration_secs_listener(
    lambda event, seconds, **_: compiled.__setitem__(event, compiled[event] + seconds))
spent = collections.defaultdict(float)
def timed(name, fn):
    def wrapper(*args, **kwargs):
        t0 = time.perf_counter()
        try:
            return fn(*args, **kwargs)
        finally:
            spent[name] += time.perf_counter() - t0
    return wrapper
for name, (module, owner, attributes) in phases.items():
    target = importlib.import_module(module)
    target = getattr(target, owner) if owner else target
    for attribute in attributes.split("|"):
        if hasattr(target, attribute):
            setattr(target, attribute, timed(name, getattr(target, attribute)))
            break
from jaxflex.cli import main
t0 = time.perf_counter()
try:
    main(sys.argv[2:])
except SystemExit:
    pass
total = time.perf_counter() - t0
events = {"tracing": "/jax/core/compile/jaxpr_trace_duration",
          "lowering": "/jax/core/compile/jaxpr_to_mlir_module_duration",
          "compiling and loading compiled programs": "/jax/core/compile/backend_compile_duration"}
print(json.dumps({"total": total, "phases": dict(spent),
                  "compilation": {k: compiled[v] for k, v in events.items()}}))
"""


def breakdown(argv: list[str], env: dict[str, str], tree: Path) -> dict:
    """One run of ``jaxflex argv`` with the time of each discovery phase (:data:`PHASES`,
    nested phases counted in each) and of tracing, lowering and compiling."""
    done = subprocess.run([sys.executable, "-c", BREAKDOWN, json.dumps(PHASES), *argv],
                          env=env, cwd=tree, capture_output=True, text=True, check=True)
    return json.loads(done.stdout.strip().splitlines()[-1])


def median_of(rounds: list[dict]) -> dict:
    """One command's cold or warm runs over the rounds: the median seconds and CPU seconds,
    each round's seconds, and the worst exit status with its last line."""
    worst = next((run for run in rounds if run["exit"] != 0), rounds[0])
    return {"seconds": round(statistics.median(r["seconds"] for r in rounds), 2),
            "cpu_seconds": round(statistics.median(r["cpu_seconds"] for r in rounds), 2),
            "each_seconds": [r["seconds"] for r in rounds],
            "load_average_before": [round(r["load_average_before"], 2) for r in rounds],
            "exit": worst["exit"], "last_line": worst["last_line"]}


def revision_label(tree: Path) -> str:
    """The short git revision of ``tree``."""
    return subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=tree, capture_output=True,
                          text=True).stdout.strip()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--tree", type=Path, action="append")
    parser.add_argument("--label", action="append")
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--only", nargs="*", default=None)
    parser.add_argument("--breakdown", action="store_true")
    args = parser.parse_args()
    trees = [t.resolve() for t in args.tree or [ROOT]]
    labels = args.label or [revision_label(t) for t in trees]
    if len(labels) != len(trees) or args.rounds < 1:
        parser.error("give one --label per --tree, and --rounds >= 1")
    timings = {label: {} for label in labels}
    breakdowns = {}
    with tempfile.TemporaryDirectory() as scratch:
        scratch = Path(scratch)
        data = scratch / "data"
        base = {k: v for k, v in os.environ.items() if not k.startswith("JAX_")}
        base |= {"JAXFLEX_PROGRESS": "0"}
        prepare_data(trees[0], data, {**base, "JAXFLEX_CACHE_DIR": str(scratch / "other")})
        for round_ in range(args.rounds):
            for tree, label in zip(trees, labels, strict=True):
                cache, out = scratch / "cache", scratch / label / "out"
                out.mkdir(parents=True, exist_ok=True)
                path = os.pathsep.join(filter(None, [str(tree), base.get("PYTHONPATH")]))
                env = base | {"PYTHONPATH": path, "JAXFLEX_CACHE_DIR": str(cache)}
                for name, argv in commands(tree, data, out).items():
                    if args.only and name not in args.only:
                        continue
                    if cache.exists():
                        subprocess.run(["rm", "-rf", str(cache)], check=True)
                    runs = timings[label].setdefault(name, {"cold": [], "warm": []})
                    runs["cold"].append(timed(argv, env, tree))
                    runs["warm"].append(timed(argv, env, tree))
                    print(f"round {round_ + 1}, {label}, {name}: cold "
                          f"{runs['cold'][-1]['seconds']} s, warm {runs['warm'][-1]['seconds']} s",
                          flush=True)
                    if args.breakdown and name == "discover_rotflex" and label not in breakdowns:
                        breakdowns[label] = breakdown(argv, env, tree)
    results = json.loads(RESULTS.read_text()) if RESULTS.exists() else {"revisions": {}}
    results.update(benchmark="time to answer: fresh processes, cold and warm compilation cache",
                   targets_seconds=TARGETS)
    for label, commands_run in timings.items():
        runs = {name: {kind: median_of(each) for kind, each in kinds.items()}
                for name, kinds in commands_run.items()}
        if label in breakdowns:
            runs["discover_rotflex"]["breakdown"] = breakdowns[label]
        results["revisions"][label] = {"runs": runs, "rounds": args.rounds,
                                       "provenance": provenance()}
    write_json(RESULTS, results, overwrite=True)


if __name__ == "__main__":
    main()
