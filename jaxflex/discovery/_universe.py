"""The universe: the base model extended by every candidate at its null, so that one compiled
function (and one forward-mode Jacobian) serves every score test, refit and discovery run on
the same records."""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float

from jaxflex.discovery.candidates import Candidate, Variant
from jaxflex.effects import AbstractEffect
from jaxflex.model import Model
from jaxflex.objective import Objective, free_specs
from jaxflex.parallel import population_vmap
from jaxflex.parameters import ParameterSpace


@dataclass(frozen=True)
class Slot:
    """One candidate profile member inside the universe model."""

    candidate: int
    member: int
    effect: AbstractEffect  # the original effect
    names: tuple[str, ...]  # its parameter names in the universe
    own_names: tuple[str, ...]  # its own parameter names

    @property
    def tested(self) -> tuple[str, ...]:
        """The universe names of the parameters with a null, which score tests and likelihood
        ratios judge; a shape parameter without one (a Stribeck velocity) is only fitted."""
        return tuple(n for n, p in zip(self.names, self.effect.parameters, strict=True)
                     if p.null is not None)

    @property
    def tested_own(self) -> tuple[str, ...]:
        """:attr:`tested` under the effect's own names."""
        return tuple(p.name for p in self.effect.parameters if p.null is not None)


@dataclass(frozen=True)
class Universe:
    model: Model  # the starting model followed by every candidate member
    base: Model  # the starting model
    candidates: tuple[Candidate, ...]
    slots: tuple[Slot, ...]
    space: ParameterSpace
    null: np.ndarray  # null of each candidate parameter (a shape parameter: its start; the base
    # ones: unused)
    log: np.ndarray  # log-scale flag per parameter
    fixed: dict[str, float]  # base parameters held at given values (not in ``space``)
    bounds: dict[str, tuple[float, float]]  # the given bounds, in universe names

    @classmethod
    def build(cls, base: Model, candidates: Sequence[Candidate],
              bounds: Mapping[str, tuple[float, float]] | None = None,
              fixed: Mapping[str, float] | None = None) -> Universe:
        """The universe of ``base`` and ``candidates``; ``bounds`` replace the search bounds of
        base or effect parameters (every setting of an effect), ``fixed`` holds base parameters,
        both validated as :func:`jaxflex.identification.identify` validates them."""
        members, slots = [], []
        for i, cand in enumerate(candidates):
            if cand.name in base.effect_names:
                raise ValueError(f"candidate {cand.name!r} is already in the model")
            for j, effect in enumerate(cand.effects):
                variant = Variant(effect, f"__{i}_{j}")
                members.append(variant)
                slots.append(Slot(i, j, effect, tuple(p.name for p in variant.parameters),
                                   tuple(p.name for p in effect.parameters)))
        model = base.with_effects(*members)
        own = {s.name: s for s in base.space.specs}
        for slot in slots:
            own.update({p.name: p for p in slot.effect.parameters if p.name not in own})
        free_specs(ParameterSpace(own.values()), bounds, fixed)  # names, pairs, values
        held = sorted(set(fixed or {}) - set(base.space.names))
        if held:
            raise ValueError(f"fixed names effect parameter(s) {held}; discover holds only "
                             f"base-model parameters fixed: {list(base.space.names)}")
        owner = {u: o for slot in slots for u, o in zip(slot.names, slot.own_names, strict=True)}
        given = dict(bounds or {})
        bounds = {n: tuple(map(float, given[owner.get(n, n)])) for n in model.space.names
                  if owner.get(n, n) in given}
        specs, values = free_specs(model.space, bounds, fixed)
        space = ParameterSpace(specs)
        null = np.array([s.reference if s.null is None else s.null for s in space.specs])
        log = np.array([s.log_scale for s in space.specs])
        return cls(model, base, tuple(candidates), tuple(slots), space, null, log,
                   {n: float(v) for n, v in values.items()}, bounds)

    @property
    def base_names(self) -> tuple[str, ...]:
        """The fitted (not fixed) base parameters: the first :attr:`n_base` of ``space``."""
        return tuple(n for n in self.base.space.names if n not in self.fixed)

    @property
    def n_base(self) -> int:
        return len(self.base_names)

    def index(self, names: Iterable[str]) -> np.ndarray:
        return np.array([self.space.names.index(n) for n in names], dtype=int)

    def vector(self, params: Mapping[str, ArrayLike], active: Sequence[int] = ()) -> np.ndarray:
        """Universe vector: the base parameters and active slots from ``params`` (own names),
        every other candidate parameter at its null."""
        x = self.null.copy()
        for k, n in enumerate(self.base_names):
            x[k] = float(params[n])
        for s in active:
            slot = self.slots[s]
            for u, own in zip(slot.names, slot.own_names, strict=True):
                x[self.space.names.index(u)] = float(params[own])
        return x

    def active_mask(self, active: Sequence[int]) -> np.ndarray:
        mask = np.zeros(len(self.space), dtype=bool)
        mask[: self.n_base] = True
        for s in active:
            mask[self.index(self.slots[s].names)] = True
        return mask

    def params(self, x: np.ndarray, active: Sequence[int]) -> dict[str, float]:
        """Own-named parameters of the base (fixed ones included) and the active slots."""
        out = {**self.fixed, **{n: float(x[k]) for k, n in enumerate(self.base_names)}}
        for s in active:
            slot = self.slots[s]
            for u, own in zip(slot.names, slot.own_names, strict=True):
                out[own] = float(x[self.space.names.index(u)])
        return out

    def slot_of(self, candidate: int, member: int) -> int:
        return next(i for i, s in enumerate(self.slots)
                    if s.candidate == candidate and s.member == member)

    def model_of(self, active: Sequence[int]) -> Model:
        """The plain model (no variants) with the active slots' effects."""
        return self.base.with_effects(*(self.slots[s].effect for s in active))


class Problem(eqx.Module):
    """Whitened predictions of the universe model over the records (:mod:`jaxflex.discovery`)."""

    objective: Objective
    measured: Float[Array, " N"]  # y/σ, in the objective's element order

    sigma: Float[Array, " N"]

    def predicted(self, x: Float[Array, " d"]) -> Float[Array, " N"]:
        """``ŷ/σ`` for the universe parameter vector ``x``."""
        sims = self.objective.simulate(self.objective.space.from_vector(x))
        return jnp.concatenate([s.reshape(-1) for s in sims]) / self.sigma


def _block_impl(problem: Problem, x, tangents):
    """Predictions at ``x`` and their derivatives along ``BLOCK`` tangents (forward mode): the
    tangents select the Jacobian's columns. The tangents are split evenly across the host's
    devices (:func:`jaxflex.parallel.population_vmap`, no whole SIMD vectors asked), each
    device running the primal beside its share: four tangents and a primal on each of two
    cores took 0.6–0.8 of the time of eight on one (ROTFLEX, the bundled example)."""
    ys, jt = population_vmap(lambda t: jax.jvp(problem.predicted, (x,), (t,)), tangents,
                             lanes=1, min_per_device=1)
    return ys[0], jt


jacobian_block = eqx.filter_jit(_block_impl)
"""Compiled residual Jacobian of a block of columns (one compile per problem shape): every
Jacobian of a discovery run."""


forward_many = eqx.filter_jit(lambda problem, xs: population_vmap(problem.predicted, xs))
"""Compiled predictions of a problem at the rows of ``xs``, one batched call."""


MANY = 32

"""Rows per batched prediction (:func:`forward_many`): one compiled size for every batch, split
across two devices (:data:`jaxflex.parallel.MIN_PER_DEVICE`)."""


BLOCK = 8

"""Tangent columns per forward-mode pass (split across the host's devices). Sixteen would take
every ROTFLEX refit's columns in one pass, but where a pass is bound by arithmetic rather than
by its chain of steps (the bundled example's three records, batched) it costs twice as much."""
