"""One step at a time on a fitted model: score-test the candidates, refit on the discovery
likelihood, add one effect and refit."""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from typing import Any

import numpy as np
from jaxtyping import ArrayLike

from jaxflex.data import Dataset, Record
from jaxflex.diagnosis import (
    Noise,
    noise_levels,
)
from jaxflex.discovery._engine import Engine
from jaxflex.discovery.candidates import Candidate, as_candidate, candidate_set
from jaxflex.discovery.report import DiscoveryFit
from jaxflex.discovery.scores import ALPHA, ScoreResult
from jaxflex.effects import AbstractEffect
from jaxflex.model import Model
from jaxflex.objective import as_dataset
from jaxflex.records import OUTPUT_COLUMNS


def full_params(model: Model, params: Mapping[str, ArrayLike] | Any) -> dict[str, float]:
    """Parameter values of ``model`` from a mapping or a fit (its ``params``)."""
    values = getattr(params, "params", params)
    if not isinstance(values, Mapping):
        raise TypeError(f"params must be a mapping or a fit with .params, got {type(params)}")
    missing = [n for n in model.space.names if n not in values]
    if missing:
        raise ValueError(f"parameter value(s) missing for {missing}")
    out = {n: float(np.asarray(values[n])) for n in model.space.names}
    model.space.validate(out)
    return out


def score_tests(
    records: Dataset | Iterable[Record],
    model: Model,
    params: Mapping[str, ArrayLike],
    candidates: Iterable[str | AbstractEffect | Candidate] | None = None,
    *,
    alpha: float = ALPHA,
    noise: Noise | None = None,
    channels: Sequence[str] = OUTPUT_COLUMNS,
) -> list[ScoreResult]:
    """Score-test every candidate effect at the fit ``params`` of ``model`` (best first).

    ``candidates`` are effect names or instances (default: the library, Stribeck profiled over
    its velocity grid); those already in ``model`` are skipped. ``noise`` gives each channel's
    :class:`~jaxflex.diagnosis.NoiseLevel` (default: estimated from the residuals).
    ``significant`` marks p-values below ``alpha/m`` (Bonferroni over the ``m`` candidates).
    ``channels`` are the outputs the records measure (see :func:`~jaxflex.discovery.discover`).
    """
    records = as_dataset(records)
    values = full_params(model, params)
    cands = tuple(
        c for c in candidate_set(candidates, channels, model) if c.name not in model.effect_names
    )
    engine = Engine.build(model, cands, records, values, noise, channels=channels)
    return engine.score_tests(engine.universe.vector(values), (), alpha)


def refit(
    records: Dataset | Iterable[Record],
    model: Model,
    params: Mapping[str, ArrayLike] | Any,
    *,
    noise: Noise | None = None,
    channels: Sequence[str] = OUTPUT_COLUMNS,
) -> DiscoveryFit:
    """Fit ``model`` on the discovery likelihood from ``params`` (a mapping or a fit).

    Levenberg–Marquardt of every parameter on the noise-whitened residuals
    (:mod:`jaxflex.discovery`); ``noise`` defaults to the levels estimated from the residuals
    at ``params``; ``channels`` are the outputs the records measure.
    """
    records = as_dataset(records)
    values = full_params(model, params)
    engine = Engine.build(model, (), records, values, noise, channels=channels)
    x, cost = engine.fit(engine.universe.vector(values), ())
    return engine.discovery_fit(x, (), cost)


def add_effect(
    records: Dataset | Iterable[Record],
    fit: DiscoveryFit | Any,
    effect: str | AbstractEffect,
    *,
    model: Model | None = None,
    noise: Noise | None = None,
    channels: Sequence[str] | None = None,
) -> DiscoveryFit:
    """Add ``effect`` to a fitted model and refit everything, warm-started.

    The fitted parameters are kept as the start; the effect's parameters start from the best
    of a short profile over their bounds (and the score test's one-step estimate); then
    Levenberg–Marquardt refines all of them on the discovery likelihood. ``fit`` is a
    :class:`DiscoveryFit` or anything with ``.params`` (then give its ``model``; default the
    reference testbed). A profiled effect name (``"stribeck"``) uses its best-scoring member.
    ``channels`` are the outputs the records measure (default: those of a
    :class:`DiscoveryFit`, else ``joint_angle`` and ``tip_acceleration``).
    """
    records = as_dataset(records)
    base = model if model is not None else getattr(fit, "model", None)
    base = base() if callable(base) and not isinstance(base, Model) else base
    base = base if isinstance(base, Model) else Model()
    values = full_params(base, fit)
    cand = as_candidate(effect)
    if cand.name in base.effect_names:
        raise ValueError(f"effect {cand.name!r} is already in the model")
    levels = dict(fit.noise) if isinstance(fit, DiscoveryFit) else {}
    if channels is None:
        channels = tuple(levels) or OUTPUT_COLUMNS
    levels.update(noise_levels(noise, channels))
    engine = Engine.build(base, (cand,), records, values, levels, channels=channels)
    x0 = engine.universe.vector(values)
    best = engine.score_tests(x0, (), 1.0)[0]
    slot, start = engine.start(x0, (), engine.candidate(cand.name), best.estimate)
    x, cost = engine.fit(start, [slot])
    return engine.discovery_fit(x, [slot], cost)


__all__ = [
    "score_tests",
    "refit",
    "add_effect",
]
