"""The demo: the whole jaxflex story on synthetic data, as a sequence of small, named steps.

1. **records** — simulate the reference testbed under its three reference inputs and add the
   spec's sensor noise (seeded); save them as record files, as a user's measurements would be.
2. **identify** — fit the six parameters on the triangular record alone (a short differential
   evolution, then Levenberg–Marquardt refinement), set them against the true values; save the
   fit.
3. **validate** — compare the fitted model with all three records: the pulse and half-sine are
   held out; print the Table-3-style table with the noise floors.
4. **report** — write the table, ``comparison.json`` and the figures.
5. **discover** — the bundled example arm hides a physical effect: fit the base model (from
   the reference values), show where it fails, name the missing effect (score tests, confirmed
   by refits), add it and show the error fall; the step table, ``discover.json`` and figures go
   to ``discover/``.

Each step is a function ``DemoState → DemoState``; :data:`STEPS` lists them in order, so the
story grows by appending steps. Nothing is overwritten unless asked: every file the demo would
write is checked before the first step runs, and the files appear together when the last step
has succeeded (:func:`jaxflex._io.all_or_nothing`).
"""

from __future__ import annotations

import os
import shlex
import shutil
import sys
import sysconfig
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

from jaxflex._io import all_or_nothing, check_writable
from jaxflex.comparison import Comparison, compare
from jaxflex.data import Dataset, save_record
from jaxflex.synthetic import (
    ACCELEROMETER_SIGMA,
    DEFAULT_INPUTS,
    ENCODER_COUNTS,
    make_records,
    true_parameters,
)

FIT_ON = "triangular"
"""The record the demo identifies on; the others are held out."""
NOISE = {"encoder_counts": ENCODER_COUNTS, "accel_sigma": ACCELEROMETER_SIGMA}
"""Noise of the demo's records: encoder counts per revolution, accelerometer σ (m/s²)."""
BUDGET = {"population": 24, "generations": 12}
"""A deliberately short search: the refinement finishes the job, and the demo stays quick."""
DISCOVER_DIR = "discover"
"""Subdirectory of the discovery report."""


@dataclass(frozen=True)
class DemoState:
    """What the steps pass along: settings, then each step's results."""

    out: Path
    seed: int = 0
    overwrite: bool = False
    echo: Callable[[str], None] = print
    records: Dataset | None = None
    fit: Any = None  # jaxflex.identification.Fit
    comparison: Comparison | None = None
    discovery: Any = None  # jaxflex.discovery.DiscoveryReport
    files: tuple[Path, ...] = ()
    timings: dict[str, float] = field(default_factory=dict)

    def wrote(self, *paths: Path) -> DemoState:
        return replace(self, files=self.files + tuple(paths))


Step = Callable[[DemoState], DemoState]
"""One step of the demo: takes the state so far, returns it with the step's results."""


def make_data(state: DemoState) -> DemoState:
    """Noisy synthetic records of the reference inputs, saved under ``records/``."""
    records = make_records(inputs=DEFAULT_INPUTS, noise=True, seed=state.seed)
    paths = [
        save_record(r, _record_path(state.out, r.name), overwrite=state.overwrite) for r in records
    ]
    state.echo(
        f"made {len(records)} noisy records ({', '.join(records.names)}), seed "
        f"{state.seed}: encoder {ENCODER_COUNTS} counts/rev, accelerometer sigma "
        f"{ACCELEROMETER_SIGMA} m/s^2"
    )
    return replace(state, records=records).wrote(*paths)


def identify_on_one(state: DemoState) -> DemoState:
    """Identify the six parameters on the ``FIT_ON`` record only; save ``fit.json``."""
    from jaxflex.identification import identify

    fit = identify(state.records[FIT_ON], method="de", seed=state.seed, intervals=False, **BUDGET)
    path = fit.to_json(state.out / "fit.json", overwrite=state.overwrite)
    state.echo(
        f"identified on {FIT_ON!r}: DE, population {BUDGET['population']}, "
        f"{BUDGET['generations']} generations (cost {fit.cost_search:.3g}), then "
        f"refinement (cost {fit.cost:.3g})"
    )
    truth = true_parameters()
    state.echo(f"  {'parameter':<10} {'identified':>12} {'true':>12} {'error %':>8}")
    for name, value in fit.params.items():
        true = float(truth[name])
        state.echo(f"  {name:<10} {value:>12.5g} {true:>12.5g} {100 * (value / true - 1):>8.3f}")
    return replace(state, fit=fit).wrote(path)


def validate_held_out(state: DemoState) -> DemoState:
    """Compare the fitted model with every record; the ones not fitted are held out."""
    fit = state.fit
    comparison = compare(
        state.records, fit.model, fit.params, fit_names=fit.record_names, **NOISE
    )
    state.echo("validation (fit on one record, the others held out):")
    state.echo(_indent(comparison.table()))
    return replace(state, comparison=comparison)


def write_report(state: DemoState) -> DemoState:
    """Table, comparison.json and figures into the output directory."""
    from jaxflex.plots.compare import save_report

    paths = save_report(state.comparison, state.out, overwrite=state.overwrite)
    return state.wrote(*paths)


def discover_hidden_effect(state: DemoState) -> DemoState:
    """Find the effect the bundled example arm hides; the report goes to ``discover/``."""
    from jaxflex.discovery import discover, load_example
    from jaxflex.plots.discover import save_discovery_report

    records, holdout = load_example()
    state.echo(f"the example arm: {len(records)} records to fit, {len(holdout)} held out; "
               "the base model is fitted from the reference values")
    report = discover(records, holdout=holdout, seed=state.seed,
                      initial=true_parameters(), max_confirm=2)
    state.echo("where the base model fails:")
    state.echo(_indent("\n".join(report.base.diagnosis.summary())))
    state.echo("what is missing (score tests of every candidate, confirmed by refits):")
    for step in report.steps:
        if step.ranking:
            state.echo(_indent(step.ranking[0].explanation))
    state.echo("the error as effects are added:")
    state.echo(_indent(report.table()))
    paths = save_discovery_report(report, state.out / DISCOVER_DIR, overwrite=state.overwrite)
    state.echo(f"  (the answer is in the files' comments: {records[0].metadata.get('answer')})")
    return replace(state, discovery=report).wrote(*paths)


STEPS: tuple[tuple[str, Step], ...] = (
    ("records", make_data),
    ("identify", identify_on_one),
    ("validate", validate_held_out),
    ("report", write_report),
    ("discover", discover_hidden_effect),
)
"""The demo's steps in order, by name."""


def planned_files(out: Path) -> list[Path]:
    """Every file the demo writes, so that all can be checked before any work is done."""
    from jaxflex.discovery import load_example
    from jaxflex.plots.compare import report_paths
    from jaxflex.plots.discover import report_paths as discovery_paths

    records = [_record_path(out, name) for name in DEFAULT_INPUTS]
    example = load_example()[0].names
    return [*records, out / "fit.json", *report_paths(DEFAULT_INPUTS, out),
            *discovery_paths(example, out / DISCOVER_DIR)]


def run_demo(
    out: str | os.PathLike,
    *,
    seed: int = 0,
    overwrite: bool = False,
    steps: Sequence[tuple[str, Step]] = STEPS,
    echo: Callable[[str], None] = print,
) -> DemoState:
    """Run ``steps`` in order into the directory ``out``; returns the final state."""
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise ValueError(f"{out}: exists and is not a directory")
    if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
        raise ValueError(f"seed must be a non-negative integer, got {seed!r}")
    for path in planned_files(out):
        check_writable(path, overwrite)
    state = DemoState(out=out, seed=seed, overwrite=overwrite, echo=echo)
    with all_or_nothing():  # the files appear when every step has succeeded, or not at all
        for name, step in steps:
            echo(f"== {name}")
            start = time.perf_counter()
            state = step(state)
            elapsed = time.perf_counter() - start
            state = replace(state, timings=state.timings | {name: elapsed})
            echo(f"   ({elapsed:.1f} s)")
    total = sum(state.timings.values())
    echo(f"== done in {total:.1f} s; wrote {len(state.files)} files to {out}/")
    records, fit = shlex.quote(f"{out}/records"), shlex.quote(f"{out}/fit.json")
    echo(f"   try: {jaxflex_command()} validate {records} --fit {fit}")
    return state


def jaxflex_command() -> str:
    """How to run the ``jaxflex`` command of this interpreter from a shell in the working
    folder: ``jaxflex`` when the ``PATH`` finds that very script, else its path (relative when it
    lies below the working folder, as ``.venv/bin/jaxflex`` after ``make demo``), else
    ``python -m jaxflex`` with this interpreter."""
    name = "jaxflex.exe" if os.name == "nt" else "jaxflex"
    script = Path(sysconfig.get_path("scripts")) / name
    if not script.is_file():
        return f"{shlex.quote(sys.executable)} -m jaxflex"
    found = shutil.which("jaxflex")
    if found is not None and Path(found).resolve() == script.resolve():
        return "jaxflex"
    relative = os.path.relpath(script)
    if relative.startswith(".."):
        return shlex.quote(str(script))
    return shlex.quote(relative if os.sep in relative else os.path.join(".", relative))


def _record_path(out: Path, name: str) -> Path:
    return out / "records" / f"{name}.csv"


def _indent(text: str) -> str:
    return "\n".join(f"  {line}" if line else line for line in text.rstrip("\n").splitlines())


__all__ = ["STEPS", "DemoState", "planned_files", "run_demo"]
