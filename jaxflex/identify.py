"""Identification: evolutionary search → Levenberg–Marquardt → uncertainty → a :class:`Fit`.

::

    from jaxflex.identify import identify
    from jaxflex.synthetic import make_records

    fit = identify(make_records(seed=1), method="de", seed=0)
    print(fit.summary())
    fit.to_json("fit.json")

The search follows the paper (DE, GA or PSO with its settings, in the unit box, every generation
one batched evaluation of the whole population, :mod:`jaxflex.evolve`); the best candidate (or the
best few) is refined by :func:`jaxflex.refine.refine`, kept only if the cost fell, and the
uncertainty of the result is estimated by :func:`jaxflex.refine.uncertainty`.
"""

from __future__ import annotations

import json
import math
import os
import time
from collections.abc import Mapping, Sequence
from dataclasses import MISSING, dataclass, field, fields
from pathlib import Path
from typing import Any

import numpy as np
from jaxtyping import ArrayLike

from jaxflex._io import provenance, to_jsonable, write_json
from jaxflex.diagnose import Noise, noise_levels
from jaxflex.evolve import STRATEGIES, get_strategy, run
from jaxflex.model import Model
from jaxflex.objective import DEFAULT_CHANNELS, Objective, Records, build_objective
from jaxflex.refine import Refinement, uncertainty
from jaxflex.refine import refine as refine_parameters
from jaxflex.testbed import Testbed

FIT_FORMAT = "jaxflex-fit/1"
METHODS: tuple[str, ...] = tuple(sorted(STRATEGIES))


# ------------------------------------------------------------------------------ model description


def describe_model(model: Model) -> dict[str, Any]:
    """A JSON-able description of ``model`` (testbed settings, effects with their settings)."""
    return {
        "testbed": {f.name: getattr(model.testbed, f.name) for f in fields(model.testbed)},
        "effects": [
            {"name": e.name, "settings": {f.name: getattr(e, f.name) for f in fields(e)}}
            for e in model.effects
        ],
        "n_substeps": model.n_substeps,
    }


def build_model(description: Mapping[str, Any]) -> Model:
    """The :class:`Model` a :func:`describe_model` description stands for."""
    from jaxflex.effects import get_effect

    try:
        testbed = Testbed(**description["testbed"])
        effects = tuple(
            get_effect(e["name"], **e.get("settings", {})) for e in description["effects"]
        )
        return Model(testbed, effects, int(description["n_substeps"]))
    except KeyError as exc:
        raise ValueError(f"model description lacks {exc.args[0]!r}") from None
    except TypeError as exc:
        raise ValueError(f"model description does not fit this jaxflex: {exc}") from None


# ------------------------------------------------------------------------------ result


@dataclass(frozen=True)
class History:
    """Per generation (0 = the initial population): best and mean cost, best parameters."""

    best: np.ndarray
    mean: np.ndarray
    best_params: dict[str, np.ndarray]

    def to_dict(self) -> dict[str, Any]:
        return {"best": self.best, "mean": self.mean, "best_params": self.best_params}

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> History:
        return cls(
            best=_array(data["best"]),
            mean=_array(data["mean"]),
            best_params={k: _array(v) for k, v in data["best_params"].items()},
        )


@dataclass(frozen=True)
class Fit:
    """An identified parameter set with how it was found and how well it is known.

    ``params`` holds every model parameter (identified and fixed) in physical units;
    ``names`` are the identified ones, and ``intervals``/``std``/``covariance``/``correlation``
    refer to them (in that order for the matrices). ``cost`` is the final objective (weighted
    mean squared NRMSE, a fraction; see :mod:`jaxflex.objective`), ``cost_search`` the best the
    evolutionary search found. ``model()`` rebuilds the :class:`Model`.
    """

    params: dict[str, float]
    names: tuple[str, ...]
    fixed: dict[str, float]
    model_description: dict[str, Any]
    cost: float
    cost_search: float
    intervals: dict[str, tuple[float, float]]
    std: dict[str, float]
    covariance: np.ndarray
    correlation: np.ndarray
    noise: dict[str, float]
    poorly_identifiable: tuple[str, ...]
    warnings: tuple[str, ...]
    history: History
    refinement: Refinement | None
    method: str
    seed: int
    settings: dict[str, Any]
    timing: dict[str, float]
    record_names: tuple[str, ...]
    level: float = 0.95
    identifiability: dict[str, Any] = field(default_factory=dict)
    provenance: dict[str, Any] = field(default_factory=dict)

    # --- use -------------------------------------------------------------------------------
    def model(self) -> Model:
        """The model this fit belongs to (testbed settings and effects)."""
        return build_model(self.model_description)

    @property
    def effects(self) -> tuple[str, ...]:
        return tuple(e["name"] for e in self.model_description["effects"])

    @property
    def n_params(self) -> int:
        """Number of identified parameters."""
        return len(self.names)

    @property
    def nrmse(self) -> float:
        """``100·√cost``: the root-mean-square of the normalised errors, in percent."""
        return 100.0 * math.sqrt(self.cost) if math.isfinite(self.cost) else math.inf

    def summary(self) -> str:
        """A text table: value, interval and relative half-width of each parameter."""
        from jaxflex.parameters import BASE_PARAMETERS

        units = {s.name: s.unit for s in BASE_PARAMETERS}
        units.update({s.name: s.unit for s in self.model().space.specs})
        pct = f"{100 * self.level:g} %"
        lines = [
            f"{self.method.upper()} seed {self.seed}: cost {self.cost:.6g} "
            f"(search {self.cost_search:.6g}, rms NRMSE {self.nrmse:.4g} %)",
            f"{'parameter':<10} {'value':>12} {pct + ' interval':>29} {'±%':>8}  unit",
        ]
        for n in self.params:
            value = self.params[n]
            if n in self.intervals:
                lo, hi = self.intervals[n]
                rel = 50.0 * (hi - lo) / abs(value) if value else math.nan
                flag = "  poorly identifiable" if n in self.poorly_identifiable else ""
                lines.append(
                    f"{n:<10} {value:>12.6g} [{lo:>12.6g}, {hi:>12.6g}] {rel:>8.3g}  "
                    f"{units.get(n, '')}{flag}"
                )
            else:
                lines.append(f"{n:<10} {value:>12.6g} {'(fixed)':>29} {'':>8}  {units.get(n, '')}")
        if self.refinement is not None:
            r = self.refinement
            lines.append(
                f"refinement: {r.result}, {r.steps} steps, cost {r.cost_start:.6g} -> "
                f"{r.cost_end:.6g} ({'accepted' if r.accepted else 'rejected'})"
            )
        lines += [f"warning: {w}" for w in self.warnings]
        return "\n".join(lines) + "\n"

    # --- files -----------------------------------------------------------------------------
    def to_dict(self) -> dict[str, Any]:
        """Plain JSON-able contents (arrays as lists, non-finite numbers as null)."""
        data = {"format": FIT_FORMAT}
        for f in fields(self):
            value = getattr(self, f.name)
            if isinstance(value, (History, Refinement)):
                value = value.to_dict()
            data[f.name] = value
        return to_jsonable(data)

    def to_json(self, path: str | os.PathLike, overwrite: bool = False) -> Path:
        """Write the fit as JSON, atomically; an existing file needs ``overwrite=True``."""
        return write_json(path, self.to_dict(), overwrite=overwrite)

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> Fit:
        if data.get("format") != FIT_FORMAT:
            raise ValueError(f"not a jaxflex fit (format {data.get('format')!r}, "
                             f"expected {FIT_FORMAT!r})")
        required = [f.name for f in fields(cls) if f.default is f.default_factory is MISSING]
        missing = [n for n in required if n not in data]
        if missing:
            raise ValueError(f"fit lacks field(s) {missing}")
        refinement = data["refinement"]
        return cls(
            params={k: _float(v) for k, v in data["params"].items()},
            names=tuple(data["names"]),
            fixed={k: _float(v) for k, v in data["fixed"].items()},
            model_description=dict(data["model_description"]),
            cost=_float(data["cost"]),
            cost_search=_float(data["cost_search"]),
            intervals={k: (_float(v[0]), _float(v[1])) for k, v in data["intervals"].items()},
            std={k: _float(v) for k, v in data["std"].items()},
            covariance=_matrix(data["covariance"]),
            correlation=_matrix(data["correlation"]),
            noise={k: _float(v) for k, v in data["noise"].items()},
            poorly_identifiable=tuple(data["poorly_identifiable"]),
            warnings=tuple(data["warnings"]),
            history=History.from_dict(data["history"]),
            refinement=None if refinement is None else Refinement.from_dict(refinement),
            method=str(data["method"]),
            seed=int(data["seed"]),
            settings=dict(data["settings"]),
            timing={k: _float(v) for k, v in data["timing"].items()},
            record_names=tuple(data["record_names"]),
            level=float(data.get("level", 0.95)),
            identifiability=_identifiability(data.get("identifiability", {})),
            provenance=dict(data.get("provenance", {})),
        )

    @classmethod
    def from_json(cls, path: str | os.PathLike) -> Fit:
        """Read a fit written by :meth:`to_json`; errors name the file."""
        path = Path(path)
        try:
            data = json.loads(path.read_text())
        except json.JSONDecodeError as exc:
            raise ValueError(f"{path}: not valid JSON ({exc})") from None
        if not isinstance(data, dict):
            raise ValueError(f"{path}: not a jaxflex fit (expected a JSON object)")
        try:
            return cls.from_dict(data)
        except (KeyError, TypeError, ValueError) as exc:
            message = exc.args[0] if exc.args else exc
            raise ValueError(f"{path}: {message}") from None


def load_fit(path: str | os.PathLike) -> Fit:
    """Read a fit file written by :meth:`Fit.to_json` (or ``jaxflex identify --out``)."""
    return Fit.from_json(path)


def _float(value: Any) -> float:
    return math.nan if value is None else float(value)


def _identifiability(data: Mapping[str, Any]) -> dict[str, Any]:
    out = dict(data)
    if "eigenvalues" in out:
        out["eigenvalues"] = _array(out["eigenvalues"])
    if "eigenvectors" in out:
        out["eigenvectors"] = _matrix(out["eigenvectors"])
    return out


def _array(value: Any) -> np.ndarray:
    """A 1-D float array from a JSON list (null → NaN)."""
    return np.array([_float(v) for v in value], dtype=np.float64)


def _matrix(value: Any) -> np.ndarray:
    """A 2-D float array from a JSON list of lists (null → NaN; [] → shape (0, 0))."""
    rows = [[_float(v) for v in row] for row in value]
    return np.array(rows, dtype=np.float64).reshape(len(rows), len(rows[0]) if rows else 0)


# ------------------------------------------------------------------------------ pipeline


def _check_method(method: str) -> str:
    name = str(method).lower()
    if name not in STRATEGIES:
        raise ValueError(f"unknown method {method!r}; choose one of {', '.join(METHODS)}")
    return name


def _unit_seeds(objective: Objective, init_population: Any) -> np.ndarray | None:
    """Physical starting points (a mapping name → value(s), a list of them, or a Fit) → unit box."""
    if init_population is None:
        return None
    if isinstance(init_population, Fit):
        init_population = init_population.params
    rows = [init_population] if isinstance(init_population, Mapping) else list(init_population)
    units = []
    for row in rows:
        if not isinstance(row, Mapping):
            raise ValueError("init_population must be a mapping name → value(s) or a list of them")
        units.append(objective.space.unit_seeds(row, "init_population"))
    return np.concatenate(units, axis=0)


def _refinement_starts(objective: Objective, evolution, count: int) -> list[dict[str, float]]:
    """The best point found, then the best distinct members of the final population."""
    candidates = [np.asarray(evolution.best_x)]
    order = np.argsort(np.asarray(evolution.final_fitness))
    population = np.asarray(evolution.final_population)
    for i in order:
        if len(candidates) >= count:
            break
        if np.isfinite(evolution.final_fitness[i]) and not any(
            np.allclose(population[i], c, rtol=0, atol=1e-9) for c in candidates
        ):
            candidates.append(population[i])
    return [_physical(objective, u) for u in candidates]


def _physical(objective: Objective, u: ArrayLike) -> dict[str, float]:
    values = objective.from_unit(u)
    return {n: float(values[n]) for n in objective.names}


def identify(
    records: Records,
    model: Model | None = None,
    method: str = "de",
    seed: int = 0,
    generations: int = 100,
    population: int | None = None,
    refine: bool = True,
    weights: Mapping[str, float] | None = None,
    progress: bool = False,
    init_population: Any = None,
    bounds: Mapping[str, tuple[float, float]] | None = None,
    *,
    fixed: Mapping[str, float] | None = None,
    channels: Sequence[str] = DEFAULT_CHANNELS,
    refine_starts: int = 1,
    strategy_options: Mapping[str, Any] | None = None,
    intervals: bool = True,
    level: float = 0.95,
    noise: Noise | None = None,
) -> Fit:
    """Identify the parameters of ``model`` (default: the reference testbed) from ``records``.

    ``method`` is ``"de"``, ``"ga"`` or ``"pso"`` with the paper's settings; ``population``
    overrides the preset's (100), ``strategy_options`` any other setting (e.g. ``{"F": 0.7}``).
    The search runs ``generations`` generations from ``seed`` (same seed → same result) in the
    unit box of the free parameters; ``bounds`` narrows or widens a parameter's range
    (``{"J_h": (1e-3, 1e-2)}``), ``fixed`` holds parameters at given values, ``weights`` and
    ``channels`` shape the objective (:func:`jaxflex.objective.build_objective`); ``noise``
    (channel → σ or :class:`~jaxflex.diagnose.NoiseLevel`, every fitted channel) sets the
    weights from the channels' noise levels instead (:func:`jaxflex.objective.noise_weights`).
    ``init_population`` seeds the search with physical points (a mapping name → value or
    values, a list of mappings, or a previous :class:`Fit`). ``refine`` polishes the result with
    Levenberg–Marquardt from the ``refine_starts`` best candidates; ``intervals`` computes the
    Gauss–Newton uncertainty at ``level``.
    """
    t_start = time.perf_counter()
    method = _check_method(method)
    objective = build_objective(
        records, model, weights=weights, channels=channels, fixed=fixed, bounds=bounds,
        noise=noise,
    )
    overrides = dict(strategy_options or {})
    if population is not None:
        overrides["population"] = population
    strategy = get_strategy(method, "paper", **overrides)
    if not (isinstance(refine_starts, int) and 1 <= refine_starts <= strategy.population):
        raise ValueError(
            f"refine_starts must be an int in [1, population={strategy.population}], "
            f"got {refine_starts!r}"
        )
    seeds = _unit_seeds(objective, init_population)

    evolution = run(
        strategy,
        objective.fitness,
        objective.dim,
        seed=seed,
        generations=generations,
        init_population=seeds,
        progress=progress,
    )
    best = _physical(objective, evolution.best_x)
    cost_search = float(evolution.best_fitness)
    timing = {"search": evolution.wall_time, "search_compile": evolution.compile_time}

    refinement = None
    estimate, cost = best, cost_search
    if refine:
        starts = _refinement_starts(objective, evolution, refine_starts)
        refinement = refine_parameters(objective, starts)
        timing["refine"] = refinement.wall_time
        timing["refine_compile"] = refinement.compile_time
        if refinement.accepted and refinement.cost < cost:
            estimate, cost = refinement.params, refinement.cost

    warnings: list[str] = []
    if not math.isfinite(cost):
        warnings.append("no candidate gave a finite simulation: the fit is meaningless")
    if refinement is not None and refinement.result != "successful":
        warnings.append(f"refinement stopped early ({refinement.result}): {refinement.message}")
    if not refine and intervals:
        warnings.append(
            "intervals computed at the search result, which is not refined to a least-squares "
            "optimum: they are only indicative"
        )
    unc = None
    if intervals and math.isfinite(cost):
        t0 = time.perf_counter()
        unc = uncertainty(objective, estimate, level=level)
        timing["uncertainty"] = time.perf_counter() - t0
        warnings += unc.warnings
    timing["total"] = time.perf_counter() - t_start

    history_x = np.asarray(objective.space.to_vector(objective.from_unit(evolution.history_best_x)))
    return Fit(
        params=_ordered(objective, estimate),
        names=objective.names,
        fixed={n: float(v) for n, v in objective.fixed.items()},
        model_description=describe_model(objective.model),
        cost=cost,
        cost_search=cost_search,
        intervals={} if unc is None else unc.intervals,
        std={} if unc is None else dict(zip(unc.names, map(float, unc.std), strict=True)),
        covariance=np.full((0, 0), np.nan) if unc is None else unc.covariance,
        correlation=np.full((0, 0), np.nan) if unc is None else unc.correlation,
        noise={} if unc is None else unc.noise,
        poorly_identifiable=() if unc is None else unc.poorly_identifiable,
        warnings=tuple(warnings),
        history=History(
            best=np.asarray(evolution.history_best),
            mean=np.asarray(evolution.history_mean),
            best_params={n: history_x[:, i] for i, n in enumerate(objective.names)},
        ),
        refinement=refinement,
        method=method,
        seed=seed,
        settings={
            "method": method,
            "strategy": evolution.settings,
            "generations": generations,
            "n_evaluations": evolution.n_evaluations,
            "refine": refine,
            "refine_starts": refine_starts,
            "channels": list(objective.channels),
            "weights": dict(zip(objective.channels, map(float, objective.weights), strict=True)),
            "noise": {c: v.to_dict() for c, v in noise_levels(noise).items()},
            "bounds": {s.name: [s.lower, s.upper] for s in objective.specs},
            "log_scale": {s.name: s.log_scale for s in objective.specs},
            "seeded": 0 if seeds is None else int(seeds.shape[0]),
            "dt": objective.dt,
        },
        timing=timing,
        record_names=objective.record_names,
        level=level,
        identifiability={}
        if unc is None
        else {
            "eigenvalues": unc.eigenvalues,
            "eigenvectors": unc.eigenvectors,
            "coordinates": list(unc.coordinates),
            "at_bounds": list(unc.at_bounds),
        },
        provenance=provenance(),
    )


def _ordered(objective: Objective, estimate: Mapping[str, float]) -> dict[str, float]:
    """Every model parameter in the model's order: identified values, then fixed ones."""
    values = {**{n: float(v) for n, v in objective.fixed.items()}, **estimate}
    return {n: values[n] for n in objective.model.space.names}


__all__ = [
    "FIT_FORMAT",
    "METHODS",
    "Fit",
    "History",
    "build_model",
    "describe_model",
    "identify",
    "load_fit",
]
