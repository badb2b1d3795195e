"""A real-coded genetic algorithm: truncation selection, blend crossover, Gaussian mutation."""

from __future__ import annotations

import math
from typing import Any, ClassVar

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array, Float, PRNGKeyArray

from jaxflex.evolve._base import (
    AbstractStrategy,
    State,
    check_integer,
    check_range,
    gaussian,
    repair,
    uniform_blocks,
    uniform_index,
    update_best,
)


class GA(AbstractStrategy):
    """Real-coded GA on the unit box (after Haupt & Haupt's continuous GA).

    One generation produces ``population`` children and evaluates them in one call:

    * **selection** — truncation: the mating pool is the best
      ``n_pool = max(2, ⌈selection_rate · P⌉)`` members; both parents of a child are drawn
      uniformly (with replacement) from the pool.
    * **crossover** — with probability ``crossover`` the child is a BLX-α blend
      ``c_j = p1_j + γ_j (p2_j - p1_j)``, ``γ_j ~ U(-α, 1 + α)`` (``α = blend_alpha``, 0.5 by
      default, so children may land a little outside the parents' box and the spread of
      the population does not collapse); otherwise it is a copy of ``p1``.
    * **mutation** — each coordinate, with probability ``mutation``, gets Gaussian noise
      ``N(0, mutation_scale²)`` (in unit-box units).
    * **boundary** — components outside ``[0, 1]`` are resampled between ``p1`` and the violated
      bound (:func:`jaxflex.evolve._base.repair`).
    * **elitism** — the ``n_elite`` best members of the old population compete with the
      children; the best ``P`` of those ``P + n_elite`` survive, so the population's best never
      gets worse.

    Needs ``population ≥ 2`` (two parents); ``selection_rate ∈ (0, 1]``, ``crossover`` and
    ``mutation`` in ``[0, 1]``.
    """

    name: ClassVar[str] = "GA"
    population: int = eqx.field(static=True, default=100)
    generations: int = eqx.field(static=True, default=100)
    selection_rate: float = 0.5
    crossover: float = 0.8
    mutation: float = 0.2
    mutation_scale: float = 0.1
    blend_alpha: float = 0.5
    n_elite: int = eqx.field(static=True, default=1)

    def __check_init__(self) -> None:
        check_integer("GA", "population", self.population, 2, "crossover needs two parents")
        check_range("GA", "selection_rate", self.selection_rate, 0.0, 1.0, low_open=True)
        check_range("GA", "crossover", self.crossover, 0.0, 1.0)
        check_range("GA", "mutation", self.mutation, 0.0, 1.0)
        check_range("GA", "mutation_scale", self.mutation_scale, 0.0, math.inf, low_open=True,
                    high_open=True)
        check_range("GA", "blend_alpha", self.blend_alpha, 0.0, math.inf, high_open=True)
        check_integer("GA", "n_elite", self.n_elite, 0)
        if self.n_elite > self.population:
            raise ValueError(
                f"GA: n_elite must be <= population={self.population}, got {self.n_elite}"
            )

    @classmethod
    def paper(cls, **overrides: Any) -> GA:
        """Paper settings: 100 members, selection rate 0.5, crossover 0.8, mutation 0.2."""
        settings = {"population": 100, "selection_rate": 0.5, "crossover": 0.8, "mutation": 0.2}
        return cls(**{**settings, **overrides})

    @property
    def n_pool(self) -> int:
        """Size of the mating pool kept by truncation selection."""
        return min(self.population, max(2, math.ceil(self.selection_rate * self.population)))

    def ask(self, state: State, key: PRNGKeyArray) -> tuple[Float[Array, "P d"], State]:
        """Children: parents from the truncated pool, BLX-α crossover, Gaussian mutation."""
        x, fitness = state.population, state.fitness
        n, d = x.shape
        u_parents, u_cross, u_blend, u_mut, u_noise, u_angle, u_repair = uniform_blocks(
            key, n, 2, 1, d, d, d, d, d
        )

        order = jnp.argsort(fitness, stable=True)
        pool = x[order[: self.n_pool]]
        parents = uniform_index(u_parents, self.n_pool)
        p1, p2 = pool[parents[:, 0]], pool[parents[:, 1]]

        gamma = (1.0 + 2.0 * self.blend_alpha) * u_blend - self.blend_alpha
        child = jnp.where(u_cross < self.crossover, p1 + gamma * (p2 - p1), p1)
        noise = self.mutation_scale * gaussian(u_noise, u_angle)
        return repair(u_repair, jnp.where(u_mut < self.mutation, child + noise, child), p1), state

    def tell(self, state: State, candidates: Float[Array, "P d"],
             fitness: Float[Array, " P"]) -> State:
        """Elitism: the ``n_elite`` best members compete with the children; the best P live."""
        x = state.population
        elite = jnp.argsort(state.fitness, stable=True)[: self.n_elite]
        merged_x = jnp.concatenate([x[elite], candidates])
        merged_f = jnp.concatenate([state.fitness[elite], fitness])
        keep = jnp.argsort(merged_f, stable=True)[: x.shape[0]]
        x, fitness = merged_x[keep], merged_f[keep]
        best_x, best_fitness = update_best(state.best_x, state.best_fitness, x, fitness)
        return State(x, fitness, best_x, best_fitness, state.generation + 1)
