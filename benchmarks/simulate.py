"""Benchmark: candidate simulations per second, batched in jaxflex vs NumPy and diffrax.

Measures, in one run on this machine, for populations of 1, 10, 20, 100 and 1000 (2 s at 1 kHz,
n_el = 10, two sub-steps: the accuracy the tests check against Radau): compile time, best-of-5
run time and simulations per second of ``simulate_batch`` (the population split across one CPU
device per core, :mod:`jaxflex.parallel`) and of a plain vmap on one device, peak resident
memory, and two peers for the ratios, in the same run: the NumPy candidate-by-candidate
simulator of ``benchmarks/numpy_reference.py`` (same model and scheme) and diffrax's implicit
Kvaerno5 vmapped over a small population (``benchmarks/diffrax_reference.py``, same model's
ODE). diffrax runs at the loosest tolerance of a ladder whose error against SciPy Radau
(``tests/reference_solver.py``) is no larger than jaxflex's on the joint angle and the tip
acceleration, both measured here at the reference parameters (the accuracy tests' condition).
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

HERE = Path(__file__).parent
sys.path[:0] = [str(HERE), str(HERE.parent / "tests")]

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402

import jaxflex  # noqa: E402
from jaxflex._io import provenance, write_json  # noqa: E402
from jaxflex.model import Model  # noqa: E402
from jaxflex.signals import reference_input  # noqa: E402
from jaxflex.simulation import simulate, simulate_batch, simulate_core  # noqa: E402

RESULTS = HERE / "results" / "simulate.json"
DIFFRAX_RTOLS = (1e-4, 3e-5, 1e-5, 3e-6, 1e-6)
"""The tolerance ladder, loosest first; ``atol = DIFFRAX_ATOL_PER_RTOL · rtol`` (the state mixes
radians of hub angle with millimetres of deflection)."""
DIFFRAX_ATOL_PER_RTOL = 1e-2


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


def nrmse_percent(reference: np.ndarray, value: np.ndarray) -> float:
    """The accuracy tests' measure: RMS error over RMS of the reference, in %."""
    return float(100.0 * np.sqrt(np.mean((reference - value) ** 2) / np.mean(reference**2)))


def _errors(reference, angle, tip) -> dict[str, float]:
    return {
        "joint_angle_nrmse_percent": nrmse_percent(reference[0], np.asarray(angle)),
        "tip_acceleration_nrmse_percent": nrmse_percent(reference[1], np.asarray(tip)),
    }


def bench_diffrax(model: Model, torque: np.ndarray, population: int, seed: int) -> dict:
    """diffrax at the loosest tolerance as accurate as jaxflex against Radau, and its speed.

    The accuracies are compared where the accuracy tests compare them: at the reference
    parameters, on this input.
    """
    import diffrax_reference
    from reference_solver import radau_reference

    dt = model.testbed.dt
    u = np.random.default_rng(seed).uniform(size=(population, len(model.space)))
    params = model.space.from_unit(u)
    program = diffrax_reference.batch(model, torque, dt)
    reference_params = jaxflex.reference_parameters()
    reference = radau_reference(model, reference_params, torque, dt)
    ours = simulate(model, reference_params, torque)
    jaxflex_error = _errors(reference, ours.joint_angle, ours.tip_acceleration)
    checked = jax.tree.map(lambda x: jnp.asarray(x)[None], reference_params)
    ladder = []
    for rtol in DIFFRAX_RTOLS:
        angle, tip = program(checked, rtol, DIFFRAX_ATOL_PER_RTOL * rtol)
        error = _errors(reference, angle[0], tip[0])
        ladder.append({"rtol": rtol, **error})
        if all(error[k] <= jaxflex_error[k] for k in error):
            break
    else:
        raise RuntimeError(f"diffrax misses jaxflex's accuracy even at rtol {rtol}: {ladder}")
    atol = DIFFRAX_ATOL_PER_RTOL * rtol
    first, best = _first_and_best(
        lambda: program(params, rtol, atol)[0].block_until_ready(), repeats=2
    )
    return {
        "solver": "diffrax.Kvaerno5 + PIDController, jax.vmap over the population",
        "population": population,
        "rtol": rtol,
        "atol": atol,
        "accuracy_at": "reference parameters, pulse input (the accuracy tests' condition)",
        "jaxflex_error_vs_radau": jaxflex_error,
        "diffrax_error_vs_radau": ladder[-1],
        "tolerance_ladder": ladder,
        "first_call_s": first,
        "run_s": best,
        "simulations_per_s": population / best,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--populations", default="1,10,20,100,1000")
    parser.add_argument("--numpy-candidates", type=int, default=3)
    parser.add_argument("--diffrax-population", type=int, default=20)
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
    peer = bench_diffrax(model, torque, args.diffrax_population, args.seed)
    same = next((r for r in rows if r["population"] == args.diffrax_population), None)
    same = same or bench_population(model, torque, args.diffrax_population, args.seed)
    diffrax_ratios = {
        "same_population": same["simulations_per_s"] / peer["simulations_per_s"],
        "jaxflex_at_population_100": at_100["simulations_per_s"] / peer["simulations_per_s"],
    }
    print(
        f"diffrax Kvaerno5 at rtol {peer['rtol']:g} (population {peer['population']}): "
        f"{peer['simulations_per_s']:.2f} sims/s; jaxflex {diffrax_ratios['same_population']:.0f}x "
        f"at the same population, {diffrax_ratios['jaxflex_at_population_100']:.0f}x at 100"
    )
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
            "diffrax": peer,
            "diffrax_ratios": diffrax_ratios,
            "peak_rss_mb": peak_memory_mb(),
            "load_average_1_5_15min_at_end": list(os.getloadavg()),
            **provenance(),
        },
        overwrite=True,
    )
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
