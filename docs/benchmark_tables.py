"""The documentation's measured figures, read from ``benchmarks/results/*.json``: none is copied
by hand, so a figure on a page is the one its results file holds.

:data:`TABLES` builds each table by name, :func:`lookup` and :func:`formatted` give one value;
``docs/generated.py`` writes them into the README and the pages (``<!-- generated: NAME -->``
blocks, ``<!-- value: FILE/KEY/... | SPEC -->`` values).
"""

from __future__ import annotations

import json
from collections.abc import Callable
from functools import cache
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results"


@cache
def result(name: str) -> dict:
    """The results file ``benchmarks/results/NAME.json``."""
    return json.loads((RESULTS / f"{name}.json").read_text(encoding="utf-8"))


def lookup(path: str) -> object:
    """The value at ``FILE/KEY/...`` (a list is indexed by position)."""
    name, *keys = path.split("/")
    value: object = result(name)
    for key in keys:
        value = value[int(key)] if isinstance(value, list) else value[key]  # type: ignore[index]
    return value


def formatted(value: object, spec: str = "") -> str:
    """``value`` as text: ``spec`` is a Python format spec, optionally after ``ms`` (seconds
    shown in milliseconds) or ``%`` (a fraction shown in per cent)."""
    unit, _, rest = spec.partition(" ")
    if unit in ("ms", "%"):
        return format(float(value) * 1000 if unit == "ms" else float(value) * 100, rest)
    return format(value, spec)


def _table(header: list[str], rows: list[list[str]]) -> str:
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(row) + " |" for row in rows]
    return "\n".join(lines) + "\n"


def _seconds(s: float) -> str:
    return f"{s * 1000:.1f} ms" if s < 1 else f"{s:.2f} s" if s < 10 else f"{s:.1f} s"


def _mb(value: float) -> str:
    return f"{value:,.0f}" if value >= 100 else f"{value:.1f}"


def simulate_table() -> str:
    """Throughput of ``simulate_batch`` against population (``simulate.json``)."""
    rows = [[f"{r['population']:,}", f"{r['compile_s']:.1f} s", _seconds(r["run_s"]),
             f"{r['simulations_per_s']:,.0f}", f"{r['one_device_vmap_simulations_per_s']:,.0f}"]
            for r in result("simulate")["jax"]]
    return _table(["population", "compile", "run (best of 5)", "simulations/s",
                   "one-device vmap, simulations/s"], rows)


def peers_table() -> str:
    """jaxflex against the NumPy loop and diffrax, same run (``simulate.json``)."""
    data = result("simulate")
    at_100 = next(r for r in data["jax"] if r["population"] == 100)
    diffrax = data["diffrax"]
    rows = [
        ["jaxflex, population 100", f"{at_100['simulations_per_s']:,.0f}", "1"],
        ["NumPy loop (`benchmarks/numpy_reference.py`)",
         f"{data['numpy']['simulations_per_s']:.1f}", f"{data['ratio_at_population_100']:,.0f}×"],
        [f"diffrax Kvaerno5 + PID, rtol {diffrax['rtol']:g}, population {diffrax['population']}",
         f"{diffrax['simulations_per_s']:.2f}",
         f"{data['diffrax_ratios']['jaxflex_at_population_100']:,.0f}×"],
    ]
    return _table(["simulator", "simulations/s", "jaxflex is faster by"], rows)


def scaling_table() -> str:
    """Run time and memory against mesh, record length and population (``scaling.json``)."""
    rows = [[str(p["n_elements"]), f"{p['duration_s']:g} s", f"{p['population']:,}",
             f"{p['compile_s']:.1f} s", _seconds(p["run_s"]), f"{p['simulations_per_s']:,.0f}",
             f"{p['peak_rss_mb']:,.0f} MB",
             f"{_mb(p['xla_output_mb'])} + {_mb(p['xla_temp_mb'])} MB"]
            for p in sorted(result("scaling")["points"],
                            key=lambda p: (p["duration_s"], p["n_elements"], p["population"]))]
    return _table(["n_el", "record", "population", "compile", "run", "simulations/s",
                   "peak RSS", "XLA output + temp"], rows)


def accelerator_table() -> str:
    """Simulations per second on one GPU, the XLA program before and after the batched
    eigensolver and the fused kernel, beside the 2-core CPU at the same point
    (``gpu_h200.json``, ``scaling.json``)."""
    gpu = result("gpu_h200")
    cpu = {p["population"]: p["simulations_per_s"] for p in result("scaling")["points"]
           if (p["n_elements"], p["duration_s"]) == (10, 2.0)}
    before = {p["population"]: p["simulations_per_s"] for p in gpu["before"]["points"]
              if p["program"] == "scan"}
    after = {(p["program"], p["population"]): p["simulations_per_s"] for p in gpu["points"]}

    def rate(value) -> str:
        return "–" if value is None else f"{value:,.0f}"

    rows = []
    for population in sorted({p for _, p in after}):
        fused, on_cpu = after.get(("fused", population)), cpu.get(population)
        rows.append([f"{population:,}", rate(on_cpu), rate(before.get(population)),
                     rate(after.get(("scan", population))), rate(fused),
                     "–" if on_cpu is None else f"{fused / on_cpu:.1f}×"])
    return _table(["population", "2-core CPU", "H200 XLA, before", "H200 XLA", "H200 fused",
                   "fused / CPU"], rows)


def substeps_table() -> str:
    """Accuracy against SciPy Radau and cost, by sub-steps and friction weight
    (``substeps.json``)."""
    data = result("substeps")
    inputs = data["settings"]["inputs"]
    rows = []
    for r in data["rows"]:
        errors = [f"{r['nrmse_percent'][i]['joint_angle']:.3g} / "
                  f"{r['nrmse_percent'][i]['tip_acceleration']:.3g}" for i in inputs]
        rows.append([str(r["n_substeps"]), f"{r['friction_weight']:g}", *errors,
                     "yes" if r["within_targets"] else "no", _seconds(r["population_100_s"])])
    return _table(["sub-steps", "friction weight", *[f"{i}: θ / tip %" for i in inputs],
                   "within targets", "100 candidates"], rows)


def accuracy_table() -> str:
    """NRMSE against SciPy Radau at the default two sub-steps (``substeps.json``)."""
    row = next(r for r in result("substeps")["rows"]
               if r["n_substeps"] == 2 and r["friction_weight"] == 0.55)
    return _table(["input", "joint angle NRMSE", "tip acceleration NRMSE"],
                  [[name, f"{e['joint_angle']:.2g} %", f"{e['tip_acceleration']:.3g} %"]
                   for name, e in row["nrmse_percent"].items()])


def profile_table() -> str:
    """Run time against population and against the plain Newton steps of the friction solve
    (``profile_simulate.json``, one device)."""
    data = result("profile_simulate")
    rows = [[f"population {n}", _seconds(s)] for n, s in data["time_vs_population_s"].items()]
    rows += [[f"{n_el} elements, population 100", _seconds(s)]
             for n_el, s in data["time_vs_elements_at_population_100_s"].items()]
    rows += [[f"{k} plain Newton steps, population 100", _seconds(s)]
             for k, s in data["time_vs_plain_newton_steps_at_population_100_s"].items()]
    return _table(["case", "run"], rows)


def identify_table() -> str:
    """DE, GA and PSO on three noisy records, with SciPy's DE beside them (``identify.json``)."""
    data = result("identify")
    rows = [[r["method"].upper(), f"{r['population']} × {r['generations']}",
             f"{r['compile_time_s']:.1f} s", f"{r['wall_time_s']:.1f} s",
             f"{r['objective']:.4e}", f"{r['refine_time_s']:.1f} s",
             f"{r['objective_refined']:.4e}"] for r in data["jaxflex"]]
    scipy = data["scipy"]
    rows.append([f"SciPy DE, {scipy['workers']} workers", f"{scipy['population']} × "
                 f"{scipy['generations']}", "—",
                 f"{scipy['wall_time_s']:.1f} s (full run ≈ "
                 f"{data['comparison']['scipy_full_run_time_s']:,.0f} s)",
                 f"{scipy['objective']:.4e}", "—", "—"])
    return _table(["method", "budget", "compile", "search", "objective", "refinement",
                   "refined objective"], rows)


def design_table() -> str:
    """The worst 95 % half-width of each input, predicted and over noise seeds
    (``design.json``)."""
    summary = result("design")["summary"]
    rows = []
    for name, (param, width) in summary["predicted_worst"].items():
        white = summary["measured_white_worst"][name]
        quantised = summary["measured_quantised_worst"][name]
        rows.append([name, f"{param} {width:.3g}", f"{white[0]} {white[1]:.3g}",
                     f"{quantised[0]} {quantised[1]:.3g}"])
    return _table(["input", "predicted", "measured, white noise", "measured, quantised encoder"],
                  rows)


def warm_start_table() -> str:
    """DE generations to reach each cost, uniform start against the rigid warm start
    (``design.json``, median over seeds)."""
    medians = result("design")["warm_start"]["median_generations_to"]
    levels = list(next(iter(medians.values())))
    rows = [[start, *[f"{medians[start][level]:.0f}" for level in levels]] for start in medians]
    return _table(["DE start", *[f"cost {level}" for level in levels]], rows)


def discover_table() -> str:
    """``discover`` on the hidden-payload example, cold and warm (``discover.json``)."""
    rows = [[name.replace("_", ", "), f"{run['seconds']:.1f} s", ", ".join(run["added"]),
             f"{run['final_nrmse_percent']['joint_angle']:.3f} % / "
             f"{run['final_nrmse_percent']['tip_acceleration']:.2f} %"]
            for name, run in result("discover")["runs"].items()]
    return _table(["run", "wall time", "added", "final NRMSE θ / tip"], rows)


def cli_startup_table() -> str:
    """Start-up of fresh processes, median of interleaved rounds (``cli_startup.json``)."""
    data = result("cli_startup")
    (checkout, now), (baseline, before) = data["rows"].items()
    rows = [[f"`{command}`", f"{times['median_s']:.2f} s",
             f"{before[command]['median_s']:.2f} s" if "median_s" in before[command] else "failed"]
            for command, times in now.items()]
    return _table(["command", checkout, baseline], rows)


def time_to_answer_table() -> str:
    """Seconds a user waits, command by command, cold and warm compilation cache, each revision
    measured in one session beside the targets (``time_to_answer.json``)."""
    data = result("time_to_answer")
    revisions = data["revisions"]
    names = {"discover_rotflex": "`discover` ROTFLEX", "discover_example": "`discover` example",
             "identify_rotflex": "`identify` ROTFLEX", "help": "`jaxflex --help`"}
    rows = []
    for command, name in names.items():
        target = data["targets_seconds"].get(command, {})
        row = [name, " / ".join(f"{target[k]:.0f}" if k in target else "–"
                                for k in ("cold", "warm"))]
        for revision in revisions.values():
            run = revision["runs"].get(command)
            row.append("–" if run is None else
                       f"{run['cold']['seconds']:.1f} / {run['warm']['seconds']:.1f}")
        rows.append(row)
    return _table(["command", "target s (cold / warm)",
                   *(f"{label} s" + (f", median of {r['rounds']}" if r.get("rounds", 1) > 1
                                     else "") for label, r in revisions.items())], rows)


def time_to_answer_breakdown_table() -> str:
    """Where a warm ``discover`` on ROTFLEX spends its time, by phase, each revision
    (``time_to_answer.json``, ``--breakdown``)."""
    revisions = {label: revision["runs"]["discover_rotflex"]["breakdown"]
                 for label, revision in result("time_to_answer")["revisions"].items()
                 if "breakdown" in revision["runs"].get("discover_rotflex", {})}
    phases = list(dict.fromkeys(p for b in revisions.values() for p in b["phases"]))
    rows = [[phase, *(f"{b['phases'][phase]:.1f}" if phase in b["phases"] else "–"
                      for b in revisions.values())] for phase in phases]
    rows += [[f"{step} (all phases)", *(f"{b['compilation'][step]:.1f}"
                                        for b in revisions.values())]
             for step in next(iter(revisions.values()))["compilation"]]
    rows.append(["whole run", *(f"{b['total']:.1f}" for b in revisions.values())])
    return _table(["phase", *(f"{label} s" for label in revisions)], rows)


def _pair(scores: dict) -> str:
    """θ / α NRMSE of one ROTFLEX prediction or simulation."""
    return " / ".join(f"{scores[c]:.0f} %" if scores[c] >= 100 else f"{scores[c]:.1f} %"
                      for c in ("joint_angle", "deflection_angle"))


def real_rig_table() -> str:
    """ROTFLEX: physical fits and the best black box, on the fit run and held out
    (``real_rig.json``)."""
    data = result("real_rig")

    rows = []
    for key in ("physical", "physical_offset"):
        fit = data[key]
        label = f"jaxflex, arm `{data['arm']}`" + "".join(f" + `{e}`" for e in fit["effects"])
        rows.append([label, f"{fit['n_parameters']} physical", _pair(fit["nrmse_fit"]),
                     _pair(fit["nrmse_held_out"])])
    box = data["black_box"]["best"]
    rows.append([f"N4SID state space, order {box['order']} (best held out)",
                 str(box["n_parameters"]), _pair(box["nrmse_fit"]), _pair(box["nrmse_held_out"])])
    return _table(["model", "parameters", "fit run: θ / α NRMSE", "held out: θ / α NRMSE"], rows)


def real_rig_prediction_table() -> str:
    """ROTFLEX run 985 held out: k-step-ahead predictions of the square-wave fit's Kalman filter
    beside the best N4SID model's own Kalman predictor (``real_rig.json``)."""
    data = result("real_rig")
    ours, box = data["prediction"]["nrmse_held_out"], data["black_box"]["best"]
    theirs = box["nrmse_prediction_held_out"] | {"simulation": box["nrmse_held_out"]}
    columns = [c for c in ours if c != "simulation"] + ["simulation"]
    rows = [["jaxflex, square-wave fit + `torque_offset`, its Kalman filter",
             *(_pair(ours[c]) for c in columns)],
            [f"N4SID order {box['order']}, its Kalman predictor",
             *(_pair(theirs[c]) for c in columns)]]
    rate = data["prediction"]["held_out_rate_hz"]
    return _table([f"θ / α NRMSE, run 985 at {rate:.0f} Hz",
                   *(c.replace("_", " ") for c in columns)], rows)


def real_rig_criteria_table() -> str:
    """ROTFLEX run 985: output-error and prediction-error fits on its first half, scored on its
    second half (``real_rig.json``)."""
    data = result("real_rig")["criteria"]
    columns = list(data["output"]["nrmse_second_half"])
    columns = [c for c in columns if c != "simulation"] + ["simulation"]
    rows = [[f"{name.replace('_', ' ')} error", *(_pair(data[key]["nrmse_second_half"][c])
                                                  for c in columns)]
            for key, name in (("output", "output"), ("prediction", "prediction"))]
    return _table(["fitted by (first half)", *(c.replace("_", " ") for c in columns)], rows)


def machines_table() -> str:
    """Where and with what each results file was measured."""
    rows = []
    for path in sorted(RESULTS.glob("*.json")):
        data = result(path.stem)
        where = data.get("provenance", data)
        machine, versions = where.get("machine", {}), where.get("versions", {})
        rows.append([f"`{path.name}`", str(machine.get("cpu_count", "—")),
                     versions.get("jax", "—"), where.get("python", "—")])
    return _table(["results file", "CPU cores", "jax", "Python"], rows)


TABLES: dict[str, Callable[[], str]] = {
    "simulate": simulate_table,
    "peers": peers_table,
    "scaling": scaling_table,
    "accelerator": accelerator_table,
    "substeps": substeps_table,
    "accuracy": accuracy_table,
    "profile": profile_table,
    "identify": identify_table,
    "design": design_table,
    "warm_start": warm_start_table,
    "discover": discover_table,
    "cli_startup": cli_startup_table,
    "time_to_answer": time_to_answer_table,
    "time_to_answer_breakdown": time_to_answer_breakdown_table,
    "real_rig": real_rig_table,
    "real_rig_prediction": real_rig_prediction_table,
    "real_rig_criteria": real_rig_criteria_table,
    "machines": machines_table,
}
"""Each table by the name its marker gives."""
