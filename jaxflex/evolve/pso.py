"""Particle swarm optimisation (Kennedy & Eberhart, 1995) with inertia weight and velocity clamp."""

from __future__ import annotations

import dataclasses
import math
from typing import Any, ClassVar

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Float, PRNGKeyArray

from jaxflex.evolve._base import (
    AbstractStrategy,
    State,
    check_integer,
    check_range,
    clip_at_walls,
    uniform_blocks,
    update_best,
)


class PSOState(State):
    """Swarm state: positions are ``population``, plus velocities and personal bests."""

    velocity: Float[Array, "P d"]
    personal_best_x: Float[Array, "P d"]
    personal_best_fitness: Float[Array, " P"]


class PSO(AbstractStrategy):
    """Global-best PSO on the unit box.

    Per particle and coordinate, with fresh ``r1, r2 ~ U(0, 1)``::

        v ← w_g v + c1 r1 (p - x) + c2 r2 (g - x)        p: personal best, g: swarm best
        v ← clip(v, -v_max, v_max)                       if v_max is set
        x ← x + v

    Positions are clipped to ``[0, 1]`` and the velocity component that hit a wall is set to
    zero (:func:`jaxflex.evolve._base.clip_at_walls`). Velocities start at zero.

    The inertia ``w_g`` is constant (``w_final=None``) or decreases linearly from ``w`` at the
    first generation to ``w_final`` at generation ``horizon`` and stays there; :func:`run` sets
    ``horizon`` to its number of generations. The default is Clerc's constriction
    (``w = 0.7298``, ``c1 = c2 = 1.49618``), which converges without a clamp. The paper's
    ``w = 1.4`` makes velocities grow geometrically, so :meth:`paper` decreases ``w`` from 1.4
    to 0.4 over the run (explore first, converge at the end) *and* clamps ``|v_j| ≤ 0.2`` (a
    fifth of the box per generation) to keep the early, expanding phase bounded.
    """

    name: ClassVar[str] = "PSO"
    population: int = eqx.field(static=True, default=100)
    generations: int = eqx.field(static=True, default=100)
    w: float = 0.7298
    c1: float = 1.49618
    c2: float = 1.49618
    w_final: float | None = None
    v_max: float | None = None
    horizon: int = eqx.field(static=True, default=100)

    def __check_init__(self) -> None:
        check_integer("PSO", "population", self.population, 2, "a swarm shares a best position")
        check_range("PSO", "w", self.w, 0.0, math.inf, high_open=True)
        check_range("PSO", "c1", self.c1, 0.0, math.inf, high_open=True)
        check_range("PSO", "c2", self.c2, 0.0, math.inf, high_open=True)
        if self.w_final is not None:
            check_range("PSO", "w_final", self.w_final, 0.0, math.inf, high_open=True)
        if self.v_max is not None:
            check_range("PSO", "v_max", self.v_max, 0.0, 1.0, low_open=True)
        check_integer("PSO", "horizon", self.horizon, 1)

    @classmethod
    def paper(cls, **overrides: Any) -> PSO:
        """Paper settings (100 particles, ``w = 1.4``, ``c1 = 1.5``, ``c2 = 2.5``), made convergent.

        ``w`` decreases linearly to 0.4 over the run and ``|v_j| ≤ 0.2``, see the class doc.
        """
        settings = {"population": 100, "w": 1.4, "c1": 1.5, "c2": 2.5, "w_final": 0.4,
                    "v_max": 0.2}
        return cls(**{**settings, **overrides})

    def for_generations(self, generations: int) -> PSO:
        """Stretch the inertia schedule over ``generations``."""
        return dataclasses.replace(self, horizon=generations)

    def inertia(self, generation: ArrayLike) -> Float[Array, ""]:
        """``w_g`` for the update made in generation ``g + 1`` (``g`` updates done so far)."""
        if self.w_final is None:
            return jnp.asarray(self.w, dtype=float)
        fraction = jnp.clip(generation / max(self.horizon - 1, 1), 0.0, 1.0)
        return self.w + (self.w_final - self.w) * fraction

    def start(self, population: Float[Array, "P d"], fitness: Float[Array, " P"]) -> PSOState:
        """The swarm at rest: zero velocities, each particle its own best."""
        s = super().start(population, fitness)
        return PSOState(
            s.population, s.fitness, s.best_x, s.best_fitness, s.generation,
            velocity=jnp.zeros_like(s.population),
            personal_best_x=s.population,
            personal_best_fitness=s.fitness,
        )

    def ask(self, state: PSOState, key: PRNGKeyArray) -> tuple[Float[Array, "P d"], PSOState]:
        """The particles moved by their new velocities (kept in the returned state)."""
        x, v = state.population, state.velocity
        r1, r2 = uniform_blocks(key, x.shape[0], x.shape[1], x.shape[1])
        v = (
            self.inertia(state.generation) * v
            + self.c1 * r1 * (state.personal_best_x - x)
            + self.c2 * r2 * (state.best_x[None, :] - x)
        )
        if self.v_max is not None:
            v = jnp.clip(v, -self.v_max, self.v_max)
        x, v = clip_at_walls(x + v, v)
        return x, dataclasses.replace(state, velocity=v)

    def tell(self, state: PSOState, candidates: Float[Array, "P d"],
             fitness: Float[Array, " P"]) -> PSOState:
        """Personal and swarm bests updated; the particles stay where they moved."""
        improved = fitness < state.personal_best_fitness
        pbest_x = jnp.where(improved[:, None], candidates, state.personal_best_x)
        pbest_f = jnp.where(improved, fitness, state.personal_best_fitness)
        best_x, best_fitness = update_best(state.best_x, state.best_fitness, candidates, fitness)
        return PSOState(
            candidates, fitness, best_x, best_fitness, state.generation + 1,
            velocity=state.velocity, personal_best_x=pbest_x, personal_best_fitness=pbest_f,
        )
