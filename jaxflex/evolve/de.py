"""Differential evolution (Storn & Price, 1997), DE/rand/1/bin and DE/best/1/bin."""

from __future__ import annotations

from typing import Any, ClassVar

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array, Float, Int, PRNGKeyArray

from jaxflex.evolve._base import (
    AbstractStrategy,
    State,
    check_integer,
    check_range,
    repair,
    uniform_blocks,
    uniform_index,
    update_best,
)

VARIANTS = ("rand1bin", "best1bin")
"""Mutation schemes of :class:`DE`: from a random base vector, or from the best one."""


class DE(AbstractStrategy):
    """Differential evolution: difference-vector mutation, binomial crossover, greedy selection.

    For every target ``x_i`` of the population::

        v_i  = x_b + F (x_r1 - x_r2)                          mutation
        u_ij = v_ij if U_ij < CR or j = j_rand else x_ij       binomial crossover
        x_i ← u_i if f(u_i) ≤ f(x_i)                           selection

    with ``r1 ≠ r2`` drawn from the population without ``i``, and the base ``x_b`` a third
    distinct random member (``"rand1bin"``, needs ``population ≥ 4``) or the current best
    (``"best1bin"``, greedier, needs ``population ≥ 3``). ``j_rand`` makes every trial differ
    from its target in at least one coordinate. Selection is elitist, so the population's best
    never gets worse. Trial components that leave the unit box are resampled between the target
    component and the violated bound (:func:`jaxflex.evolve._base.repair`).

    ``F ∈ (0, 2]`` scales the step, ``CR ∈ [0, 1]`` is the fraction of coordinates taken from
    the mutant.
    """

    name: ClassVar[str] = "DE"
    population: int = eqx.field(static=True, default=100)
    generations: int = eqx.field(static=True, default=100)
    F: float = 0.5
    CR: float = 0.8
    variant: str = eqx.field(static=True, default="rand1bin")

    def __check_init__(self) -> None:
        if self.variant not in VARIANTS:
            raise ValueError(f"DE: variant must be one of {VARIANTS}, got {self.variant!r}")
        minimum = 4 if self.variant == "rand1bin" else 3
        check_integer(
            "DE", "population", self.population, minimum,
            f"{self.variant} draws {minimum - 1} distinct members other than the target",
        )
        check_range("DE", "F", self.F, 0.0, 2.0, low_open=True)
        check_range("DE", "CR", self.CR, 0.0, 1.0)

    @classmethod
    def paper(cls, **overrides: Any) -> DE:
        """Paper settings: 100 members, ``F = 0.5``, ``CR = 0.8``, DE/rand/1/bin."""
        return cls(**{"population": 100, "F": 0.5, "CR": 0.8, "variant": "rand1bin", **overrides})

    def ask(self, state: State, key: PRNGKeyArray) -> tuple[Float[Array, "P d"], State]:
        """Trials: mutation from distinct random members, binomial crossover, repair."""
        x, fitness = state.population, state.fitness
        n, d = x.shape
        n_picks = 3 if self.variant == "rand1bin" else 2
        u_pick, u_cross, u_jrand, u_repair = uniform_blocks(key, n, n_picks, d, 1, d)

        others = _distinct_others(u_pick)
        if self.variant == "rand1bin":
            base = x[others[:, 0]]
        else:
            base = jnp.broadcast_to(x[jnp.argmin(fitness)], x.shape)
        mutant = base + self.F * (x[others[:, -2]] - x[others[:, -1]])

        take = (u_cross < self.CR) | (jnp.arange(d) == uniform_index(u_jrand, d))
        return repair(u_repair, jnp.where(take, mutant, x), x), state

    def tell(self, state: State, candidates: Float[Array, "P d"],
             fitness: Float[Array, " P"]) -> State:
        """Greedy selection: each trial replaces its target where it is no worse."""
        accept = fitness <= state.fitness
        x = jnp.where(accept[:, None], candidates, state.population)
        fitness = jnp.where(accept, fitness, state.fitness)
        best_x, best_fitness = update_best(state.best_x, state.best_fitness, x, fitness)
        return State(x, fitness, best_x, best_fitness, state.generation + 1)


def _distinct_others(u: Float[Array, "n k"]) -> Int[Array, "n k"]:
    """Per row ``i``, ``k`` distinct indices uniform on ``{0..n-1} \\ {i}``, from ``u ~ U[0,1)``.

    Draw ``r`` uniform on the ``n - m`` still-allowed values, then skip over the ``m`` already
    taken indices in increasing order (``r += r ≥ e``): O(n k²) work, no ``n × n`` matrix.
    """
    n, k = u.shape
    taken = jnp.arange(n)[:, None]
    for m in range(k):
        r = uniform_index(u[:, m], n - 1 - m)
        excluded = jnp.sort(taken, axis=1)
        for j in range(m + 1):
            r = r + (r >= excluded[:, j])
        taken = jnp.concatenate([taken, r[:, None]], axis=1)
    return taken[:, 1:]
