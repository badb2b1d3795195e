"""Benchmark: paper-setting identification in jaxflex against SciPy DE on a NumPy simulator.

One run per algorithm (DE, GA, PSO; population 100 × 100 generations by default) on three
noisy 2 s reference records, each generation one JIT-compiled, vmapped evaluation of the whole
population; reported: wall time after compilation, compile time, objective after the search and
after refinement.

The alternative a user would pick is ``scipy.optimize.differential_evolution`` with the same
settings (DE/rand/1/bin, F = 0.5, CR = 0.8, population 100, the same unit box with log scales,
no polishing) driving the NumPy simulator of ``numpy_reference.py`` candidate by candidate.
That costs seconds per candidate, so a full 10 100-evaluation run takes hours: by default SciPy
runs ``--scipy-generations`` generations (``--scipy-generations 100`` for the full run), its
time per evaluation is measured, and the full-run time is extrapolated (flagged as such). The
objectives are compared at an equal number of generations.

    python benchmarks/identify.py [--generations 100] [--scipy-generations 1] [--scipy-workers 2]

Results go to ``benchmarks/results/identify.json``.
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import time
from pathlib import Path

import jax
import numpy as np
from scipy.optimize import differential_evolution

import jaxflex  # noqa: F401  (float64)
from jaxflex._io import provenance, write_json
from jaxflex.identification import identify
from jaxflex.model import Model
from jaxflex.objective import build_objective
from jaxflex.synthetic import make_records

sys.path.insert(0, str(Path(__file__).resolve().parent))
import numpy_reference  # noqa: E402

RESULTS = Path(__file__).resolve().parent / "results" / "identify.json"
TARGET_SECONDS = 3.0
TARGET_SPEEDUP = 100.0


class NumpyObjective:
    """The SciPy side's objective: unit box → physical (log scales) → NumPy cost. Picklable."""

    def __init__(self, records):
        space = Model().space
        self.records = list(records)
        self.names = space.names
        self.lower, self.upper = space.lower, space.upper
        self.log = np.array([s.log_scale for s in space.specs])

    def physical(self, u: np.ndarray) -> dict[str, float]:
        lo, hi = self.lower, self.upper
        x = np.where(self.log, lo * (hi / lo) ** u, lo + u * (hi - lo))
        return dict(zip(self.names, map(float, x), strict=True))

    def __call__(self, u: np.ndarray) -> float:
        try:
            value = numpy_reference.cost(self.physical(np.asarray(u)), self.records)
        except (np.linalg.LinAlgError, OverflowError, ValueError):
            return math.inf
        return value if math.isfinite(value) else math.inf


def check_agreement(records, seed: int = 123) -> float:
    """Largest relative difference of the two objectives at a few random candidates."""
    rng = np.random.default_rng(seed)
    objective = build_objective(records)
    numpy_side = NumpyObjective(records)
    worst = 0.0
    for u in rng.uniform(0.2, 0.8, size=(2, len(numpy_side.names))):
        a = float(objective.unit_cost(u))
        b = numpy_side(u)
        worst = max(worst, abs(a - b) / abs(a))
    return worst


def run_jaxflex(records, method: str, generations: int, population: int) -> dict:
    fit = identify(
        records, method=method, seed=0, generations=generations, population=population,
        intervals=False,
    )
    t = fit.timing
    return {
        "method": method,
        "population": population,
        "generations": generations,
        "evaluations": fit.settings["n_evaluations"],
        "wall_time_s": t["search"],
        "compile_time_s": t["search_compile"],
        "objective": fit.cost_search,
        "refine_time_s": t.get("refine"),
        "refine_compile_s": t.get("refine_compile"),
        "objective_refined": fit.cost,
        "evaluations_per_s": fit.settings["n_evaluations"] / t["search"],
        "history_best": fit.history.best,
        "params": fit.params,
    }


def run_scipy(records, generations: int, population: int, workers: int) -> dict:
    objective = NumpyObjective(records)
    dim = len(objective.names)
    init = np.random.default_rng(0).uniform(size=(population, dim))
    best: list[float] = []

    def callback(intermediate_result):
        best.append(float(intermediate_result.fun))

    t0 = time.perf_counter()
    result = differential_evolution(
        objective,
        bounds=[(0.0, 1.0)] * dim,
        strategy="rand1bin",
        maxiter=generations,
        init=init,
        mutation=0.5,
        recombination=0.8,
        tol=0.0,
        atol=0.0,
        polish=False,
        seed=0,
        workers=workers,
        updating="deferred" if workers != 1 else "immediate",
        callback=callback,
    )
    wall = time.perf_counter() - t0
    return {
        "population": population,
        "generations": generations,
        "workers": workers,
        "evaluations": int(result.nfev),
        "wall_time_s": wall,
        "seconds_per_evaluation": wall / result.nfev,
        "objective": float(result.fun),
        "history_best": best,
    }


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--generations", type=int, default=100)
    parser.add_argument("--population", type=int, default=100)
    parser.add_argument("--methods", default="de,ga,pso")
    parser.add_argument("--scipy-generations", type=int, default=1,
                        help="generations SciPy runs (100 = the full, hours-long run)")
    parser.add_argument("--scipy-workers", type=int, default=2,
                        help="processes for SciPy's candidate evaluations (-1: all cores)")
    parser.add_argument("--skip-scipy", action="store_true")
    parser.add_argument("--out", default=str(RESULTS))
    args = parser.parse_args(argv)

    load_before = os.getloadavg()
    records = make_records(noise=True, seed=0)
    agreement = check_agreement(records)
    print(f"objective agreement jaxflex vs NumPy reference: {agreement:.1e} (relative)")

    runs = []
    for method in args.methods.split(","):
        run = run_jaxflex(records, method, args.generations, args.population)
        runs.append(run)
        print(
            f"jaxflex {method.upper():<4} {run['evaluations']} evaluations: "
            f"{run['wall_time_s']:.2f} s after {run['compile_time_s']:.1f} s compile; "
            f"objective {run['objective']:.4e} (refined {run['objective_refined']:.4e} "
            f"in {run['refine_time_s']:.2f} s)"
        )

    results = {
        "benchmark": "identify",
        "records": "three noisy 2 s reference records (triangular, pulse, half_sine; seed 0)",
        "objective_agreement": agreement,
        "cpu_devices": len(jax.devices("cpu")),  # the population is split across them
        "jaxflex": runs,
        "targets": {"de_wall_time_s": TARGET_SECONDS, "speedup_vs_scipy": TARGET_SPEEDUP},
        "provenance": provenance(),
        "load_average": {"start": load_before},  # other work on the machine slows every timing
    }
    de = next((r for r in runs if r["method"] == "de"), None)
    if not args.skip_scipy and de is not None:
        scipy = run_scipy(records, args.scipy_generations, args.population, args.scipy_workers)
        full_evaluations = de["evaluations"]
        extrapolated = scipy["seconds_per_evaluation"] * full_evaluations
        g = min(args.scipy_generations, args.generations)
        scipy_at_g = scipy["history_best"][g - 1] if scipy["history_best"] else scipy["objective"]
        comparison = {
            "scipy_full_run_time_s": extrapolated if g < args.generations else scipy["wall_time_s"],
            "scipy_full_run_extrapolated": g < args.generations,
            "speedup": (extrapolated if g < args.generations else scipy["wall_time_s"])
            / de["wall_time_s"],
            "throughput_ratio": de["evaluations_per_s"] * scipy["seconds_per_evaluation"],
            "generations_compared": g,
            "jaxflex_objective_at_g": float(de["history_best"][g]),
            "scipy_objective_at_g": scipy_at_g,
            "jaxflex_final_objective": de["objective"],
        }
        comparison["equal_or_better_objective"] = bool(
            comparison["jaxflex_objective_at_g"] <= comparison["scipy_objective_at_g"]
        )
        results["scipy"] = scipy
        results["comparison"] = comparison
        print(
            f"SciPy DE (NumPy simulator, {scipy['workers']} workers): {scipy['evaluations']} "
            f"evaluations in {scipy['wall_time_s']:.1f} s = "
            f"{scipy['seconds_per_evaluation']:.3f} s each; full run "
            f"{'~' if comparison['scipy_full_run_extrapolated'] else ''}"
            f"{comparison['scipy_full_run_time_s']:.0f} s"
        )
        print(
            f"speed-up of the DE run: {comparison['speedup']:.0f}x; objective after {g} "
            f"generation(s): jaxflex {comparison['jaxflex_objective_at_g']:.4e}, "
            f"SciPy {comparison['scipy_objective_at_g']:.4e}"
        )
    if de is not None:
        results["meets_time_target"] = de["wall_time_s"] <= TARGET_SECONDS
        if "comparison" in results:
            results["meets_speedup_target"] = results["comparison"]["speedup"] >= TARGET_SPEEDUP
    results["load_average"]["end"] = os.getloadavg()
    write_json(args.out, results, overwrite=True)
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
