"""Benchmark: the Quanser rotary flexible link, physical model against a black-box baseline.

Both models are fitted on the square-wave run (500 Hz, 5 s) and simulated, from rest and from
the logged voltage alone, on the held-out random run 985 (1 kHz, 60 s):

* physical — the packaged arm ``quanser_rotflex`` (voltage drive, encoder, root strain gauge as
  Quanser's deflection angle), six parameters identified by DE + Levenberg–Marquardt
  (``jaxflex.identify``) on both channels; and the same with the ``torque_offset`` effect
  (seven parameters);
* black box — a linear state-space model from voltage to (θ, α) identified by N4SID (the
  ``nfoursid`` package, dev extra) at every order from 2 to 12, simulated output-error
  (no Kalman gain) on the held-out voltage decimated to 500 Hz; the best held-out order is
  the baseline reported.

NRMSE in percent per channel (``100·rms(y − ŷ)/rms(y)``) over the whole records. The data come
from ``JAXFLEX_DATA_DIR`` or the pinned upstream URLs (jaxflex.datasets); nothing is stored.
Results go to ``benchmarks/results/real_rig.json``, and the figures of the fit with the torque
offset against both runs (``validate --report``'s time figures: every channel in its unit, the
residual below) to ``real_rig_square_wave.png`` and ``real_rig_random_985.png`` beside it;
``--quick`` shrinks the physical fit.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
import scipy.linalg
import scipy.signal

from jaxflex import datasets, get_effect, identify
from jaxflex._io import check_writable, provenance, write_json
from jaxflex.arm import load_arm
from jaxflex.comparison import compare
from jaxflex.measured import model_record, validate
from jaxflex.metrics import nrmse
from jaxflex.plots._style import save_figure
from jaxflex.plots.compare import plot_time

ROOT = Path(__file__).resolve().parent
ARM = "quanser_rotflex"  # the packaged arm file (jaxflex/rigs)
RESULTS = ROOT / "results" / "real_rig.json"
CHANNELS = ("joint_angle", "deflection_angle")


def clamped_frequencies(arm, params) -> list[float]:
    """The first bending frequencies (Hz) with the hub held still."""
    structure = arm.structure({k: np.float64(v) for k, v in params.items()})
    mass, stiffness = np.asarray(structure.mass)[1:, 1:], np.asarray(structure.stiffness)[1:, 1:]
    omega2 = scipy.linalg.eigh(stiffness, mass, eigvals_only=True)
    return [float(f) for f in np.sqrt(omega2[:2]) / (2 * np.pi)]


def physical(arm, fit_run, held_out, budget: tuple[int, int], seed: int, effects=()) -> dict:
    """Identify the rig's model (plus ``effects``) on ``fit_run``; score both runs."""
    generations, population = budget
    model = arm.with_effects(*effects)
    start = time.perf_counter()
    fit = identify(
        model_record(model, fit_run),
        model,
        generations=generations,
        population=population,
        seed=seed,
        intervals=False,
    )
    wall = time.perf_counter() - start
    params = {k: float(v) for k, v in fit.params.items()}
    scores = validate(model, params, [fit_run, held_out])
    return model, params, {
        "effects": [e.name for e in effects],
        "settings": {"generations": generations, "population": population, "seed": seed},
        "wall_time_s": wall,
        "n_parameters": len(params) - len(arm.fixed),
        "parameters": params,
        "clamped_frequencies_hz": clamped_frequencies(arm, params),
        "nrmse_fit": scores[fit_run.name],
        "nrmse_held_out": scores[held_out.name],
    }


def _columns(record, every: int = 1) -> tuple[np.ndarray, np.ndarray]:
    u = record.channel("voltage")[::every, None]
    y = np.column_stack([record.channel(c) for c in CHANNELS])[::every]
    return u, y - y[0]


def black_box(fit_run, held_out, orders=range(2, 13), block_rows: int = 30) -> dict:
    """N4SID state-space models of each order: fit, then output-error simulation."""
    import pandas as pd
    from nfoursid.nfoursid import NFourSID

    u, y = _columns(fit_run)
    every = int(round(fit_run.dt / held_out.dt))
    u_out, y_out = _columns(held_out, every)
    frame = pd.DataFrame({"voltage": u[:, 0], **{c: y[:, i] for i, c in enumerate(CHANNELS)}})
    n4sid = NFourSID(
        frame, output_columns=list(CHANNELS), input_columns=["voltage"], num_block_rows=block_rows
    )
    n4sid.subspace_identification()
    models = []
    for order in orders:
        ss, _ = n4sid.system_identification(rank=order)
        system = (ss.a, ss.b, ss.c, ss.d, fit_run.dt)
        scores = {}
        for label, (uu, yy) in (("fit", (u, y)), ("held_out", (u_out, y_out))):
            _, y_sim, _ = scipy.signal.dlsim(system, uu)
            scores[label] = {c: nrmse(yy[:, i], y_sim[:, i]) for i, c in enumerate(CHANNELS)}
        n_parameters = sum(m.size for m in (ss.a, ss.b, ss.c, ss.d))
        models.append(
            {
                "order": order,
                "n_parameters": int(n_parameters),
                "stable": bool(np.max(np.abs(np.linalg.eigvals(ss.a))) < 1.0),
                "nrmse_fit": scores["fit"],
                "nrmse_held_out": scores["held_out"],
            }
        )

    def worst_held_out(m):
        values = list(m["nrmse_held_out"].values())
        return max(values) if all(np.isfinite(values)) else np.inf

    best = min(models, key=worst_held_out)
    return {
        "block_rows": block_rows,
        "held_out_rate_hz": 1.0 / (held_out.dt * every),
        "best_order": best["order"],
        "best": best,
        "orders": models,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="small physical fit (DE 10 × 20)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", type=Path, default=RESULTS)
    args = parser.parse_args()
    figures = [args.out.with_name(f"real_rig_{name}.png") for name in ("square_wave", "random_985")]
    for path in (args.out, *figures):
        check_writable(path, overwrite=True)
    arm = load_arm(ARM)
    records = datasets.load("quanser_rotflex")
    fit_run, held_out = records["square_wave"], records["random_985"]
    budget = (10, 20) if args.quick else (40, 40)
    results = {
        "data": {r.name: r.metadata["source"] for r in (fit_run, held_out)},
        "licence": fit_run.metadata["licence"],
        "arm": ARM,
        "black_box": black_box(fit_run, held_out),
    }
    write_json(args.out, results | {"provenance": provenance()}, overwrite=True)
    results["physical"] = physical(arm, fit_run, held_out, budget, args.seed)[2]
    offset = (get_effect("torque_offset"),)
    model, params, results["physical_offset"] = physical(arm, fit_run, held_out, budget,
                                                         args.seed, offset)
    write_json(args.out, results | {"provenance": provenance()}, overwrite=True)
    ready = [model_record(model, r) for r in (fit_run, held_out)]
    comparison = compare(model, params, ready, fit_names=[fit_run.name], t_end=None)
    for i, path in enumerate(figures):
        save_figure(plot_time(comparison, i), path, overwrite=True)
    for label in ("physical", "physical_offset", "black_box"):
        entry = results[label]["best"] if label == "black_box" else results[label]
        print(
            f"{label:>15}: {entry['n_parameters']:3d} parameters, held-out NRMSE "
            + ", ".join(f"{c} {v:.1f} %" for c, v in entry["nrmse_held_out"].items())
        )


if __name__ == "__main__":
    main()
