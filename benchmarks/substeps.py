"""Benchmark: what fewer sub-steps per sample would buy, and what they cost in accuracy.

For 1, 2 (the default) and 4 sub-steps, and with one sub-step for other weights of the
end-of-step friction (``FRICTION_THETA``: 0.5 trapezoidal, 1 backward Euler), measures the
NRMSE against SciPy Radau (``tests/reference_solver.py``, the accuracy tests' reference) of the
joint angle, tip acceleration and joint velocity at the reference parameters on the paper's
three inputs and on a designed input (the accuracy tests' inputs; targets 0.05 %, 0.5 %, 0.5 %),
and the run time of a one-device vmap over 100 candidates (best of interleaved rounds, same
run).
Writes ``benchmarks/results/substeps.json``.
"""

from __future__ import annotations

import argparse
import importlib
import os
import sys
import time
from pathlib import Path

HERE = Path(__file__).parent
sys.path[:0] = [str(HERE), str(HERE.parent / "tests")]
os.environ.setdefault("JAXFLEX_HOST_DEVICES", "1")  # one device: the cost of one core

import jax  # noqa: E402
import numpy as np  # noqa: E402
from _output import checked_out  # noqa: E402
from profile_simulate import compiled_batch  # noqa: E402
from reference_solver import designed_torque, radau_reference  # noqa: E402

import jaxflex  # noqa: E402
from jaxflex._io import provenance, write_json  # noqa: E402
from jaxflex.metrics import nrmse  # noqa: E402
from jaxflex.model import Model  # noqa: E402
from jaxflex.signals import reference_input  # noqa: E402

simulator = importlib.import_module("jaxflex.simulation")
RESULTS = HERE / "results" / "substeps.json"
SETTINGS = ((1, 0.55), (2, 0.55), (4, 0.55), (1, 0.5), (1, 0.8), (1, 1.0))
"""(sub-steps, friction weight) pairs; the default is (2, 0.55)."""
TARGETS = {"joint_angle": 0.05, "tip_acceleration": 0.5, "joint_velocity": 0.5}
ROUNDS = 15
"""Timing rounds; each runs every setting once, in turn, so that the machine's load drifts
over all of them alike (one setting after another, this machine's noise swamped the ratios)."""


def inputs() -> dict[str, np.ndarray]:
    """The accuracy tests' torques: the paper's three and their designed input."""
    torques = {name: reference_input(name)[1] for name in ("triangular", "pulse", "half_sine")}
    return {**torques, "designed": designed_torque()}


def interleaved_best(programs: list, rounds: int = ROUNDS) -> list[float]:
    """Best time of each compiled ``(run, params)`` over ``rounds`` rounds that run them in turn."""
    best = [float("inf")] * len(programs)
    for _ in range(rounds):
        for i, (run, params) in enumerate(programs):
            start = time.perf_counter()
            run(params).joint_angle.block_until_ready()
            best[i] = min(best[i], time.perf_counter() - start)
    return best


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default=str(RESULTS))
    args = parser.parse_args()
    out = checked_out(parser, args.out)  # before any work
    params = jaxflex.reference_parameters()
    torques = inputs()
    references = {name: radau_reference(Model(), params, t, 1e-3) for name, t in torques.items()}
    default_weight, rows, programs = simulator.FRICTION_THETA, [], []
    try:
        for n_substeps, weight in SETTINGS:
            simulator.FRICTION_THETA = weight  # read when the simulator is traced
            model = Model(n_substeps=n_substeps)
            run = jax.jit(lambda p, t, m=model: simulator.simulate_core(m, p, t, 1e-3))
            errors = {}
            for name, torque in torques.items():
                simulated = run(params, torque)
                errors[name] = {
                    channel: nrmse(references[name][k], getattr(simulated, channel))
                    for k, channel in enumerate(TARGETS)
                }
            batch, candidates = compiled_batch(model, 100, torques["pulse"])
            batch(candidates).joint_angle.block_until_ready()  # traced with this weight
            programs.append((batch, candidates))
            within = all(errors[n][c] <= t for n in errors for c, t in TARGETS.items())
            rows.append({"n_substeps": n_substeps, "friction_weight": weight,
                         "nrmse_percent": errors, "within_targets": within})
    finally:
        simulator.FRICTION_THETA = default_weight
    for row, seconds in zip(rows, interleaved_best(programs), strict=True):
        row["population_100_s"] = seconds
        worst = {c: max(e[c] for e in row["nrmse_percent"].values()) for c in TARGETS}
        print(f"{row['n_substeps']} sub-steps, weight {row['friction_weight']}: worst NRMSE "
              + ", ".join(f"{c} {v:.4f} %" for c, v in worst.items())
              + f" ({'within' if row['within_targets'] else 'MISSES'} the targets); "
              f"population 100: {seconds * 1e3:.1f} ms")
    write_json(
        out,
        {
            "benchmark": "substeps",
            "settings": {"inputs": list(torques), "targets_percent": TARGETS,
                         "parameters": "reference",
                         "timing": f"one CPU device, best of {ROUNDS} interleaved rounds"},
            "rows": rows,
            "load_average_1_5_15min_at_end": list(os.getloadavg()),
            **provenance(),
        },
        overwrite=True,
    )
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
