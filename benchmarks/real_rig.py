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

Run 985 is closed-loop (the voltage is the controller's output) and the plant has a free
rigid-body mode, so a free simulation drifts with every torque mismatch; beside it come the
k-step-ahead predictions (0.1, 0.5 and 2 s, and one step) of the model's Kalman filter
(``jaxflex.kalman``; its noise levels fitted by maximum likelihood on the square-wave run) and
of each N4SID model's own steady-state Kalman predictor (the noise covariances nfoursid
estimates), both on run 985 at 500 Hz. Then prediction error against output error: the rig
(with the torque offset, its four lowest modes advanced, the others quasi-static, to keep the
filter's population cheap) fitted on the first half of run 985 by each criterion, simulated and
predicted over the whole run, and scored on its second half.

NRMSE in percent per channel (``100·rms(y − ŷ)/rms(y)``) over the whole records. The data come
from ``JAXFLEX_DATA_DIR`` or the pinned upstream URLs (jaxflex.datasets); nothing is stored.
Results go to ``benchmarks/results/real_rig.json``, and the figures of the fit with the torque
offset against both runs (``validate --report``'s time figures: every channel in its unit, the
residual below) to ``real_rig_square_wave.png`` and ``real_rig_random_985.png`` beside it, and
run 985's simulation beside its predictions to ``real_rig_prediction_985.png``; ``--quick``
shrinks the physical fits.
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
from jaxflex.data import Record
from jaxflex.measured import model_record, validate
from jaxflex.metrics import nrmse
from jaxflex.plots._style import save_figure
from jaxflex.plots.compare import plot_time
from jaxflex.plots.prediction import plot_prediction
from jaxflex.prediction_report import compare_predictions

ROOT = Path(__file__).resolve().parent
ARM = "quanser_rotflex"  # the packaged arm file (jaxflex/rigs)
RESULTS = ROOT / "results" / "real_rig.json"
CHANNELS = ("joint_angle", "deflection_angle")
HORIZONS = (0.1, 0.5, 2.0)
"""Prediction horizons (s)."""
FILTER_MODES = 4
"""Modes the rig advances in the criteria comparison (the others quasi-static)."""


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
    scores = validate([fit_run, held_out], model, params)
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
        ss, covariance = n4sid.system_identification(rank=order)
        system = (ss.a, ss.b, ss.c, ss.d, fit_run.dt)
        scores = {}
        for label, (uu, yy) in (("fit", (u, y)), ("held_out", (u_out, y_out))):
            _, y_sim, _ = scipy.signal.dlsim(system, uu)
            scores[label] = {c: nrmse(yy[:, i], y_sim[:, i]) for i, c in enumerate(CHANNELS)}
        every_k = {f"{h:g} s": int(round(h / fit_run.dt)) for h in HORIZONS}
        predicted = kalman_predictions(ss, covariance, u_out, y_out, {"one_step": 1} | every_k)
        n_parameters = sum(m.size for m in (ss.a, ss.b, ss.c, ss.d))
        models.append(
            {
                "order": order,
                "n_parameters": int(n_parameters),
                "stable": bool(np.max(np.abs(np.linalg.eigvals(ss.a))) < 1.0),
                "nrmse_fit": scores["fit"],
                "nrmse_held_out": scores["held_out"],
                "nrmse_prediction_held_out": {
                    label: {c: nrmse(y_out[:, i], p[:, i]) for i, c in enumerate(CHANNELS)}
                    for label, p in predicted.items()},
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


def kalman_predictions(ss, covariance, u, y, steps: dict[str, int]) -> dict[str, np.ndarray]:
    """``ŷ_{t|t−k}`` of a state-space model's steady-state Kalman predictor (``covariance`` of
    measurement and process noise as nfoursid gives it) for each ``k`` of ``steps``; the first
    ``k`` samples are the simulation from rest."""
    a, b, c, d = ss.a, ss.b, ss.c, ss.d
    ny = c.shape[0]
    r, s, q = covariance[:ny, :ny], covariance[ny:, :ny], covariance[ny:, ny:]
    p = scipy.linalg.solve_discrete_are(a.T, c.T, q, r, s=s)
    gain = (a @ p @ c.T + s) @ np.linalg.inv(c @ p @ c.T + r)
    n = u.shape[0]
    ahead = np.zeros((n, a.shape[0]))  # x̂_{t+1|t}
    x = np.zeros(a.shape[0])
    for t in range(n):
        x = a @ x + b @ u[t] + gain @ (y[t] - c @ x - d @ u[t])
        ahead[t] = x
    _, simulated, _ = scipy.signal.dlsim((a, b, c, d, 1.0), u)
    out = {}
    for label, k in steps.items():
        xs = ahead[: n - k].copy()
        for j in range(1, k):
            xs = xs @ a.T + u[j : n - k + j] @ b.T
        predicted = xs @ c.T + u[k:] @ d.T
        out[label] = np.concatenate([simulated[:k], predicted])
    return out


def decimated(record: Record, every: int) -> Record:
    """Every ``every``-th sample of ``record`` (the black box's held-out rate)."""
    return Record.from_columns({c: record.channel(c)[::every] for c in record.columns},
                               name=record.name, metadata=record.metadata)


def prediction(model, params, fit_run, held_out) -> tuple[dict, object]:
    """Run 985 at the fit run's rate: the fit's simulation beside its Kalman filter's
    predictions, the filter's noise levels fitted by maximum likelihood on the fit run."""
    every = int(round(fit_run.dt / held_out.dt))
    [on_fit] = compare_predictions([model_record(model, fit_run)], model, params, HORIZONS,
                                   fit_names=[fit_run.name])
    levels = on_fit.prediction
    [on_held] = compare_predictions([decimated(model_record(model, held_out), every)],
                                    model, params,
                                    HORIZONS, noise=levels.sigma_y,
                                    disturbance=levels.disturbance)
    return {
        "noise_fitted_on": fit_run.name,
        "disturbance_n_m": levels.disturbance,
        "measurement_noise": dict(levels.sigma_y),
        "held_out_rate_hz": 1.0 / (held_out.dt * every),
        "nrmse_fit": on_fit.scores(),
        "nrmse_held_out": on_held.scores(),
    }, on_held


def _second_half(row, half: int) -> dict[str, dict[str, float]]:
    """NRMSE (percent) of a prediction comparison's series over the samples from ``half`` on."""
    p = row.prediction
    series = {"simulation": row.simulated, "one_step": p.one_step} | {
        f"{h:g} s": y for h, y in p.predicted.items()}
    return {label: {c: nrmse(p.measured[i, half:], y[i, half:])
                    for i, c in enumerate(row.channels)} for label, y in series.items()}


def criteria(arm, held_out, every: int, budget: tuple[int, int], seed: int) -> dict:
    """Output error against prediction error: each fitted on the first half of run 985 (at the
    black box's rate), both simulated and predicted over the whole run and scored on its second
    half (the filter's noise levels: the prediction-error fit's own, for output error fitted by
    maximum likelihood on the first half)."""
    generations, population = budget
    model = arm.replace(n_modes=FILTER_MODES).with_effects(get_effect("torque_offset"))
    whole = decimated(model_record(model, held_out), every)
    half = whole.n_samples // 2
    first = Record.from_columns({c: whole.channel(c)[:half] for c in whole.columns},
                                name=f"{whole.name}_first_half")
    results = {"n_modes": FILTER_MODES, "fit_samples": half, "held_out_samples":
               whole.n_samples - half, "settings": {"generations": generations,
                                                    "population": population, "seed": seed}}
    for criterion in ("output", "prediction"):
        start = time.perf_counter()
        fit = identify(first, model, generations=generations, population=population, seed=seed,
                       intervals=False, criterion=criterion)
        wall = time.perf_counter() - start
        params = {k: float(v) for k, v in fit.params.items()}
        if criterion == "prediction":
            noise = {"noise": fit.settings["measurement_noise"],
                     "disturbance": fit.settings["disturbance"]}
        else:
            [own] = compare_predictions([first], model, params, ())
            noise = {"noise": own.prediction.sigma_y, "disturbance": own.prediction.disturbance}
        [row] = compare_predictions([whole], model, params, HORIZONS, **noise)
        results[criterion] = {"parameters": params, "wall_time_s": wall,
                              "disturbance_n_m": noise["disturbance"],
                              "measurement_noise": dict(noise["noise"]),
                              "nrmse_second_half": _second_half(row, half)}
    return results


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="small physical fit (DE 10 × 20)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", type=Path, default=RESULTS)
    args = parser.parse_args()
    figures = [args.out.with_name(f"real_rig_{name}.png")
               for name in ("square_wave", "random_985", "prediction_985")]
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
    comparison = compare(ready, model, params, fit_names=[fit_run.name], t_end=None)
    for i, path in enumerate(figures[:2]):
        save_figure(plot_time(comparison, i), path, overwrite=True)
    results["prediction"], row = prediction(model, params, fit_run, held_out)
    units = {c: arm.sensor(c).channel_unit for c in CHANNELS}
    save_figure(plot_prediction(row, units=units), figures[2], overwrite=True)
    write_json(args.out, results | {"provenance": provenance()}, overwrite=True)
    every = int(round(fit_run.dt / held_out.dt))
    results["criteria"] = criteria(arm, held_out, every, budget, args.seed)
    write_json(args.out, results | {"provenance": provenance()}, overwrite=True)
    for label in ("physical", "physical_offset", "black_box"):
        entry = results[label]["best"] if label == "black_box" else results[label]
        print(
            f"{label:>15}: {entry['n_parameters']:3d} parameters, held-out NRMSE "
            + ", ".join(f"{c} {v:.1f} %" for c, v in entry["nrmse_held_out"].items())
        )
    for label, scores in (("kalman", results["prediction"]["nrmse_held_out"]),
                          ("n4sid kalman", results["black_box"]["best"][
                              "nrmse_prediction_held_out"]),
                          *((f"{c} error", results["criteria"][c]["nrmse_second_half"])
                            for c in ("output", "prediction"))):
        print(f"{label:>15}: joint angle NRMSE "
              + ", ".join(f"{k} {v['joint_angle']:.1f} %" for k, v in scores.items()))


if __name__ == "__main__":
    main()
