"""Gradient refinement of an identified parameter set.

:func:`refine` polishes the search's best points with the bounded Levenberg–Marquardt of
:mod:`jaxflex.least_squares`, in the unit box of the search; how well the refined parameters
are known is :func:`jaxflex.intervals.uncertainty`'s. The solver's and the intervals' names are
importable from here too, as identification uses the three together.
"""

from __future__ import annotations

import abc
import math
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import jax.numpy as jnp
import numpy as np
from jaxtyping import ArrayLike

from jaxflex.intervals import BOUND_MARGIN as BOUND_MARGIN
from jaxflex.intervals import HAC_MAX_FRACTION as HAC_MAX_FRACTION
from jaxflex.intervals import UNIDENTIFIABLE_RATIO as UNIDENTIFIABLE_RATIO
from jaxflex.intervals import WHITE_ALPHA as WHITE_ALPHA
from jaxflex.intervals import WIDENING_LIMIT as WIDENING_LIMIT
from jaxflex.intervals import Uncertainty as Uncertainty
from jaxflex.intervals import phi_jacobian
from jaxflex.intervals import uncertainty as uncertainty
from jaxflex.least_squares import RESULT_NAMES as RESULT_NAMES
from jaxflex.least_squares import BoundedLevenbergMarquardt as BoundedLevenbergMarquardt
from jaxflex.least_squares import BoundedSolution as BoundedSolution
from jaxflex.least_squares import BoxedDampedNewton as BoxedDampedNewton
from jaxflex.least_squares import bounded_least_squares as bounded_least_squares
from jaxflex.least_squares import bounded_least_squares_of as bounded_least_squares_of
from jaxflex.least_squares import dense_jacobian as dense_jacobian
from jaxflex.least_squares import in_fit_words as in_fit_words
from jaxflex.objective import Objective


def _floats(params: Mapping[str, ArrayLike], names: Sequence[str]) -> dict[str, float]:
    return {n: float(params[n]) for n in names}



@dataclass(frozen=True)
class Refinement:
    """Outcome of :func:`refine`: where it started and ended, and whether the end was kept.

    ``params`` is the accepted point (the start if the refinement was rejected), ``cost`` its
    cost; ``end``/``cost_end`` are where the solver stopped. ``result`` is the optimistix result
    code by name (``"successful"``, ``"nonlinear_max_steps_reached"``, …) and ``steps`` the
    number of Levenberg–Marquardt steps; with several starts, these describe the best one.
    ``linearization`` holds the residuals and their Jacobian in the unit box at ``end`` (from
    the solver's last step; not serialised), which :func:`uncertainty` can reuse.
    """

    start: dict[str, float]
    end: dict[str, float]
    cost_start: float
    cost_end: float
    accepted: bool
    result: str
    message: str
    steps: int
    wall_time: float
    compile_time: float
    n_starts: int = 1
    linearization: tuple[np.ndarray, np.ndarray] | None = field(default=None, repr=False,
                                                                 compare=False)

    @property
    def params(self) -> dict[str, float]:
        return self.end if self.accepted else self.start

    @property
    def cost(self) -> float:
        return self.cost_end if self.accepted else self.cost_start

    def to_dict(self) -> dict:
        return {
            "start": self.start,
            "end": self.end,
            "cost_start": self.cost_start,
            "cost_end": self.cost_end,
            "accepted": self.accepted,
            "result": self.result,
            "message": self.message,
            "steps": self.steps,
            "wall_time": self.wall_time,
            "compile_time": self.compile_time,
            "n_starts": self.n_starts,
        }

    @classmethod
    def from_dict(cls, data: Mapping) -> Refinement:
        return cls(**{k: data[k] for k in cls.__dataclass_fields__ if k != "linearization"})



def refine(
    objective: Objective,
    starts: Mapping[str, ArrayLike] | Sequence[Mapping[str, ArrayLike]],
    *,
    rtol: float = 1e-6,
    atol: float = 1e-8,
    max_steps: int = 100,
) -> Refinement:
    """Levenberg–Marquardt from one start (free parameters, physical) or the best of several.

    Each start is refined by :func:`bounded_least_squares_of` in the unit box of the search;
    the end with the lowest cost is returned, accepted only if it is finite and below the cost
    of the best start. ``rtol``/``atol`` are optimistix's stopping tolerances (on the step in
    the unit box and on the residuals); the defaults resolve the parameters far below their
    statistical uncertainty. The residuals and their Jacobian come from the one compiled
    program :func:`jaxflex.intervals.uncertainty` uses (:func:`jaxflex.intervals.phi_jacobian`,
    in coordinates linear in the unit box), given to a solve compiled without the model step by
    step: the simulator's derivatives compile once per objective, not twice.
    """
    starts = [starts] if isinstance(starts, Mapping) else list(starts)
    if not starts:
        raise ValueError("refine needs at least one start")
    if not (isinstance(max_steps, int) and max_steps >= 1):
        raise ValueError(f"max_steps must be an int >= 1, got {max_steps!r}")
    for label, tol in (("rtol", rtol), ("atol", atol)):
        if not (math.isfinite(tol) and tol > 0):
            raise ValueError(f"{label} must be a positive number, got {tol!r}")
    space, names = objective.space, objective.names
    u_starts = []
    for start in starts:
        missing = [n for n in names if n not in start]
        if missing:
            raise ValueError(f"refinement start lacks parameter(s) {missing}")
        u_starts.append(np.clip(np.asarray(space.to_unit({n: start[n] for n in names})),
                                0.0, 1.0))
    zeros, ones = np.zeros(len(names)), np.ones(len(names))

    t0 = time.perf_counter()
    jacobian, lower, span, size = phi_jacobian(objective, u_starts[0])
    compile_time = time.perf_counter() - t0

    def system(u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        r, jac = jacobian(objective, jnp.asarray(lower + u * span))
        return np.asarray(r), np.asarray(jac) * span

    t0 = time.perf_counter()
    runs = [
        (u0, bounded_least_squares_of(system, size, u0, zeros, ones, rtol=rtol, atol=atol,
                                      max_steps=max_steps))
        for u0 in u_starts
    ]
    wall_time = time.perf_counter() - t0

    best_start = min(runs, key=lambda r: r[1].cost_start)
    _, best = min(runs, key=lambda r: r[1].cost)
    return Refinement(
        start=_floats(space.from_unit(best_start[0]), names),
        end=_floats(space.from_unit(best.value), names),
        cost_start=best_start[1].cost_start,
        cost_end=best.cost,
        accepted=bool(best.cost < best_start[1].cost_start),
        result=best.result,
        message=best.message,
        steps=best.steps,
        wall_time=wall_time,
        compile_time=compile_time,
        n_starts=len(starts),
        linearization=best.linearization,
    )


class AbstractRefinement(abc.ABC):
    """How :func:`jaxflex.identification.identify` polishes the search's result: from the
    ``starts`` best candidates, a :class:`Refinement` of the objective. Subclass it for another
    local method."""

    starts: int = 1

    @abc.abstractmethod
    def __call__(self, objective: Objective,
                 starts: Sequence[Mapping[str, ArrayLike]]) -> Refinement:
        """The refinement of ``objective`` from ``starts`` (free parameters, physical)."""


@dataclass(frozen=True)
class LevenbergMarquardt(AbstractRefinement):
    """Bounded Levenberg–Marquardt in the search's unit box (:func:`refine`) from the
    ``starts`` best candidates, with optimistix's tolerances and a step limit."""

    starts: int = 1
    rtol: float = 1e-6
    atol: float = 1e-8
    max_steps: int = 100

    def __call__(self, objective: Objective,
                 starts: Sequence[Mapping[str, ArrayLike]]) -> Refinement:
        return refine(objective, starts, rtol=self.rtol, atol=self.atol,
                      max_steps=self.max_steps)


__all__ = ["AbstractRefinement", "LevenbergMarquardt", "Refinement", "refine"]
