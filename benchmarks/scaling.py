"""Benchmark: how the simulation cost and memory grow with the mesh, the record and the population.

Three axes through one base point (pulse input, n_el = 10, 2 s at 1 kHz, population 100, two
sub-steps): the number of finite elements (10, 20, 40), the record length (2, 10, 60 s) and the
population (1, 10, 100, 1,000, 10,000). Each point runs ``simulate_batch``'s XLA program (the
population split across the CPU devices, :mod:`jaxflex.parallel`) in a fresh Python process, so
that its memory is its own, and reports:

* compile time and best-of-``k`` run time after one warm-up run (``k`` = 3, fewer where the
  runs add up to over 2 s), and simulations and simulated samples per second;
* memory, two ways: the peak resident set size of the process (``ru_maxrss``: the JAX runtime,
  the compiled program, inputs and outputs on the host, everything) beside that of the same
  process right after importing jaxflex, and XLA's own account of the compiled program
  (``Compiled.memory_analysis()``: argument, output and temporary buffers, in bytes).

``--quick`` drops the largest point of each axis; ``--populations`` replaces the population axis
(on an accelerator, say, to go past 10,000) and ``--axes`` keeps only the axes named.
``--program fused`` measures the single-kernel time loop of :mod:`jaxflex.fused` (a GPU) instead
of ``simulate_batch``'s XLA program; each point also times the per-candidate coefficients (the
modal decomposition) alone. Runs on JAX's default backend (the CPU devices, or
one GPU where there is one; recorded with each point). Writes ``benchmarks/results/scaling.json``
(``--out`` elsewhere).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import resource
import subprocess
import sys
import time
from pathlib import Path

RESULTS = Path(__file__).parent / "results" / "scaling.json"
BASE = {"n_elements": 10, "duration_s": 2.0, "population": 100}
AXES = {
    "n_elements": (10, 20, 40),
    "duration_s": (2.0, 10.0, 60.0),
    "population": (1, 10, 100, 1000, 10000),
}
LONG_RUN_S = 2.0
"""Timing stops once the timed runs add up to this (the spread is small next to long runs)."""


def peak_rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def best_time(run, budget_s: float = LONG_RUN_S) -> float:
    """Best of up to three timed calls of ``run`` after a warm-up call (fewer past ``budget_s``)."""
    run()
    times: list[float] = []
    while len(times) < 3 and sum(times) < budget_s:
        start = time.perf_counter()
        run()
        times.append(time.perf_counter() - start)
    return min(times)


def measure(
    n_elements: int, duration_s: float, population: int, seed: int, program: str = "scan"
) -> dict:
    """One point, in this process: compile, time and account for the memory of the program."""
    import jax
    import numpy as np

    import jaxflex  # noqa: F401  (float64, host devices)
    from jaxflex.fused import simulate_fused
    from jaxflex.model import Model
    from jaxflex.parallel import population_vmap
    from jaxflex.signals import reference_input
    from jaxflex.simulation import simulate_core, step_coefficients
    from jaxflex.testbed import Testbed

    rss_after_import = peak_rss_mb()
    model = Model(Testbed(n_elements=n_elements))
    _, torque = reference_input("pulse", duration=duration_s, dt=model.testbed.dt)
    u = np.random.default_rng(seed).uniform(size=(population, len(model.space)))
    params = model.space.from_unit(u)
    dt = model.testbed.dt
    if program == "fused":
        jitted = jax.jit(lambda p, t: simulate_fused(model, p, t, dt))
    else:
        jitted = jax.jit(  # what simulate_batch runs where the fused kernel does not
            lambda p, t: population_vmap(lambda q, s: simulate_core(model, q, s, dt), p, t)
        )
    start = time.perf_counter()
    compiled = jitted.lower(params, torque).compile()
    compile_s = time.perf_counter() - start
    best = best_time(lambda: compiled(params, torque).joint_angle.block_until_ready())
    coefficients = jax.jit(jax.vmap(lambda q: step_coefficients(model, q, dt)))
    coefficients_s = best_time(lambda: jax.block_until_ready(coefficients(params)))
    memory = compiled.memory_analysis()
    return {
        "n_elements": n_elements,
        "duration_s": duration_s,
        "samples": int(torque.size),
        "population": population,
        "program": program,
        "compile_s": compile_s,
        "run_s": best,
        "coefficients_s": coefficients_s,
        "simulations_per_s": population / best,
        "candidate_samples_per_s": population * torque.size / best,
        "peak_rss_mb": peak_rss_mb(),
        "rss_after_import_mb": rss_after_import,
        "xla_argument_mb": memory.argument_size_in_bytes / 2**20,
        "xla_output_mb": memory.output_size_in_bytes / 2**20,
        "xla_temp_mb": memory.temp_size_in_bytes / 2**20,
        "cpu_devices": len(jax.devices("cpu")),
        "backend": jax.default_backend(),
        "device_kind": jax.devices()[0].device_kind,
    }


def points(axes: dict[str, tuple], quick: bool) -> list[dict]:
    """The base point and each axis through it, without repeats (largest dropped if quick)."""
    out: list[dict] = []
    for axis, values in axes.items():
        for value in values[:-1] if quick else values:
            point = {**BASE, axis: value}
            if point not in out:
                out.append(point)
    return out


def run_point(point: dict, seed: int, program: str) -> dict:
    """:func:`measure` in a fresh interpreter (its peak memory is this point's alone)."""
    command = [sys.executable, __file__, "--point", json.dumps(point), "--seed", str(seed),
               "--program", program]
    done = subprocess.run(command, capture_output=True, text=True, check=False)
    if done.returncode != 0:
        raise RuntimeError(f"point {point} failed:\n{done.stderr[-3000:]}")
    return json.loads(done.stdout.splitlines()[-1])


def growth(rows: list[dict], axis: str, key: str) -> float:
    """The exponent ``b`` of ``key ∝ axis^b`` between the smallest and largest point measured."""
    line = [r for r in rows if all(r[k] == v for k, v in BASE.items() if k != axis)]
    low, high = min(line, key=lambda r: r[axis]), max(line, key=lambda r: r[axis])
    return math.log(high[key] / low[key]) / math.log(high[axis] / low[axis])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="drop the largest point of each axis")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--populations", type=int, nargs="+", help="the population axis")
    parser.add_argument("--axes", nargs="+", choices=list(AXES), help="only these axes")
    parser.add_argument("--program", choices=("scan", "fused"), default="scan",
                        help="simulate_batch's XLA program (scan) or the fused GPU kernel")
    parser.add_argument("--point", help=argparse.SUPPRESS)  # internal: one point, JSON out
    parser.add_argument("--out", default=str(RESULTS))
    args = parser.parse_args()
    if args.point:
        print(json.dumps(measure(**json.loads(args.point), seed=args.seed,
                                 program=args.program)))
        return

    from _output import checked_out

    from jaxflex._io import provenance, write_json

    bad = [p for p in args.populations or () if p < 1]
    if bad:
        parser.error(f"--populations: each population must be at least 1, got {bad}")
    if args.program == "fused":
        import jax

        if jax.default_backend() != "gpu":
            parser.error("--program fused: the kernel runs on a GPU (here it would only be "
                         f"interpreted), and JAX's default backend is {jax.default_backend()}")
    out = checked_out(parser, args.out)
    axes = {**AXES, "population": tuple(args.populations or AXES["population"])}
    axes = {k: v for k, v in axes.items() if args.axes is None or k in args.axes}
    started = time.perf_counter()
    rows = []
    for point in points(axes, args.quick):
        row = run_point(point, args.seed, args.program)
        rows.append(row)
        print(
            f"n_el {row['n_elements']:3d}, {row['duration_s']:5.1f} s, population "
            f"{row['population']:6d}: compile {row['compile_s']:5.2f} s, run "
            f"{row['run_s']:8.4f} s (coefficients {row['coefficients_s']:7.4f} s), "
            f"{row['simulations_per_s']:8.0f} sims/s, peak RSS "
            f"{row['peak_rss_mb']:6.0f} MB, XLA temp {row['xla_temp_mb']:7.1f} MB",
            flush=True,
        )
    exponents = {
        axis: {key: growth(rows, axis, key) for key in ("run_s", "peak_rss_mb", "xla_temp_mb")}
        for axis in axes
    }
    write_json(
        out,
        {
            "benchmark": "scaling",
            "settings": {
                "input": "pulse",
                "base": BASE,
                "axes": {k: v[:-1] if args.quick else v for k, v in axes.items()},
                "quick": args.quick,
                "seed": args.seed,
                "program": "simulate_batch's XLA program (population split across the CPU "
                "devices, or whole on one accelerator)" if args.program == "scan" else
                "simulate_fused (one GPU kernel for the time loop)",
                "memory": "peak_rss_mb: ru_maxrss of a fresh process per point; xla_*_mb: "
                "Compiled.memory_analysis() of the program",
            },
            "points": rows,
            "growth_exponents": exponents,
            "wall_s": time.perf_counter() - started,
            "load_average_1_5_15min_at_end": list(os.getloadavg()),
            **provenance(),
        },
        overwrite=True,
    )
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
