"""Batched evolutionary search on the unit box: DE, GA and PSO, as in the paper.

Each strategy is an :class:`equinox.Module` of hyper-parameters with pure ``ask``/``tell``
(:class:`AbstractStrategy`: subclass it for a strategy of your own); :func:`run` drives one
for a number of generations and returns an :class:`EvolutionResult`.
The fitness is minimised and evaluates a whole ``(P, d)`` population in one call::

    from jaxflex.evolve import get_strategy, run

    result = run(get_strategy("de"), fitness_fn, dim=6, seed=0, generations=100)
"""

from __future__ import annotations

import dataclasses
from typing import Any

from jaxflex.evolve._base import (
    AbstractStrategy,
    EvolutionResult,
    State,
    StrategyError,
    run,
    update_best,
)
from jaxflex.evolve.de import DE
from jaxflex.evolve.ga import GA
from jaxflex.evolve.pso import PSO, PSOState
from jaxflex.registry import Registry

STRATEGIES: Registry[AbstractStrategy] = Registry(
    "strategy", AbstractStrategy, key=lambda cls: cls.name.lower(), classes=(DE, GA, PSO),
    plural="strategies",
)
"""The evolutionary strategies by name (lower case); ``STRATEGIES.register`` adds one."""
PRESETS = ("paper", "default")
"""Named settings of every strategy: the paper's, or jaxflex's defaults."""


def get_strategy(name: str, preset: str = "paper", **overrides: Any) -> AbstractStrategy:
    """A strategy by name (``"de"``, ``"ga"``, ``"pso"``, any case) from a preset.

    ``preset="paper"`` gives the paper's settings, ``"default"`` the class defaults (the same
    for DE and GA; constriction coefficients for PSO); ``overrides`` replace single fields,
    e.g. ``get_strategy("de", population=40, variant="best1bin")``.
    """
    cls = STRATEGIES.lookup(str(name).lower())
    if preset not in PRESETS:
        raise ValueError(f"unknown preset {preset!r}; valid presets are {list(PRESETS)}")
    valid = {f.name for f in dataclasses.fields(cls)}
    unknown = sorted(set(overrides) - valid)
    if unknown:
        raise ValueError(
            f"{cls.name}: unknown setting(s) {unknown}; valid settings are {sorted(valid)}"
        )
    return cls.paper(**overrides) if preset == "paper" else cls(**overrides)


__all__ = [
    "DE",
    "GA",
    "PSO",
    "AbstractStrategy",
    "EvolutionResult",
    "PSOState",
    "State",
    "StrategyError",
    "get_strategy",
    "run",
    "update_best",
]
