"""Profile: where one simulator time step spends its time, on one CPU device.

Measures what limits the simulator's throughput (``benchmarks/simulate.py`` reports the
throughput itself): the number of XLA kernels inside the compiled time loop, and the run time
of a plain one-device vmap (best of 5) as the population, the number of finite elements and the
plain Newton steps of the friction solve change, and how that solve converges. A
straight-line fit of time against population separates the fixed cost of a step (kernel
launches) from the cost per candidate.
Writes ``benchmarks/results/profile_simulate.json``.
"""

from __future__ import annotations

import argparse
import importlib
import os
import re
import time
from pathlib import Path

os.environ.setdefault("JAXFLEX_HOST_DEVICES", "1")  # one device: the cost of one core

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

import jaxflex  # noqa: E402, F401  (float64)
from jaxflex._io import provenance, write_json  # noqa: E402
from jaxflex.model import Model  # noqa: E402
from jaxflex.signals import reference_input  # noqa: E402
from jaxflex.testbed import Testbed  # noqa: E402

simulator = importlib.import_module("jaxflex.simulation")
solver = importlib.import_module("jaxflex.friction_solve")
RESULTS = Path(__file__).parent / "results" / "profile_simulate.json"


def compiled_batch(model: Model, population: int, torque):
    params = model.space.from_unit(np.random.default_rng(0).uniform(size=(population, 6)))
    run = jax.jit(jax.vmap(lambda p: simulator.simulate_core(model, p, torque, model.testbed.dt)))
    return run, params


def best_time(model: Model, population: int, torque, repeats: int = 5) -> float:
    run, params = compiled_batch(model, population, torque)
    run(params).joint_angle.block_until_ready()
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        run(params).joint_angle.block_until_ready()
        times.append(time.perf_counter() - start)
    return min(times)


def _computation(text: str, name: str) -> str:
    body = text[text.index(f"%{name} ") :]
    return body[: body.index("\n}")]


def _operations(computation: str) -> dict[str, int]:
    ops = re.findall(r"= \S+ ([a-z\-]+)\(", computation)
    counts = {op: ops.count(op) for op in sorted(set(ops))}
    for bookkeeping in ("get-tuple-element", "parameter", "tuple", "constant"):
        counts.pop(bookkeeping, None)
    return counts


def kernels_per_sample(model: Model, torque) -> tuple[dict[str, int], dict[str, int]]:
    """Operations in the body of the compiled time loop (one sample = n_substeps steps), and in
    one iteration of the friction solve's loop nested in it (its body and its condition)."""
    run, params = compiled_batch(model, 100, torque)
    text = run.lower(params).compile().as_text()
    loop = next(
        line for line in text.splitlines()
        if " while(" in line and f'"known_trip_count":{{"n":"{torque.shape[0]}"}}' in line
    )
    body = _computation(text, re.search(r"body=%?([\w.\-]+)", loop).group(1))
    nested = next(line for line in body.splitlines() if " while(" in line)
    iteration = {}
    for part in ("body", "condition"):
        name = re.search(part + r"=%?([\w.\-]+)", nested).group(1)
        for op, n in _operations(_computation(text, name)).items():
            iteration[op] = iteration.get(op, 0) + n
    return _operations(body), iteration


def friction_iterations(model: Model, torque, population: int = 10) -> dict[str, float]:
    """How the friction solve converges, per sub-step: the share of candidates' steps that the
    plain Newton steps did not converge (solved again by the safeguarded loop), the share of
    vmapped steps in which that loop ran for some candidate, and the law's evaluations per
    candidate, recorded by a host callback in each solve."""
    counts = []
    solve = solver.bracketed_newton

    def counted(residual, lo, hi, guess, **options):
        root, count, extra = solve(residual, lo, hi, guess, **options)
        jax.debug.callback(lambda c: counts.append(int(c)), count)
        return root, count, extra

    solver.bracketed_newton = counted
    try:
        run, params = compiled_batch(model, population, torque)
        run(params).joint_angle.block_until_ready()
        jax.effects_barrier()
    finally:
        solver.bracketed_newton = solve
    per_step = np.asarray(counts).reshape(-1, population)  # the callback runs lane by lane
    loop = per_step - (solver.NEWTON_STEPS + 1)  # evaluations after the plain steps
    return {
        "population": population,
        "plain_newton_steps": solver.NEWTON_STEPS,
        "share_of_candidate_steps_solved_by_the_loop": float((loop > 0).mean()),
        "share_of_vmapped_steps_running_the_loop": float((loop > 0).any(axis=1).mean()),
        "evaluations_per_candidate_step": float(per_step.mean()),
        "loop_iterations_per_vmapped_step": float(loop.max(axis=1).mean()),
        "most_loop_iterations": int(loop.max()),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default=str(RESULTS))
    args = parser.parse_args()
    torque = jnp.asarray(reference_input("pulse")[1])
    samples = torque.shape[0]
    model = Model()

    kernels, per_iteration = kernels_per_sample(model, torque)
    launches = ("fusion", "copy", "custom-call")
    launched = sum(n for op, n in kernels.items() if op in launches)
    per_friction_iteration = sum(n for op, n in per_iteration.items() if op in launches)
    print(
        f"kernels per sample ({model.n_substeps} sub-steps): {launched} {kernels}, plus "
        f"{per_friction_iteration} per friction iteration {per_iteration}"
    )

    iterations = friction_iterations(model, torque)
    print(
        f"friction solve (population {iterations['population']}): "
        f"{iterations['share_of_candidate_steps_solved_by_the_loop']:.2e} of the candidates' "
        f"sub-steps need the safeguarded loop (at most {iterations['most_loop_iterations']} "
        f"iterations), {iterations['share_of_vmapped_steps_running_the_loop']:.2e} of the vmapped "
        f"sub-steps run it; {iterations['evaluations_per_candidate_step']:.3f} evaluations of "
        "the law per candidate and sub-step"
    )
    total = launched + (
        model.n_substeps
        * iterations["loop_iterations_per_vmapped_step"]
        * per_friction_iteration
    )
    print(f"kernel launches per sample, the loop's iterations included: {total:.0f}")

    populations = [1, 10, 25, 50, 100]
    per_population = [best_time(model, p, torque) for p in populations]
    slope, intercept = np.polyfit(populations, per_population, 1)
    for p, t in zip(populations, per_population, strict=True):
        print(f"population {p:4d}: {t * 1e3:7.1f} ms ({p / t:6.0f} sims/s)")
    print(
        f"fit: {intercept * 1e3:.1f} ms fixed + {slope * 1e3:.3f} ms per candidate; per sample "
        f"{intercept / samples * 1e6:.2f} us fixed = {intercept / samples / total * 1e9:.0f} "
        f"ns per kernel"
    )

    per_mesh = {}
    for n_el in (2, 5, 10):
        per_mesh[n_el] = best_time(Model(testbed=Testbed(n_elements=n_el)), 100, torque)
        print(f"n_el {n_el:2d} ({2 * n_el} modes), population 100: {per_mesh[n_el] * 1e3:.1f} ms")


    per_steps = {}
    default = solver.NEWTON_STEPS
    try:  # 0: every lane's solve after its first evaluation is the safeguarded loop's
        for n in (0, 1, 2, 3):
            solver.NEWTON_STEPS = n
            per_steps[n] = best_time(model, 100, torque)
            print(f"{n} plain Newton steps before the loop, population 100: "
                  f"{per_steps[n] * 1e3:.1f} ms")
    finally:
        solver.NEWTON_STEPS = default

    write_json(
        args.out,
        {
            "benchmark": "profile_simulate",
            "settings": {
                "input": "pulse", "samples": samples, "n_substeps": model.n_substeps,
                "device": "one CPU device (JAXFLEX_HOST_DEVICES=1)", "repeats": 5,
            },
            "kernels_per_sample": kernels,
            "kernels_per_friction_iteration": per_iteration,
            "kernel_launches_per_sample": launched,
            "kernel_launches_per_sample_with_friction_iterations": total,
            "time_vs_population_s": dict(zip(map(str, populations), per_population, strict=True)),
            "linear_fit": {"fixed_s": intercept, "per_candidate_s": slope},
            "time_vs_elements_at_population_100_s": {str(k): v for k, v in per_mesh.items()},
            "friction_iterations_per_substep": iterations,
            "time_vs_plain_newton_steps_at_population_100_s": {
                str(k): v for k, v in per_steps.items()
            },
            "load_average_1_5_15min_at_end": list(os.getloadavg()),
            **provenance(),
        },
        overwrite=True,
    )
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
