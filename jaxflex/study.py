"""The paper's study: each evolutionary method from several seeds, summarised like its tables.

Every run is one :func:`jaxflex.identification.identify` call on the same records (so all runs of a
method share one compiled program); the study keeps, per run, the identified parameters, the
final and search costs, the timing and the convergence history, and prints the mean ± standard
deviation of each parameter over seeds with the final objective and wall time::

    study = run_study(records, methods=("de", "ga", "pso"), seeds=range(10))
    print(study.table())
    study.to_json("study.json")
"""

from __future__ import annotations

import os
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from jaxflex._io import provenance, to_jsonable, write_json
from jaxflex._progress import Progress
from jaxflex.identification import Fit, check_method, identify
from jaxflex.model import Model
from jaxflex.objective import Records, as_dataset

STUDY_FORMAT = "jaxflex-study/2"
"""Format tag written into study files; bumped when their layout changes (2: the summary's wall
times moved under ``"timing"``)."""


@dataclass(frozen=True)
class StudyRun:
    """One run of the study: what it found and what it cost (wall time after compiling)."""

    method: str
    seed: int
    params: dict[str, float]
    cost: float
    cost_search: float
    wall_time: float  # search + refinement, without compilation
    compile_time: float
    history: np.ndarray  # best cost per generation

    @classmethod
    def from_fit(cls, fit: Fit) -> StudyRun:
        t = fit.timing
        return cls(
            method=fit.method,
            seed=fit.seed,
            params={n: fit.params[n] for n in fit.names},
            cost=fit.cost,
            cost_search=fit.cost_search,
            wall_time=t["search"] + t.get("refine", 0.0),
            compile_time=t["search_compile"] + t.get("refine_compile", 0.0),
            history=np.asarray(fit.history.best),
        )

    def to_dict(self) -> dict[str, Any]:
        """The run as JSON contents; the times, which differ between identical runs, go under
        ``"timing"`` so that everything else can be compared."""
        data = dict(self.__dict__)
        data["timing"] = {k: data.pop(k) for k in ("wall_time", "compile_time")}
        return data


@dataclass(frozen=True)
class Study:
    """All runs of a study, with the settings they shared."""

    runs: tuple[StudyRun, ...]
    names: tuple[str, ...]
    record_names: tuple[str, ...]
    settings: dict[str, Any]
    provenance: dict[str, Any] = field(default_factory=dict)

    @property
    def methods(self) -> tuple[str, ...]:
        return tuple(dict.fromkeys(r.method for r in self.runs))

    def of(self, method: str) -> tuple[StudyRun, ...]:
        return tuple(r for r in self.runs if r.method == method)

    def histories(self) -> dict[str, list[np.ndarray]]:
        """``method → [best cost per generation of each run]`` (for the convergence figure)."""
        return {m: [r.history for r in self.of(m)] for m in self.methods}

    def summary(self) -> dict[str, dict[str, Any]]:
        """Per method: mean and std over seeds of each parameter, cost and wall time."""
        out: dict[str, dict[str, Any]] = {}
        for m in self.methods:
            runs = self.of(m)
            columns = {n: [r.params[n] for r in runs] for n in self.names}
            columns["cost"] = [r.cost for r in runs]
            columns["cost_search"] = [r.cost_search for r in runs]
            columns["wall_time"] = [r.wall_time for r in runs]
            out[m] = {
                k: {"mean": float(np.mean(v)), "std": float(np.std(v, ddof=1) if len(v) > 1 else 0)}
                for k, v in columns.items()
            }
            out[m]["seeds"] = [r.seed for r in runs]
        return out

    def table(self, truth: Mapping[str, float] | None = None) -> str:
        """The paper-like table: rows are parameters (mean ± std over seeds), then the final
        objective and wall time; one column per method (and the true values, if given)."""
        summary = self.summary()
        methods = self.methods
        width = 26
        header = f"{'':<12}" + "".join(
            f"{m.upper() + f' ({len(self.of(m))} seeds)':>{width}}" for m in methods
        )
        if truth is not None:
            header += f"{'true':>14}"
        lines = [header]
        for key in (*self.names, "cost", "wall_time"):
            label = {"cost": "objective", "wall_time": "wall time s"}.get(key, key)
            row = f"{label:<12}"
            for m in methods:
                s = summary[m][key]
                row += f"{s['mean']:>{width - 13}.5g} ± {s['std']:<10.3g}"
            if truth is not None:
                row += f"{truth[key]:>14.5g}" if key in truth else f"{'':>14}"
            lines.append(row)
        return "\n".join(lines) + "\n"

    def to_dict(self) -> dict[str, Any]:
        """The study as JSON contents; the wall times, which differ between identical studies,
        are kept only under ``"timing"`` (per method, as in each run)."""
        summary = self.summary()
        timing = {m: {"wall_time": summary[m].pop("wall_time")} for m in summary}
        return to_jsonable(
            {
                "format": STUDY_FORMAT,
                "names": self.names,
                "record_names": self.record_names,
                "settings": self.settings,
                "summary": summary,
                "runs": [r.to_dict() for r in self.runs],
                "timing": timing,
                "provenance": self.provenance,
            }
        )

    def to_json(self, path: str | os.PathLike, overwrite: bool = False) -> Path:
        return write_json(path, self.to_dict(), overwrite=overwrite)


def run_study(
    records: Records,
    methods: Sequence[str] = ("de", "ga", "pso"),
    seeds: Iterable[int] = range(10),
    *,
    model: Model | None = None,
    generations: int = 100,
    population: int | None = None,
    refine: bool = True,
    progress: bool = False,
    **identify_kwargs: Any,
) -> Study:
    """Identify with each method from each seed (paper settings unless overridden).

    ``identify_kwargs`` go to :func:`jaxflex.identification.identify` (bounds, fixed, weights, …);
    intervals are not computed per run (the spread over seeds is the study's subject).
    ``progress`` reports each run on stderr: a bar on a terminal or in Jupyter, else a line per
    run.
    """
    methods = [check_method(m) for m in methods]
    seeds = [int(s) for s in seeds]
    if not methods or not seeds:
        raise ValueError("a study needs at least one method and one seed")
    for label, values in (("seeds", seeds), ("methods", methods)):
        if len(set(values)) != len(values):
            raise ValueError(f"{label} repeat: {values}; each run would be counted twice")
    dataset = as_dataset(records)
    identify_kwargs.setdefault("intervals", False)
    runs = []
    jobs = [(m, s) for m in methods for s in seeds]
    bar = Progress(jobs, label="study", enabled=progress, each_stage=True)
    names: tuple[str, ...] = ()
    for method, seed in bar:
        fit = identify(
            dataset, model, method=method, seed=seed, generations=generations,
            population=population, refine=refine, **identify_kwargs,
        )
        names = fit.names
        runs.append(StudyRun.from_fit(fit))
        if progress:
            bar.set_message(f"{method} seed {seed}: cost {fit.cost:.3e}")
    return Study(
        runs=tuple(runs),
        names=names,
        record_names=dataset.names,
        settings={
            "methods": methods,
            "seeds": seeds,
            "generations": generations,
            "population": population,
            "refine": refine,
            **{k: v for k, v in identify_kwargs.items() if k != "init_population"},
        },
        provenance=provenance(),
    )


__all__ = ["STUDY_FORMAT", "Study", "StudyRun", "run_study"]
