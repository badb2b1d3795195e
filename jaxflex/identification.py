"""Identification: evolutionary search → Levenberg–Marquardt → uncertainty → a :class:`Fit`.

::

    from jaxflex.identification import identify
    from jaxflex.synthetic import make_records

    fit = identify(make_records(seed=1), method="de", seed=0)
    print(fit.summary())
    fit.to_json("fit.json")

The search follows the paper (DE, GA or PSO with its settings, in the unit box, every generation
one batched evaluation of the whole population, :mod:`jaxflex.evolve`); the best candidate (or the
best few) is refined by :func:`jaxflex.refine.refine`, kept only if the cost fell, and the
uncertainty of the result is estimated by :func:`jaxflex.intervals.uncertainty`.
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
from jaxtyping import ArrayLike

from jaxflex import initial as _initial
from jaxflex._arguments import shown
from jaxflex._io import provenance
from jaxflex._progress import stage
from jaxflex.evolve import STRATEGIES, AbstractStrategy, get_strategy, run
from jaxflex.fit import FIT_FORMAT, FIT_SCHEMA, Fit, History, build_model, describe_model, load_fit
from jaxflex.intervals import uncertainty
from jaxflex.kalman import check_disturbance
from jaxflex.model import Model
from jaxflex.noise import Noise, noise_levels
from jaxflex.objective import Objective, Records, build_objective, check_records, record_tuple
from jaxflex.prediction_error import check_criterion, noise_settings, prediction_objective
from jaxflex.refine import AbstractRefinement, LevenbergMarquardt

METHODS: tuple[str, ...] = tuple(sorted(STRATEGIES))
"""The evolutionary methods an identification can use, by name."""


class FitError(ValueError):
    """A fit that found no parameters at all: every candidate's simulation was non-finite
    (diverged, or gave NaN), so its cost is ``cost`` and its values are arbitrary."""

    def __init__(self, message: str, cost: float) -> None:
        super().__init__(message)
        self.cost = cost


# ------------------------------------------------------------------------------ pipeline


def check_method(method: str) -> str:
    """The search strategy ``method`` in lower case; an unknown one is a one-line error naming
    the choices."""
    name = str(method).lower()
    if name not in STRATEGIES:
        raise ValueError(f"unknown method {method!r}; choose one of {', '.join(METHODS)}")
    return name


def _strategy(search: AbstractStrategy | None, method: str, generations: int,
              population: int | None, options: Mapping[str, Any] | None) -> AbstractStrategy:
    """The search of :func:`identify`: ``search`` itself, or the strategy ``method`` names with
    the paper's settings, ``generations``, ``population`` and ``options``."""
    if search is None:
        overrides = dict(options or {}) | {"generations": generations}
        if population is not None:
            overrides["population"] = population
        return get_strategy(method, "paper", **overrides)
    if not isinstance(search, AbstractStrategy):
        raise TypeError(f"identify: search must be a strategy (e.g. jaxflex.evolve.DE()), got "
                        f"{shown(search)}")
    given = [name for name, value, default in (
        ("method", method, "de"), ("generations", generations, 100),
        ("population", population, None), ("strategy_options", options, None))
        if value != default]
    if given:
        raise ValueError(f"identify: search= holds the whole search; drop {', '.join(given)} "
                         f"(set them on the strategy, e.g. DE(population=40, generations=60))")
    return search


def _refinement(refine: bool | AbstractRefinement, starts: int,
                population: int) -> AbstractRefinement | None:
    """The refinement of :func:`identify`: ``refine`` itself, Levenberg–Marquardt from
    ``starts`` candidates for ``True``, None for ``False``."""
    if isinstance(refine, AbstractRefinement):
        if starts != 1:
            raise ValueError("identify: refine= holds the whole refinement; drop refine_starts "
                             "(e.g. LevenbergMarquardt(starts=3))")
        starts = refine.starts
    elif not isinstance(refine, bool):
        raise TypeError(f"identify: refine must be True, False or a refinement (e.g. "
                        f"LevenbergMarquardt()), got {shown(refine)}")
    if not (isinstance(starts, int) and 1 <= starts <= population):
        raise ValueError(f"refine_starts must be an int in [1, population={population}], "
                         f"got {starts!r}")
    if isinstance(refine, AbstractRefinement):
        return refine
    return LevenbergMarquardt(starts=starts) if refine else None


def _described(method: AbstractRefinement | None) -> dict[str, Any] | None:
    """A refinement's class and settings, for the fit's record of how it was made."""
    if method is None:
        return None
    settings = dataclasses.asdict(method) if dataclasses.is_dataclass(method) else {}
    return {"method": type(method).__name__} | settings


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
    refine: bool | AbstractRefinement = True,
    weights: Mapping[str, float] | None = None,
    progress: bool = False,
    init_population: Any = None,
    bounds: Mapping[str, tuple[float, float]] | None = None,
    *,
    fixed: Mapping[str, float] | None = None,
    channels: Sequence[str] | None = None,
    refine_starts: int = 1,
    strategy_options: Mapping[str, Any] | None = None,
    intervals: bool = True,
    level: float = 0.95,
    noise: Noise | None = None,
    tol: float | None = None,
    criterion: str = "output",
    disturbance: float | None = None,
    search: AbstractStrategy | None = None,
    initial_state: str = "rest",
    initial_modes: int = _initial.DEFAULT_MODES,
) -> Fit:
    """Identify the parameters of ``model`` (default: the reference testbed) from ``records``.

    ``search`` is the evolutionary strategy, with its settings and length
    (``search=DE(population=40, generations=60)``: :mod:`jaxflex.evolve`, or a strategy of one's
    own); ``method`` is the shorthand for a registered one with the paper's settings
    (``"de"``, ``"ga"``, ``"pso"``), ``population`` overriding the preset's (100) and
    ``strategy_options`` any other setting (e.g. ``{"F": 0.7}``).
    The search runs ``generations`` generations from ``seed`` (same seed → same result) in the
    unit box of the free parameters, fewer if ``tol`` is given and the population's costs agree
    to it first (:func:`jaxflex.evolve.run`); ``bounds`` narrows or widens a parameter's range
    (``{"J_h": (1e-3, 1e-2)}``), ``fixed`` holds parameters at given values, ``weights`` and
    ``channels`` shape the objective (:func:`jaxflex.objective.build_objective`); ``noise``
    (channel → σ or :class:`~jaxflex.diagnosis.NoiseLevel`, every fitted channel) sets the
    weights from the channels' noise levels instead (:func:`jaxflex.objective.noise_weights`).
    ``init_population`` seeds the search with physical points (a mapping name → value or
    values, a list of mappings, or a previous :class:`Fit`). ``refine`` polishes the result:
    ``True`` with Levenberg–Marquardt from the ``refine_starts`` best candidates, or as the
    given refinement says (``refine=LevenbergMarquardt(starts=3, max_steps=200)``,
    :mod:`jaxflex.refine`); ``False`` not at all. ``intervals`` computes the
    Gauss–Newton uncertainty at ``level``. ``progress`` reports the stages (search, refinement,
    intervals) on stderr: a bar on a terminal or in Jupyter, else a line per stage.
    ``criterion="prediction"`` fits the Kalman filter's one-step predictions instead of the
    free simulation (:mod:`jaxflex.prediction_error`: closed-loop records, a free rigid-body
    mode); ``disturbance`` (N m) and ``noise`` give the filter's noise levels, fitted by maximum
    likelihood at the reference parameters where not given. ``initial_state`` (``"rest"``,
    ``"estimate"``, ``"periodic"``; ``initial_modes`` modes) says where records start
    (:mod:`jaxflex.initial`); one fitted from rest that moved warns. A fit in which no
    candidate gave a finite simulation raises :class:`FitError`.
    """
    t_start = time.perf_counter()
    check_records(records, "identify")
    method = check_method(method)
    criterion = check_criterion(criterion)
    check_disturbance(disturbance)
    if criterion == "prediction" and initial_state != "rest":
        raise ValueError(f"identify: criterion='prediction' starts its filter from rest and "
                         f"corrects the state from the data; initial_state={initial_state!r} "
                         "applies to output error only")
    objective = build_objective(
        records, model, weights=weights, channels=channels, fixed=fixed, bounds=bounds,
        noise=noise, initial_state=initial_state, initial_modes=initial_modes,
    )
    if criterion == "prediction":
        objective = prediction_objective(
            objective, record_tuple(records), objective.full(objective.space.reference()),
            noise=noise, disturbance=disturbance)
    strategy = _strategy(search, method, generations, population, strategy_options)
    method, generations = strategy.name.lower(), strategy.generations
    refinement_method = _refinement(refine, refine_starts, strategy.population)
    seeds = _unit_seeds(objective, init_population)

    evolution = run(
        strategy,
        objective.fitness,
        objective.dim,
        seed=seed,
        init_population=seeds,
        progress=progress,
        tol=tol,
    )
    best = _physical(objective, evolution.best_x)
    cost_search = float(evolution.best_fitness)
    timing = {"search": evolution.wall_time, "search_compile": evolution.compile_time}

    refinement = None
    estimate, cost, linearization = best, cost_search, None
    if refinement_method is not None:
        starts = _refinement_starts(objective, evolution, refinement_method.starts)
        refinement = refinement_method(objective, starts)
        timing["refine"] = refinement.wall_time
        timing["refine_compile"] = refinement.compile_time
        stage(f"refinement: {refinement.result} after {refinement.steps} steps, cost "
              f"{refinement.cost:.3e} ({refinement.wall_time:.1f} s)", progress)
        if refinement.accepted and refinement.cost < cost:
            estimate, cost = refinement.params, refinement.cost
            linearization = refinement.linearization  # the intervals reuse its Jacobian

    if not math.isfinite(cost):
        effects = objective.model.effect_names
        suspects = f"the effects {list(effects)}, " if effects else ""
        raise FitError(
            f"identify: the fit failed: no candidate of {evolution.n_evaluations} gave a finite "
            f"simulation (cost {cost}), so there are no parameters to return; check "
            f"{suspects}the bounds and the records", cost)
    warnings: list[str] = []
    if objective.initial_state == "rest":  # a record that moved at its start is named
        warnings += [moved for r in record_tuple(records)
                     if (moved := _initial.why_not_still(r, objective.model, objective.channels))]
    if refinement is not None and refinement.result != "successful":
        warnings.append(f"refinement stopped early ({refinement.result}): {refinement.message}")
    if refinement_method is None and intervals:
        warnings.append(
            "intervals computed at the search result, which is not refined to a least-squares "
            "optimum: they are only indicative"
        )
    unc = None
    if intervals and math.isfinite(cost):
        t0 = time.perf_counter()
        unc = uncertainty(objective, estimate, level=level, linearization=linearization)
        timing["uncertainty"] = time.perf_counter() - t0
        stage(f"intervals: {level:.0%} ({timing['uncertainty']:.1f} s)", progress)
        warnings += unc.warnings
    states, state_intervals = _initial.initial_state_report(
        objective, estimate, None if unc is None else unc.noise, level, math.isfinite(cost))
    timing["total"] = time.perf_counter() - t_start

    history_x = np.asarray(objective.space.to_vector(objective.from_unit(evolution.history_best_x)))
    return Fit(
        params=_ordered(objective, estimate),
        names=objective.names,
        fixed={n: float(v) for n, v in objective.fixed.items()},
        model=objective.model,
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
            "generations_run": evolution.generations,
            "tol": tol,
            "n_evaluations": evolution.n_evaluations,
            "refine": refinement_method is not None,
            "refine_starts": None if refinement_method is None else refinement_method.starts,
            "refinement": _described(refinement_method),
            "channels": list(objective.channels),
            "weights": dict(zip(objective.channels, map(float, objective.weights), strict=True)),
            "noise": {c: v.to_dict() for c, v in noise_levels(noise).items()},
            "bounds": {s.name: [s.lower, s.upper] for s in objective.specs},
            "log_scale": {s.name: s.log_scale for s in objective.specs},
            "seeded": 0 if seeds is None else int(seeds.shape[0]),
            "dt": objective.dt,
            "initial_state": objective.initial_state,
            "initial_modes": objective.initial_modes,
        } | ({"criterion": criterion} | noise_settings(objective)
             if criterion != "output" else {}),
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
        unidentifiable=() if unc is None else unc.unidentifiable,
        robust_intervals={} if unc is None else unc.robust_intervals,
        robust_std={} if unc is None or unc.robust_std is None
        else dict(zip(unc.names, map(float, unc.robust_std), strict=True)),
        residual_checks={} if unc is None else _jsonable_checks(unc.residual_checks),
        initial_state=objective.initial_state,
        initial_states=states,
        initial_state_intervals=state_intervals,
    )


def _jsonable_checks(checks: Mapping[str, Any]) -> dict[str, Any]:
    """The residual checks without the per-series bandwidths (each channel keeps its largest)."""
    return {k: v for k, v in checks.items() if k != "hac_lags"}


def _ordered(objective: Objective, estimate: Mapping[str, float]) -> dict[str, float]:
    """Every model parameter in the model's order: identified values, then fixed ones."""
    values = {**{n: float(v) for n, v in objective.fixed.items()}, **estimate}
    return {n: values[n] for n in objective.model.space.names}


__all__ = [
    "FIT_FORMAT",
    "FIT_SCHEMA",
    "METHODS",
    "Fit",
    "FitError",
    "History",
    "build_model",
    "describe_model",
    "identify",
    "load_fit",
]
