"""The discovery loop: fit the base model, then diagnose, score-test, confirm and add effects
until none is significant and confirmed."""

from __future__ import annotations

import dataclasses
import math
import time
import warnings
from collections.abc import Iterable, Mapping, Sequence
from typing import Any

import numpy as np
from jaxtyping import ArrayLike

from jaxflex._progress import Progress
from jaxflex.comparison import DEFAULT_T_END, FRFSettings, channel_units, compare_record
from jaxflex.data import Dataset, Record
from jaxflex.diagnosis import (
    Diagnosis,
    Noise,
    diagnose,
    noise_levels,
)
from jaxflex.discovery._confirm import confirm, on_bound, profile_scan
from jaxflex.discovery._engine import Engine
from jaxflex.discovery.candidates import Candidate, candidate_set
from jaxflex.discovery.explain import annotate, collect_evidence, percent, ranking_key
from jaxflex.discovery.operations import full_params
from jaxflex.discovery.report import Confirmation, DiscoveryFit, DiscoveryReport, Step
from jaxflex.discovery.scores import ALPHA, ScoreResult
from jaxflex.discovery.torque_proposal import (
    BOOTSTRAP,
    claim,
    errors,
    fitted_expression,
    formula_of,
)
from jaxflex.effects import AbstractEffect
from jaxflex.evolve import AbstractStrategy, get_strategy
from jaxflex.initial import DEFAULT_MODES, check_initial_modes, check_initial_state
from jaxflex.model import Model
from jaxflex.objective import (
    as_dataset,
    check_channels,
    check_records,
    check_weights,
    fitted_channels,
    held_fixed,
)
from jaxflex.simulation import Outputs

MIN_EXPLAINED = 0.9

"""An effect that leaves structure behind is kept only if it removed this share of the misfit,
or, with held-out records, if it lowered their error (the mean over the channels)."""


MAX_CONFIRM = 3

"""Candidates refitted per step to confirm the score ranking."""


BUDGET = (60, 40)

"""(generations, population) of the differential evolution that identifies the base model from
scratch: a reduced budget (the paper: 100 × 100) — seeded around the rigid-body estimate and
refined by Levenberg–Marquardt, the search only has to find the right basin."""


CONFIRM_RATIO = 0.1

"""Candidates are refitted to confirm them if their score reaches this fraction of the best."""


def _metrics(records: Dataset, preds: Sequence[Outputs], holdout: Dataset | None,
             holdout_preds: Sequence[Outputs] | None, channels: Sequence[str],
             t_end: float | None) -> tuple[dict, float, dict | None]:
    """(NRMSE per channel, FRF NRMSE, held-out errors), means over the records, as
    :func:`jaxflex.comparison.compare` computes them over the first ``t_end`` seconds."""
    def rows(role, data, predictions):
        return [compare_record(r, p, role, t_end, FRFSettings(), None, None, channels)
                for r, p in zip(data, predictions, strict=True)]

    fitted = rows("fit", records, preds)
    nrmse = {o: float(np.nanmean([r.nrmse[o] for r in fitted])) for o in channels}
    frf = [r.frf_nrmse for r in fitted if math.isfinite(r.frf_nrmse)]
    held = None
    if holdout is not None and holdout_preds is not None:
        scored = rows("held-out", holdout, holdout_preds)
        held = {key: {o: float(np.nanmean([getattr(r, key)[o] for r in scored]))
                      for o in channels} for key in ("nrmse", "relative_error")}
    return nrmse, float(np.mean(frf)) if frf else math.nan, held


def _rigid(records: Dataset, model: Model, channels: Sequence[str]):
    """The convex rigid-body estimate (no torque offset: the flexible models have none either),
    or ``None`` where the records do not determine it: no joint angle fitted, or an input that
    is not the hub torque (a voltage or current drive)."""
    from jaxflex.drives import TorqueDrive
    from jaxflex.rigid import estimate_rigid

    if "joint_angle" not in channels or not isinstance(model.drive, TorqueDrive):
        return None
    try:
        return estimate_rigid(records, offset=False)
    except ValueError:
        return None


def _rigid_step(engine: Engine, estimate, records: Dataset, holdout: Dataset | None,
                alpha: float, channels: Sequence[str], t_end: float | None) -> Step:
    """The first rung of the ladder: the rigid-body model (no link flexibility)."""
    from jaxflex.rigid import rigid_simulate

    rig = engine.universe.base  # its link and sensors: the rigid predictions of every channel
    preds = tuple(rigid_simulate(estimate, r.input, r.dt, model=rig) for r in records)
    held = None
    if holdout is not None:
        held = [rigid_simulate(estimate, r.input, r.dt, model=rig) for r in holdout]
    nrmse, frf, held = _metrics(records, preds, holdout, held, channels, t_end)
    params = {"J_tot": estimate.J_tot, "b_v": estimate.b_v, "tau_c": estimate.tau_c}
    fit = DiscoveryFit(model=None, params=params, cost=engine.prediction_cost(preds),
                       n_params=len(params),
                       n_samples=engine.n_samples, noise=engine.noise)
    return Step(added=None, fit=fit, nrmse=nrmse, frf_nrmse=frf, holdout=held,
                diagnosis=diagnose(records, preds, noise=engine.noise, alpha=alpha,
                                   channels=channels,
                                   units=channel_units(engine.universe.base, channels)),
                label="rigid", predictions=preds)


def _base_weights(records: Dataset, noise: Noise | None, weights: Mapping[str, float] | None,
                  channels: Sequence[str]) -> dict[str, float] | None:
    """Channel weights of the base model's search: the noise-derived ones
    (:func:`jaxflex.objective.noise_weights`) where ``noise`` gives every fitted channel's level,
    times the user's ``weights`` — the weighting the discovery fits use."""
    from jaxflex.objective import noise_weights

    if noise is None or any(c not in noise_levels(noise, channels) for c in channels):
        return None if weights is None else dict(weights)
    user = dict(weights or {})
    return {c: w * float(user.get(c, 1.0))
            for c, w in noise_weights(records, noise, channels).items()}


def _initial_params(records: Dataset, model: Model, initial: Any, search: AbstractStrategy,
                    seed: int, progress: bool, rigid, fit_options: Mapping[str, Any]
                    ) -> dict[str, float]:
    """The starting fit of the base model: ``initial`` (fixed values put in), or
    :func:`jaxflex.identification.identify` (the ``search``, seeded around the rigid-body
    estimate, then Levenberg–Marquardt) with the run's bounds, fixed values and channel
    weights."""
    fixed = {k: float(v) for k, v in (fit_options["fixed"] or {}).items()}
    if initial is not None:
        return {**full_params(model, initial), **fixed}
    from jaxflex.identification import identify

    bounds = _model_bounds(model, fit_options["bounds"])
    channels = fit_options["channels"]
    weights = _base_weights(records, fit_options["noise"], fit_options["weights"], channels)
    seeds = None
    if rigid is not None:
        from jaxflex.rigid import warm_start

        space = model.space.with_bounds(bounds)
        units = warm_start(rigid, space, population=search.population, seed=seed)
        seeds = [{k: float(v) for k, v in space.from_unit(u).items()} for u in units]
    fit = identify(records, model, search=search, seed=seed, progress=progress,
                   init_population=seeds, intervals=False, bounds=bounds or None,
                   fixed=fixed or None, weights=weights, channels=channels,
                   initial_state=fit_options["initial_state"],
                   initial_modes=fit_options["initial_modes"])
    return full_params(model, fit)


def _model_bounds(model: Model, bounds: Mapping[str, tuple[float, float]] | None
                  ) -> dict[str, tuple[float, float]]:
    """The given ``bounds`` of ``model``'s own parameters (the others bound effects)."""
    return {k: v for k, v in (bounds or {}).items() if k in model.space.names}


def _anchor(model: Model, initial: Any, start: Mapping[str, float], rigid,
            bounds: Mapping[str, tuple[float, float]] | None) -> dict[str, Any] | None:
    """Where a base parameter that a refit leaves on a bound is sent back to: the given start,
    or, for a base model identified from scratch, the search's centre
    (:func:`jaxflex.rigid.search_centre`). That fit's own values will not do: a parameter that
    compensated the missing effect ended on its bound there already (a Rayleigh damping at its
    maximum beside a compliant clamp) and would be sent back onto it."""
    if initial is not None:
        return None  # the given start itself
    from jaxflex.rigid import search_centre

    return search_centre(rigid, model.space.with_bounds(_model_bounds(model, bounds)))


def _channels(records: Dataset, channels: Sequence[str], model: Model) -> tuple[str, ...]:
    """``channels`` validated: distinct outputs or sensor channels that every record measures."""
    channels = check_channels(channels, model)
    for c in channels:
        for r in records:
            if c not in r.columns:
                raise ValueError(f"record {r.name!r} has no {c!r} column to fit; its columns "
                                 f"are {list(r.columns)}")
    return channels


def discover(
    records: Dataset | Iterable[Record],
    holdout: Dataset | Iterable[Record] | None = None,
    model: Model | None = None,
    candidates: Iterable[str | AbstractEffect | Candidate] | None = None,
    max_steps: int = 4,
    alpha: float = ALPHA,
    seed: int = 0,
    progress: bool = False,
    *,
    initial: Mapping[str, ArrayLike] | Any = None,
    budget: int | tuple[int, int] | None = None,
    search: AbstractStrategy | None = None,
    noise: Noise | None = None,
    bounds: Mapping[str, tuple[float, float]] | None = None,
    fixed: Mapping[str, float] | None = None,
    weights: Mapping[str, float] | None = None,
    channels: Sequence[str] | None = None,
    t_end: float | None = DEFAULT_T_END,
    max_confirm: int = MAX_CONFIRM,
    initial_state: str = "rest",
    initial_modes: int = DEFAULT_MODES,
    torque_map: bool = True,
) -> DiscoveryReport:
    """Find the effects the model is missing, one at a time (see :mod:`jaxflex.discovery`).

    ``model`` is the starting structure (default: the reference testbed). ``initial`` is its
    fitted parameters (a mapping or a fit); without it the base model is identified from scratch
    by ``search`` and Levenberg–Marquardt (:func:`jaxflex.identification.identify`): a strategy
    object (``search=DE(population=40, generations=60)``), or differential evolution of
    ``budget`` generations or ``(generations, population)`` (default :data:`BUDGET`).
    ``alpha`` is the family-wise level of each step, Bonferroni over the candidates. ``noise``
    gives channels' noise levels, a white σ in the channel's unit or a
    :class:`~jaxflex.diagnosis.NoiseLevel` (e.g. ``{"joint_angle": 1e-4}``); the others are
    estimated from the first fit's residuals (:func:`jaxflex.diagnosis.estimate_noise`), and
    the report states each level and how it was obtained; where it gives every channel, the
    base model's search uses them too.

    ``bounds``, ``fixed`` and ``weights`` are :func:`jaxflex.identification.identify`'s, validated
    by the same code: ``bounds`` replace the search box of base parameters and of effect
    parameters (used when the effect is added), ``fixed`` holds base parameters at their values
    in every fit (not fitted, not counted, not a nuisance of the score tests), and a channel's
    weight ``w`` scales its noise-whitened residual by ``√w`` (its noise level divided by
    ``√w``; 0 leaves the channel out of the fits and tests). Unlike ``identify``, weights combine
    with noise levels: the tests assume the weighted residuals are unit white noise, so weights
    other than 0 and 1 change the tests' level.

    ``channels`` are the outputs or sensor channels every record (and held-out record) measures
    and the fits use (default: the rig's sensor channels that they all hold, or joint angle and
    tip acceleration for a rig without sensors); residuals, noise levels, diagnostics and the
    report are per channel. The steps' NRMSE covers the first ``t_end`` seconds of each record
    (``None``: the whole record). ``progress`` reports the base model's fit and each step on
    stderr, as :func:`~jaxflex.identification.identify` does. ``initial_state``
    (``"rest"``, ``"estimate"``, ``"periodic"``; ``initial_modes`` modes) says where the
    records start (:mod:`jaxflex.initial`): each record's state, fitted and held out, is
    estimated with the parameters in every fit, test and prediction.

    ``torque_map`` (default on): where the run ends with the misfit unexplained and no
    candidate confirmed, the missing hub torque is mapped at the final model and its expression,
    where it is a function of state and input, refitted as a formula effect
    (:mod:`jaxflex.discovery.torque_proposal`, the ``"torque_map"`` claim of
    :data:`~jaxflex.discovery.explain.RULES`); the report's ``torque_map`` says what came of it.
    Returns a :class:`DiscoveryReport`.
    """
    t0 = time.perf_counter()
    check_records(records, "discover")
    records = as_dataset(records)
    holdout = as_dataset(holdout) if holdout is not None else None
    model = Model() if model is None else model
    if not isinstance(model, Model):
        raise TypeError(f"model must be a jaxflex Model, got {type(model).__name__}")
    if isinstance(max_steps, bool) or not isinstance(max_steps, int) or max_steps < 0:
        raise ValueError(f"max_steps={max_steps!r} must be an int >= 0")
    if not 0 < alpha < 1:
        raise ValueError(f"alpha={alpha!r} must lie in (0, 1)")
    if search is None:
        budget = BUDGET if budget is None else budget
        budget = (int(budget), BUDGET[1]) if isinstance(budget, (int, np.integer)) else budget
        if len(budget) != 2 or min(budget) < 1:
            raise ValueError(f"budget={budget!r} must be generations or (generations, "
                             "population)")
        search = get_strategy("de", generations=int(budget[0]), population=int(budget[1]))
    elif budget is not None:
        raise ValueError("the base model's search is given twice: search= or budget=, not both")
    elif not isinstance(search, AbstractStrategy):
        raise TypeError(f"search must be a strategy (jaxflex.evolve), got {type(search).__name__}")
    if channels is None:
        every = [*records, *(holdout or ())]
        channels = tuple(c for c in fitted_channels(records, model)
                         if all(c in r.columns for r in every)) or fitted_channels(every, model)
        for c in fitted_channels(every, model):
            lacking = next((r.name for r in every if c not in r.columns), None)
            if c not in channels and lacking is not None:
                warnings.warn(f"channel {c!r} is not fitted: record {lacking!r} does not log it, "
                              "and discovery fits only the channels every record logs",
                              stacklevel=2)
    fixed = held_fixed(model, fixed, bounds)
    channels = _channels(records, channels, model)
    cands = tuple(
        c for c in candidate_set(candidates, channels, model) if c.name not in model.effect_names
    )
    if holdout is not None:
        _channels(holdout, channels, model)
    check_initial_state(initial_state)
    initial_modes = check_initial_modes(initial_modes, model)
    fit_options = {"bounds": bounds, "fixed": fixed, "weights": weights, "noise": noise,
                   "channels": channels, "initial_state": initial_state,
                   "initial_modes": initial_modes}
    # bad names or values: fail before any fit
    Engine.make_universe(model, cands, bounds, fixed, channels)
    check_weights(weights, channels)
    rigid = _rigid(records, model, channels)
    start = _initial_params(records, model, initial, search, seed, progress, rigid, fit_options)
    engine = Engine.build(model, cands, records, start, noise, bounds=bounds, fixed=fixed,
                          weights=weights, channels=channels,
                          anchor=_anchor(model, initial, start, rigid, bounds),
                          record_start=(initial_state, initial_modes))
    u = engine.universe
    names = [c.name for c in u.candidates]

    x, cost = engine.fit(u.vector(start), ())
    active: list[int] = []
    steps: list[Step] = []
    if rigid is not None:
        steps.append(_rigid_step(engine, rigid, records, holdout, alpha, channels, t_end))
    added: dict[str, Any] = {}
    held_out: dict[bytes, tuple[Outputs, ...]] = {}  # held-out predictions of the refits
    bar = Progress(range(max_steps + 1), label="discover", enabled=progress, each_stage=True)
    for _ in bar:
        preds = engine.predictions(x, records)
        diag = diagnose(records, preds, noise=engine.noise, alpha=alpha, channels=channels,
                        units=channel_units(model, channels))
        held_preds = None
        if holdout is not None:
            held_preds = held_out.get(x.tobytes()) or engine.predictions(x, holdout)
        nrmse, frf, held = _metrics(records, preds, holdout, held_preds, channels, t_end)
        ranking: list[ScoreResult] = []
        confirmations: list[Confirmation] = []
        refits: list[tuple[int, np.ndarray, float]] = []  # (slot, x1, cost1) of each
        best = None  # the index of the confirmed refit of largest LR
        if len(active) < max_steps and len(active) < len(cands):
            ranking = engine.score_tests(x, active, alpha)
            m = len(ranking)
            top = max((r.statistic for r in ranking), default=0.0)
            contenders = [r for r in ranking
                          if r.significant and r.statistic >= CONFIRM_RATIO * top]
            skipped = {r.effect: "ratio" for r in ranking if r.significant} | {
                r.effect: "full" for r in contenders}
            starts: dict[str, tuple[int, np.ndarray]] = {}
            scanned = False
            while True:
                # the scan's drops are first-order: every candidate it finds is refitted
                chosen = contenders if scanned else contenders[:max_confirm]
                for conf, slot, x1, cost1 in confirm(
                        engine, x, cost, active,
                        [(names.index(r.effect), r.estimate, starts.get(r.effect))
                         for r in chosen], alpha / m):
                    if conf.confirmed and (best is None or conf.lr > confirmations[best].lr):
                        best = len(confirmations)
                    confirmations.append(conf)
                    refits.append((slot, x1, cost1))
                if scanned or diag.consistent_with_noise or (
                        best is not None and confirmations[best].explained >= MIN_EXPLAINED):
                    break
                # the score tests' first-order picture named nothing that explains the misfit
                # (an effect that moves a resonance far, compensated by a base parameter, scores
                # the wrong way at the null): scan the profiles of the candidates not refitted
                refitted = {c.effect for c in confirmations}
                ranking, starts = profile_scan(engine, x, active, ranking, alpha / m,
                                               skip=refitted)
                contenders = sorted((r for r in ranking if r.profile_drop is not None
                                     and r.effect not in refitted
                                     and r.profile_p_value < alpha / m),
                                    key=lambda r: -r.profile_drop)
                skipped |= {r.effect: "full" for r in contenders}
                scanned = True
            if holdout is not None and refits:  # every refit's held-out run in one batch
                ends = [x1 for _, x1, _ in refits]
                held_out = {x1.tobytes(): p for x1, p in
                            zip(ends, engine.predictions_many(ends, holdout), strict=True)}
                confirmations = [dataclasses.replace(c, holdout_error=_holdout_error(
                    holdout, held_out[x1.tobytes()], channels, t_end))
                    for c, x1 in zip(confirmations, ends, strict=True)]
            ranking = _final_ranking(ranking, confirmations, u.candidates, diag, alpha / m,
                                     _mean_error(held), skipped)
        steps.append(Step(
            **_base_on_bounds(u, x, active),
            added=added.get("name"), fit=engine.discovery_fit(x, active, cost), nrmse=nrmse,
            frf_nrmse=frf, holdout=held, diagnosis=diag, ranking=tuple(ranking),
            confirmations=tuple(confirmations), lr=added.get("lr"),
            p_value=added.get("p"), explained=added.get("explained"), predictions=preds,
            holdout_predictions=tuple(held_preds or ()),
        ))
        found = ("no refit confirmed one" if best is None else
                 f"the refit confirmed {confirmations[best].effect}: added (withdrawn at the "
                 "end if it leaves most of the misfit)")
        bar.set_message(f"after '{steps[-1].structure}': {len(ranking)} candidates tested; "
                        f"{found}")
        if best is None:
            break
        conf, (slot, x, cost) = confirmations[best], refits[best]
        active = active + [slot]
        added = {"name": conf.effect, "lr": conf.lr, "p": conf.p_value,
                 "explained": conf.explained}

    steps, cut = _withdraw(steps)
    withdrawn = [s.added for s in cut if s.added]
    effects = {c.name: c.effects[0] for c in cands}
    mapped = None
    if (torque_map and not steps[-1].diagnosis.consistent_with_noise
            and sum(s.added is not None for s in steps) < max_steps):
        step, mapped = _torque_map_step(engine, steps[-1], records, holdout, alpha, seed,
                                        fit_options, t_end)
        if step is not None:
            steps[-1] = dataclasses.replace(steps[-1], ranking=tuple(sorted(
                (*steps[-1].ranking, mapped.pop("result")), key=ranking_key)))
            steps.append(step)
            effects[step.added] = step.fit.model.effects[-1]
        mapped.pop("result", None)
    every = annotate([*steps, *cut], withdrawn, MIN_EXPLAINED, effects)
    steps, cut = every[:len(steps)], every[len(steps):]
    unexplained = steps[-1].diagnosis.unexplained()
    if unexplained is not None:
        if steps[-1].ranking or withdrawn:
            note = "no candidate effect explains it"
        elif sum(s.added is not None for s in steps) >= max_steps:
            note = f"the loop stopped at max_steps={max_steps} before testing more candidates"
        else:
            note = "every candidate is in the model already"
        if withdrawn:
            note += f" ({withdrawn_note(cut, holdout is not None)})"
        if mapped is not None and mapped["added"]:
            note = "the library and the mapped torque leave it"
        unexplained["message"] = f"{unexplained['message']}; {note}"
    return DiscoveryReport(
        steps=tuple(steps),
        unexplained=unexplained,
        withdrawn=tuple(withdrawn),
        alpha=alpha,
        candidates=tuple(c.name for c in cands),
        records=records,
        holdout=holdout,
        settings={"alpha": alpha, "correction": "Bonferroni over the candidates of each step",
                  "max_steps": max_steps, "max_confirm": max_confirm, "seed": seed,
                  "channels": list(channels), "t_end": t_end,
                  "initial_state": initial_state, "initial_modes": initial_modes,
                  "budget": (search.generations, search.population)
                  if initial is None else None,
                  "search": None if initial is not None else
                  {"method": type(search).__name__} | search.settings(),
                  "initial": "given" if initial is not None else "identified",
                  "noise": {c: v.to_dict() for c, v in engine.noise.items()},
                  "bounds": {**{n: [u.space[n].lower, u.space[n].upper]
                                for n in u.base_names},
                             **{n: list(map(float, b)) for n, b in (bounds or {}).items()}},
                  "fixed": dict(u.fixed), "weights": dict(engine.weights),
                  "min_explained": MIN_EXPLAINED, "torque_map": bool(torque_map),
                  "torque_map_bootstrap": BOOTSTRAP},
        wall_time=time.perf_counter() - t0,
        noise_floor={c: d.noise_floor_nrmse for c, d in steps[-1].diagnosis.channels.items()},
        withdrawn_steps=tuple(cut),
        torque_map=mapped,
    )


def _base_on_bounds(universe, x: np.ndarray, active) -> dict[str, Any]:
    """A step's ``on_bound`` and ``bounds``: the base parameters that end on a bound at ``x``
    (:func:`~jaxflex.discovery._confirm.on_bound`) and those parameters' bounds."""
    specs = [universe.space[n] for n in universe.base_names]
    ends = on_bound(universe.params(x, active), specs)
    return {"on_bound": ends,
            "bounds": {s.name: (s.lower, s.upper) for s in specs if s.name in ends}}


def _torque_map_step(engine: Engine, last: Step, records: Dataset, holdout: Dataset | None,
                     alpha: float, seed: int, fit_options: Mapping[str, Any],
                     t_end: float | None) -> tuple[Step | None, dict[str, Any]]:
    """The missing torque mapped at ``last``'s fit and, where the map proposes a formula,
    that formula refitted as a candidate (:func:`~jaxflex.discovery._confirm.confirm`: LR at
    ``alpha``, BIC, bound rules) and its held-out error: (the step that adds it, or ``None``
    where it is not added; the outcome, its ``"result"`` the formula's ranked score result
    where added)."""
    from jaxflex.discovery.candidates import as_candidate
    from jaxflex.missing_torque import estimate_missing_torque
    from jaxflex.torque_regression import torque_map

    channels = fit_options["channels"]
    final = last.fit
    before = errors(last.nrmse, last.holdout)
    try:
        estimate = estimate_missing_torque(records, final.model, final.params,
                                           channels=channels, noise=engine.noise)
    except ValueError as error:  # a model or channels the augmented filter does not take
        return None, {"map": None, "effect": None, "added": False, "error_before": before,
                      "claim": f"the missing torque could not be mapped ({error})"}
    tmap = torque_map(estimate, bootstrap=BOOTSTRAP, seed=seed)
    effect = formula_of(tmap)
    outcome: dict[str, Any] = {"map": tmap.to_dict(), "effect": None, "formula": None,
                               "added": False, "refit": None, "error_before": before,
                               "error_after": None}
    if effect is None:
        return None, outcome | {"claim": claim(outcome)}
    cand = as_candidate(effect)
    eng = Engine.build(final.model, (cand,), records, final.params, engine.noise,
                       bounds=fit_options["bounds"], fixed=fit_options["fixed"],
                       weights=fit_options["weights"], channels=channels,
                       record_start=engine.record_start)
    x0, cost0 = eng.fit(eng.universe.vector(final.params), ())
    score = eng.score_tests(x0, (), alpha)[0]
    [(conf, slot, x1, cost1)] = confirm(eng, x0, cost0, [], [
        (eng.candidate(cand.name), score.estimate, None)], alpha)
    preds = eng.predictions(x1, records)
    held_preds = eng.predictions(x1, holdout) if holdout is not None else None
    nrmse, frf, held = _metrics(records, preds, holdout, held_preds, channels, t_end)
    if held is not None:
        conf = dataclasses.replace(conf, holdout_error=_mean_error(held))
    after = errors(nrmse, held)
    added = conf.confirmed and (held is None or _mean_error(held) < _mean_error(last.holdout))
    outcome |= {"effect": effect.name, "formula": effect.expression,
                "fitted_expression": fitted_expression(effect, conf.params),
                "added": bool(added), "error_after": after,
                "refit": {"lr": conf.lr, "p_value": conf.p_value, "level": conf.level,
                          "delta_bic": conf.delta_bic, "explained": conf.explained,
                          "confirmed": conf.confirmed, "on_bound": dict(conf.on_bound),
                          "params": {n: conf.params[n] for n in effect.names}}}
    outcome["claim"] = claim(outcome)
    if not added:
        return None, outcome
    diag = diagnose(records, preds, noise=eng.noise, alpha=alpha, channels=channels,
                    units=channel_units(final.model, channels))
    result = dataclasses.replace(score, evidence=collect_evidence(
        score, effect, last.diagnosis, conf, level=alpha,
        holdout_error=_mean_error(last.holdout)))
    step = Step(added=effect.name, fit=eng.discovery_fit(x1, [slot], cost1), nrmse=nrmse,
                frf_nrmse=frf, holdout=held, diagnosis=diag, lr=conf.lr, p_value=conf.p_value,
                explained=conf.explained, predictions=preds,
                holdout_predictions=tuple(held_preds or ()),
                **_base_on_bounds(eng.universe, x1, [slot]), torque_map=outcome)
    return step, outcome | {"result": result}


def _final_ranking(ranking: Sequence[ScoreResult], confirmations: Sequence[Confirmation],
                   cands: Sequence[Candidate], diag: Diagnosis, level: float,
                   holdout_error: float | None, skipped: Mapping[str, str]
                   ) -> list[ScoreResult]:
    """The ranking after the refits, in the order of
    :func:`~jaxflex.discovery.explain.ranking_key` (confirmed candidates by their likelihood
    ratio, then the others by their score test's p-value), each with its evidence (refit values
    where refitted)."""
    names = [c.name for c in cands]
    refits = {c.effect: c for c in confirmations}
    out = []
    for r in ranking:
        cand = cands[names.index(r.effect)]
        conf = refits.get(r.effect)
        member = conf.member if conf else r.member
        if conf and conf.member != r.member:
            r = dataclasses.replace(r, setting=conf.setting, member=member)
        out.append(dataclasses.replace(r, evidence=collect_evidence(
            r, cand.effects[member], diag, conf, level=level, holdout_error=holdout_error,
            skipped=None if conf else skipped.get(r.effect))))
    return sorted(out, key=ranking_key)


def _mean_error(held: Mapping[str, Any] | None) -> float | None:
    """The held-out relative error, the mean over the channels (``None``: no held-out records)."""
    if held is None:
        return None
    return float(np.mean(list(held["relative_error"].values())))


def _holdout_error(holdout: Dataset, preds: Sequence[Outputs], channels: Sequence[str],
                   t_end: float | None) -> float:
    """The held-out relative error of predictions of ``holdout``, the mean over the channels."""
    rows = [compare_record(r, p, "held-out", t_end, FRFSettings(), None, None, channels)
            for r, p in zip(holdout, preds, strict=True)]
    return float(np.mean([np.nanmean([row.relative_error[o] for row in rows])
                          for o in channels]))


def _withdraw(steps: list[Step]) -> tuple[list[Step], list[Step]]:
    """Steps without effects that leave structure behind yet removed less than
    :data:`MIN_EXPLAINED` of the misfit and did not lower the held-out error (no held-out
    records: did not): the run is cut before the first such effect; returns the steps kept and
    the steps cut.

    A real rig always leaves some structure the candidates cannot explain; an effect that
    explains part of it is kept when records it was not fitted to confirm it."""
    if steps[-1].diagnosis.consistent_with_noise:
        return steps, []
    for i, step in enumerate(steps):
        if (step.added is not None and step.explained < MIN_EXPLAINED
                and not _predicts_better(steps[i - 1], step)):
            return steps[:i], steps[i:]
    return steps, []


def withdrawn_note(cut: Sequence[Step], held_out: bool) -> str:
    """What the withdrawn effects of the steps ``cut`` did, from their own refits: the share
    of the misfit above the noise each removed (a negative one: it added misfit)."""
    held = " and did not lower the held-out error" if held_out else ""
    removed = ", ".join(
        f"{s.added} removed {percent(s.explained)}" if s.explained >= 0 else
        f"{s.added} added {percent(-s.explained)}" for s in cut if s.added)
    return (f"{removed} of the misfit above the noise, less than {percent(MIN_EXPLAINED)}"
            f"{held}; withdrawn")


def _predicts_better(before: Step, after: Step) -> bool:
    """True if ``after`` has the lower held-out relative error, the mean over the channels (each
    counts alike, whatever its unit, as in the identification objective)."""
    if before.holdout is None or after.holdout is None:
        return False
    return _mean_error(after.holdout) < _mean_error(before.holdout)


__all__ = [
    "discover",
]
