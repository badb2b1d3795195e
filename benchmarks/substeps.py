"""Benchmark: what fewer sub-steps per sample would buy, and what they cost in accuracy.

For 1, 2 (the default) and 4 sub-steps, and with one sub-step for other weights of the
end-of-step friction (``FRICTION_THETA``: 0.5 trapezoidal, 1 backward Euler), measures the
NRMSE against SciPy Radau (``tests/reference_solver.py``, the accuracy tests' reference) of the
joint angle, tip acceleration and joint velocity at the reference parameters on the paper's
three inputs and on a designed input (the accuracy tests' inputs; targets 0.05 %, 0.5 %, 0.5 %),
and the run time of a one-device vmap over 100 candidates (best of 5, same run).
Writes ``benchmarks/results/substeps.json``.
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

HERE = Path(__file__).parent
sys.path[:0] = [str(HERE), str(HERE.parent / "tests")]
os.environ.setdefault("JAXFLEX_HOST_DEVICES", "1")  # one device: the cost of one core

import jax  # noqa: E402
import numpy as np  # noqa: E402
from profile_simulate import best_time  # noqa: E402
from reference_solver import radau_reference  # noqa: E402

import jaxflex  # noqa: E402
from jaxflex._io import provenance, write_json  # noqa: E402
from jaxflex.design import fourier_basis  # noqa: E402
from jaxflex.model import Model  # noqa: E402
from jaxflex.signals import reference_input  # noqa: E402

simulator = sys.modules["jaxflex.simulation"]
RESULTS = HERE / "results" / "substeps.json"
SETTINGS = ((1, 0.55), (2, 0.55), (4, 0.55), (1, 0.5), (1, 0.8), (1, 1.0))
"""(sub-steps, friction weight) pairs; the default is (2, 0.55)."""
TARGETS = {"joint_angle": 0.05, "tip_acceleration": 0.5, "joint_velocity": 0.5}


def inputs() -> dict[str, np.ndarray]:
    """The accuracy tests' torques: the paper's three and a seeded 20-harmonic design."""
    torques = {name: reference_input(name)[1] for name in ("triangular", "pulse", "half_sine")}
    basis = fourier_basis(1.0, 1e-3, harmonics=20, ramp=0.1)
    shape = np.random.default_rng(0).standard_normal(basis.shape[0]) @ basis
    torques["designed"] = 0.3 * shape / np.max(np.abs(shape))
    return torques


def nrmse_percent(reference: np.ndarray, value) -> float:
    value = np.asarray(value)
    return float(100.0 * np.sqrt(np.mean((reference - value) ** 2) / np.mean(reference**2)))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default=str(RESULTS))
    args = parser.parse_args()
    params = jaxflex.reference_parameters()
    torques = inputs()
    references = {name: radau_reference(Model(), params, t, 1e-3) for name, t in torques.items()}
    default_weight, rows = simulator.FRICTION_THETA, []
    try:
        for n_substeps, weight in SETTINGS:
            simulator.FRICTION_THETA = weight  # read when the simulator is traced
            model = Model(n_substeps=n_substeps)
            run = jax.jit(lambda p, t, m=model: simulator.simulate_core(m, p, t, 1e-3))
            errors = {}
            for name, torque in torques.items():
                out = run(params, torque)
                errors[name] = {
                    channel: nrmse_percent(references[name][k], getattr(out, channel))
                    for k, channel in enumerate(TARGETS)
                }
            seconds = best_time(model, 100, torques["pulse"])
            within = all(errors[n][c] <= t for n in errors for c, t in TARGETS.items())
            rows.append({"n_substeps": n_substeps, "friction_weight": weight,
                         "nrmse_percent": errors, "within_targets": within,
                         "population_100_s": seconds})
            worst = {c: max(e[c] for e in errors.values()) for c in TARGETS}
            print(f"{n_substeps} sub-steps, weight {weight}: worst NRMSE "
                  + ", ".join(f"{c} {v:.4f} %" for c, v in worst.items())
                  + f" ({'within' if within else 'MISSES'} the targets); population 100: "
                  f"{seconds * 1e3:.1f} ms")
    finally:
        simulator.FRICTION_THETA = default_weight
    write_json(
        args.out,
        {
            "benchmark": "substeps",
            "settings": {"inputs": list(torques), "targets_percent": TARGETS,
                         "parameters": "reference", "timing": "one CPU device, best of 5"},
            "rows": rows,
            "load_average_1_5_15min_at_end": list(os.getloadavg()),
            **provenance(),
        },
        overwrite=True,
    )
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
