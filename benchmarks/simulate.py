"""Benchmark: candidate simulations per second, batched in JAX vs one at a time in NumPy.

Measures, in one run on this machine, for populations of 1, 10, 100 and 1000 (2 s at 1 kHz,
n_el = 10, two sub-steps: the accuracy the tests check against Radau): compile time, best-of-5
run time and simulations per second of ``simulate_batch`` (the population split across one CPU
device per core, :mod:`jaxflex.parallel`) and of a plain vmap on one device, peak resident
memory, and the NumPy candidate-by-candidate simulator of ``benchmarks/numpy_reference.py``
(same model and scheme) for the ratio.
Writes ``benchmarks/results/simulate.json``.
"""

from __future__ import annotations

import argparse
import os
import resource
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).parent))

import jax  # noqa: E402

import jaxflex  # noqa: E402
from jaxflex._io import provenance, write_json  # noqa: E402
from jaxflex.model import Model  # noqa: E402
from jaxflex.signals import reference_input  # noqa: E402
from jaxflex.simulation import simulate_batch, simulate_core  # noqa: E402

RESULTS = Path(__file__).parent / "results" / "simulate.json"


def peak_memory_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def _first_and_best(call, repeats: int = 5) -> tuple[float, float]:
    """(first call, best of ``repeats`` further calls) in seconds."""
    start = time.perf_counter()
    call()
    first = time.perf_counter() - start
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        call()
        times.append(time.perf_counter() - start)
    return first, min(times)


def bench_population(model: Model, torque: np.ndarray, population: int, seed: int) -> dict:
    """``simulate_batch`` (split across the CPU devices) and a plain one-device vmap."""
    u = np.random.default_rng(seed).uniform(size=(population, len(model.space)))
    params = model.space.from_unit(u)
    first, best = _first_and_best(
        lambda: simulate_batch(model, params, torque).joint_angle.block_until_ready()
    )
    plain = jax.jit(jax.vmap(lambda p, t: simulate_core(model, p, t, model.testbed.dt), (0, None)))
    _, best_plain = _first_and_best(lambda: plain(params, torque).joint_angle.block_until_ready())
    return {
        "population": population,
        "compile_s": first - best,
        "run_s": best,
        "simulations_per_s": population / best,
        "one_device_vmap_run_s": best_plain,
        "one_device_vmap_simulations_per_s": population / best_plain,
        "peak_rss_mb_so_far": peak_memory_mb(),
    }


def bench_numpy(torque: np.ndarray, count: int, seed: int) -> dict:
    import numpy_reference

    space = jaxflex.base_space()
    u = np.random.default_rng(seed).uniform(size=(count, len(space)))
    values = {k: np.asarray(v) for k, v in space.from_unit(u).items()}
    start = time.perf_counter()
    for i in range(count):
        numpy_reference.simulate({k: float(v[i]) for k, v in values.items()}, torque, 1e-3)
    elapsed = time.perf_counter() - start
    return {"candidates": count, "run_s": elapsed, "simulations_per_s": count / elapsed}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--populations", default="1,10,100,1000")
    parser.add_argument("--numpy-candidates", type=int, default=3)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", default=str(RESULTS))
    args = parser.parse_args()
    model = Model()
    _, torque = reference_input("pulse")
    rows = []
    for population in (int(p) for p in args.populations.split(",")):
        row = bench_population(model, torque, population, args.seed)
        rows.append(row)
        print(
            f"population {population:5d}: compile {row['compile_s']:5.2f} s, "
            f"run {row['run_s'] * 1e3:8.1f} ms, {row['simulations_per_s']:7.0f} sims/s "
            f"({row['one_device_vmap_simulations_per_s']:5.0f} on one device)"
        )
    reference = bench_numpy(torque, args.numpy_candidates, args.seed)
    print(f"NumPy candidate by candidate: {reference['simulations_per_s']:.2f} sims/s")
    at_100 = next((r for r in rows if r["population"] == 100), rows[-1])
    ratio = at_100["simulations_per_s"] / reference["simulations_per_s"]
    print(f"ratio at population {at_100['population']}: {ratio:.0f}x the NumPy loop")
    write_json(
        args.out,
        {
            "benchmark": "simulate",
            "settings": {
                "input": "pulse",
                "duration_s": model.testbed.duration,
                "dt_s": model.testbed.dt,
                "n_elements": model.testbed.n_elements,
                "n_substeps": model.n_substeps,
                "seed": args.seed,
                "cpu_devices": len(jax.devices("cpu")),
            },
            "jax": rows,
            "numpy": reference,
            "ratio_at_population_100": ratio,
            "peak_rss_mb": peak_memory_mb(),
            "load_average_1_5_15min_at_end": list(os.getloadavg()),
            **provenance(),
        },
        overwrite=True,
    )
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
