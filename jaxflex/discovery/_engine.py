"""The fitting engine of discovery: the noise-whitened, quantisation-aware discovery
likelihood on the universe, its fits (pattern search, profiles, and the bounded
Levenberg–Marquardt of :mod:`jaxflex.least_squares`) and score tests, with one compiled Jacobian for
the whole run."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass

import jax
import jax.numpy as jnp
import numpy as np
from scipy import stats

from jaxflex.data import Dataset
from jaxflex.diagnosis import (
    Noise,
    NoiseLevel,
    estimate_noise,
    noise_levels,
)
from jaxflex.discovery._universe import (
    BLOCK,
    MANY,
    Problem,
    Universe,
    forward_many,
    jacobian_block,
)
from jaxflex.discovery.candidates import Candidate, candidate_set
from jaxflex.discovery.report import DiscoveryFit
from jaxflex.discovery.scores import ScoreResult, score_statistic
from jaxflex.initial import DEFAULT_MODES, simulate_started
from jaxflex.least_squares import bounded_least_squares_of
from jaxflex.model import Model
from jaxflex.objective import build_objective
from jaxflex.parallel import LANES
from jaxflex.parameters import ParameterSpace
from jaxflex.records import OUTPUT_COLUMNS
from jaxflex.sensors import calibrated
from jaxflex.simulation import Outputs, simulate_batch

INNER_WEIGHT = 1e-2

"""``ε``: weight of quantised residuals inside the quantisation band in fits (not in tests)."""


PROFILE_POINTS = 13

"""Start values of a new effect's parameters tried before the refit (unit-box diagonal)."""


PROFILE_REFINED = 15

"""Points of a profile's each finer grid, evenly spaced between the lowest point's neighbours
(a fixed number, so that a profile's points do not depend on the profiles beside it)."""


PROFILE_WIDTH = 5e-4

"""A profile is refined until the neighbours of its lowest point are this close (unit box;
the final bracket of twelve golden-section steps from the first grid)."""


PATTERN_ROUNDS = 2

"""Pattern searches (each followed by Levenberg–Marquardt when it helps) per fit."""


PATTERN = (0.5, 0.8, 0.9, 0.95, 0.98, 0.99, 1.01, 1.02, 1.05, 1.1, 1.25, 2.0)

"""Factors a fit's pattern search tries on each effect parameter."""


KEPT_POINTS = 16

"""Points whose Jacobian columns the engine keeps (:meth:`Engine.evaluate`)."""


SOLVE_COLUMNS = 16

"""A refit's solve has a multiple of this many columns (held ones pad the fitted): its step
compiles once, not once per number of fitted parameters."""


LM_STEPS = 30

"""Levenberg–Marquardt steps per refit (each one Jacobian)."""


LM_RTOL = 1e-8

"""A refit stops when an accepted step lowers the cost by less than this fraction (or on
optimistix's test with this ``rtol`` and ``atol``)."""

ZERO_SCALE = 1e-9
"""A start below this share of its box counts as zero: the fit scales the parameter by its box
(scaled by a round-off value, a two-sided parameter could not move)."""


ProfileRequest = tuple[np.ndarray, Sequence[int], int, Mapping[str, float]]

"""``(x, active, slot, guess)``: a slot's profile from the fit ``x`` of the ``active`` slots,
with the score test's estimate ``guess`` (:meth:`Engine.profile_starts`)."""


@dataclass
class Engine:
    """The universe over the records with the noise model; evaluates costs, Jacobians, fits.

    Every Jacobian of a run (score tests, each Levenberg–Marquardt step of each refit) comes
    from the one compiled forward-mode block (``jacobian_block``), its columns kept for the points
    last evaluated; the refits' bounded Levenberg–Marquardt
    (:func:`jaxflex.least_squares.bounded_least_squares_of`) is given its columns step by step.
    Coordinates: ``φ = log x`` for active log-scale parameters, else ``x``.
    """

    universe: Universe
    problem: Problem
    records: Dataset
    noise: dict[str, NoiseLevel]
    halfwidth: np.ndarray  # per element: quantisation half-step in units of σ (0: white)
    quantised: np.ndarray  # per element: bool
    tested: tuple[int, ...] = ()  # the candidates (universe indices) to test and add
    anchor: np.ndarray | None = None  # the run's starting point: where pinned parameters return
    centred: bool = False  # the anchor is a search's centre, not the fit itself: refit from it
    max_iterations: int = LM_STEPS
    weights: dict[str, float] = dataclasses.field(default_factory=dict)  # user channel weights
    record_start: tuple[str, int] = ("rest", DEFAULT_MODES)  # initial-state option, modes
    widened: set[str] = dataclasses.field(default_factory=set)  # bounds moved to their limit
    _columns: dict = dataclasses.field(default_factory=dict, repr=False)  # Jacobians kept

    @classmethod
    def build(cls, model: Model, candidates: Sequence[Candidate], records: Dataset,
              params: Mapping[str, float], noise: Noise | None, *,
              bounds: Mapping[str, tuple[float, float]] | None = None,
              fixed: Mapping[str, float] | None = None,
              weights: Mapping[str, float] | None = None,
              channels: Sequence[str] = OUTPUT_COLUMNS,
              anchor: Mapping[str, float] | None = None,
              record_start: tuple[str, int] = ("rest", DEFAULT_MODES)) -> Engine:
        """The engine testing ``candidates`` on ``model`` over the records' ``channels`` (the
        simulator outputs they measure); the channels' noise levels are the given ones, the
        others estimated from the residuals of ``params``
        (:func:`jaxflex.diagnosis.estimate_noise`). ``bounds``, ``fixed`` and ``weights`` are
        :func:`jaxflex.identification.identify`'s (:meth:`Universe.build`); a channel's weight
        ``w`` divides its noise level by ``√w`` (it counts ``w`` times in every fit and test),
        weight 0 leaves it out. ``anchor`` (default ``params``) is where a refit sends base
        parameters left on a bound (:meth:`_release_bounds`); a given one (a search's centre)
        also makes confirmations refit each candidate from there. ``record_start`` is where the
        records start, an initial-state option and its modes (:mod:`jaxflex.initial`): each
        record's state is estimated with the parameters in every fit and test.

        The universe holds every library effect (and the given candidates) whichever are
        tested, so that every call on the same model and record layout — score tests, a refit,
        an added effect, a discovery run — reuses one compiled Jacobian.
        """
        names = [c.name for c in candidates]
        universe = cls.make_universe(model, candidates, bounds, fixed, channels)
        pool = universe.candidates
        channels = tuple(channels)
        levels = noise_levels(noise, channels)
        if any(c not in levels for c in channels):
            x = universe.vector(params)
            preds = simulate_all(universe, x, records, record_start, channels)
            residuals = [{c: r.channel(c) - np.asarray(p.channel(c)) for c in channels}
                         for r, p in zip(records, preds, strict=True)]
            levels = estimate_noise(records, residuals, given=levels, channels=channels)
        for c, level in levels.items():
            if not (math.isfinite(level.sigma) and level.sigma > 0):
                raise ValueError(f"noise level of {c} must be positive, got {level.sigma!r}; "
                                 "give it with noise={...}")
        objective = build_objective(records, universe.model, channels=channels, weights=weights,
                                    fixed=universe.fixed, bounds=universe.bounds,
                                    initial_state=record_start[0],
                                    initial_modes=record_start[1])
        weights = dict(zip(objective.channels, map(float, objective.weights), strict=True))
        _, channel, _ = objective.layout()
        fitted = objective.channels
        sigma = np.array([levels[c].sigma / math.sqrt(weights[c]) for c in fitted])[channel]
        half = np.array([0.5 * levels[c].step / levels[c].sigma
                         if levels[c].kind == "quantised" else 0.0 for c in fitted])[channel]
        half = half * np.sqrt(np.array([weights[c] for c in fitted])[channel])
        measured = np.concatenate([np.asarray(m).reshape(-1) for m in objective.measured])
        problem = Problem(objective, jnp.asarray(measured / sigma), jnp.asarray(sigma))
        tested = tuple(i for i, c in enumerate(pool) if c.name in names)
        centred = anchor is not None
        anchor = universe.vector(params if anchor is None else anchor)
        anchor = np.clip(anchor, universe.space.lower, universe.space.upper)
        return cls(universe, problem, records, levels, half, half > 0, tested, anchor,
                   weights=weights, record_start=record_start, centred=centred)

    @staticmethod
    def make_universe(model: Model, candidates: Sequence[Candidate],
                 bounds: Mapping[str, tuple[float, float]] | None = None,
                 fixed: Mapping[str, float] | None = None,
                 channels: Sequence[str] | None = None) -> Universe:
        """The universe of ``model``, the default candidates for ``channels`` and
        ``candidates`` (bounds and fixed values validated and applied)."""
        names = [c.name for c in candidates]
        pool = [c for c in candidate_set(None, channels, model) if c.name not in names]
        pool += list(candidates)
        pool = sorted((c for c in pool if c.name not in model.effect_names),
                      key=lambda c: c.name)
        return Universe.build(model, pool, bounds, fixed)

    def candidate(self, name: str) -> int:
        """Universe index of a candidate by name."""
        return [c.name for c in self.universe.candidates].index(name)

    @property
    def n_samples(self) -> int:
        return int(self.halfwidth.size)

    @property
    def noise_cost(self) -> float:
        """Expected statistics cost of pure noise: one per white element (quantised residuals
        stay inside their band)."""
        return float(np.sum(~self.quantised))

    # --- evaluation ---------------------------------------------------------------------------
    def _coords(self, mask: np.ndarray) -> np.ndarray:
        return mask & self.universe.log

    def evaluate(self, x: np.ndarray, logflag: np.ndarray, cols: Sequence[int]):
        """(``ŷ/σ``, Jacobian columns ``∂(ŷ/σ)/∂φ`` for ``cols``) at ``x``.

        The columns are computed in ``x`` (a log coordinate's is ``x`` times it) and kept for
        the last :data:`KEPT_POINTS` points, so that the score tests, the profiles and a
        refit's first step at one point share them; the missing ones in blocks of
        :data:`BLOCK`."""
        x = np.asarray(x, dtype=float)
        key = x.tobytes()
        pred, known = self._columns.get(key, (None, {}))
        missing = [c for c in dict.fromkeys(int(c) for c in cols) if c not in known]
        if pred is None or missing:
            for start in range(0, max(len(missing), 1), BLOCK):
                chunk = missing[start:start + BLOCK]
                tangents = np.zeros((BLOCK, len(x)))
                tangents[np.arange(len(chunk)), chunk] = 1.0
                y, jt = jacobian_block(self.problem, jnp.asarray(x), jnp.asarray(tangents))
                pred = np.asarray(y)
                known = known | dict(zip(chunk, np.asarray(jt), strict=False))
        self._columns.pop(key, None)
        self._columns[key] = (pred, known)  # the most recent last
        while len(self._columns) > KEPT_POINTS:
            del self._columns[next(iter(self._columns))]
        scale = np.where(logflag, x, 1.0)
        return pred, (np.stack([known[int(c)] * scale[c] for c in cols], axis=1)
                      if len(cols) else np.zeros((pred.size, 0)))

    def whitened(self, pred: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(``u``, ``dz(u)``): the whitened residual and its part beyond quantisation."""
        u = np.asarray(self.problem.measured) - pred
        return u, np.sign(u) * np.maximum(np.abs(u) - self.halfwidth, 0.0)

    def stat_cost(self, pred: np.ndarray) -> float:
        """``C = Σ dz(u)²`` (:mod:`jaxflex.discovery`)."""
        return float(np.sum(self.whitened(pred)[1] ** 2))

    def fit_cost(self, pred: np.ndarray) -> float:
        u, dz = self.whitened(pred)
        return float(np.sum(dz**2) + INNER_WEIGHT * np.sum(u[self.quantised] ** 2))

    # --- fitting ------------------------------------------------------------------------------
    def fit(self, x0: np.ndarray, active: Sequence[int]) -> tuple[np.ndarray, float]:
        """Fit the base and ``active`` slot parameters from ``x0``; returns ``(x, C)``
        (:meth:`fit_many` of one)."""
        return self.fit_many([(x0, active)])[0]

    def fit_many(self, starts: Sequence[tuple[np.ndarray, Sequence[int]]]
                 ) -> list[tuple[np.ndarray, float]]:
        """Fit the base and ``active`` slot parameters from each ``(x0, active)``; ``(x, C)``
        of each.

        Levenberg–Marquardt, then a pattern search over each effect parameter (factors
        :data:`PATTERN`) and Levenberg–Marquardt again while that finds a lower cost: an effect
        may be piecewise smooth (a delay on a zero-order-hold grid has a kink at every
        sub-step), and a gradient method stops at a kink. Inactive candidates stay at their
        nulls. The fits' pattern trials run as one batch of simulations.
        """
        if not starts:
            return []
        u = self.universe
        actives = [list(active) for _, active in starts]
        xs = [self._lm(x0, active) for (x0, _), active in zip(starts, actives, strict=True)]
        effect_cols = [[i for s in active for i in u.index(u.slots[s].names)]
                       for active in actives]
        factors = np.asarray(PATTERN)
        pending = [k for k, cols in enumerate(effect_cols) if cols]
        for _ in range(PATTERN_ROUNDS):
            if not pending:
                break
            best = {k: xs[k] for k in pending}
            base_cost: dict[int, float] = {}
            best_cost: dict[int, float] = {}
            for j in range(max(len(effect_cols[k]) for k in pending)):
                members = [k for k in pending if j < len(effect_cols[k])]
                trials = []
                for k in members:  # the factors on one parameter of each fit
                    i = effect_cols[k][j]
                    trial = np.repeat(best[k][None], len(factors) + 1, axis=0)
                    trial[1:, i] = np.clip(best[k][i] * factors, u.space.lower[i],
                                           u.space.upper[i])
                    trials.append(trial)
                costs = self.forward_costs(np.concatenate(trials)).reshape(len(members), -1)
                for k, trial, cost in zip(members, trials, costs, strict=True):
                    base_cost.setdefault(k, float(cost[0]))
                    best[k], best_cost[k] = trial[int(np.argmin(cost))], float(np.min(cost))
            pending = [k for k in pending if best_cost[k] < base_cost[k] * (1 - LM_RTOL)]
            refits = [self._lm(best[k], actives[k]) for k in pending]
            for k, x in zip(pending, refits, strict=True):
                xs[k] = x
        xs = self._release_bounds(xs, actives)
        return [(x, self.stat_cost(pred))
                for x, pred in zip(xs, self.predicted_many(np.stack(xs)), strict=True)]

    def _release_bounds(self, xs: list[np.ndarray], actives: Sequence[Sequence[int]]
                        ) -> list[np.ndarray]:
        """Each fit refitted once more with its base parameters that ended on a bound put back
        at their start, kept where that lowers its cost.

        A parameter that compensated a missing effect (a viscous friction pushed to zero) can
        stay pinned on its bound after the effect is added: on the bound the gradient still
        points outwards, a local minimum of the constrained problem.
        """
        trials = {k: trial for k, (x, active) in enumerate(zip(xs, actives, strict=True))
                  if (trial := self.released(x, active)) is not None}
        if not trials:
            return xs
        keys = list(trials)
        refits = [self._lm(trials[k], actives[k]) for k in keys]
        costs = self.forward_costs(np.stack(refits + [xs[k] for k in keys]))
        out = list(xs)
        for n, (k, refit) in enumerate(zip(keys, refits, strict=True)):
            if costs[n] < costs[len(keys) + n]:
                out[k] = refit
        return out

    def released(self, x: np.ndarray, active: Sequence[int]) -> np.ndarray | None:
        """``x`` with its base parameters that lie on a bound put back at the anchor (``None``:
        none does, away from the anchor)."""
        if self.anchor is None:
            return None
        u = self.universe
        base = np.arange(u.n_base)
        unit = np.asarray(u.space.to_unit(u.space.from_vector(np.where(
            u.active_mask(active), x, u.space.lower))))[base]
        pinned = base[(unit <= 1e-9) | (unit >= 1 - 1e-9)]
        pinned = [i for i in pinned if not np.isclose(x[i], self.anchor[i])]
        if not pinned:
            return None
        trial = x.copy()
        trial[pinned] = self.anchor[pinned]
        return trial

    def forward_cost(self, x: np.ndarray) -> float:
        """The fit cost at ``x`` (its prediction kept by :meth:`evaluate`, else one run)."""
        cost = self.fit_cost(self.evaluate(x, np.zeros(len(x), bool), [])[0])
        return cost if math.isfinite(cost) else math.inf

    def predicted_many(self, xs: np.ndarray) -> np.ndarray:
        """``ŷ/σ`` at each row of ``xs``: batched simulations, :data:`MANY` at a time (a last
        short batch padded with its first row, so that one compiled size serves them all)."""
        xs = np.asarray(xs, dtype=float)
        out = []
        for start in range(0, len(xs), MANY):
            chunk = xs[start:start + MANY]
            padded = np.concatenate([chunk, np.repeat(chunk[:1], MANY - len(chunk), axis=0)])
            out.append(np.asarray(forward_many(self.problem, jnp.asarray(padded)))[: len(chunk)])
        return np.concatenate(out)

    def forward_costs(self, xs: np.ndarray) -> np.ndarray:
        """The fit costs at the rows of ``xs`` (:meth:`predicted_many`); non-finite → ``inf``."""
        costs = np.array([self.fit_cost(p) for p in self.predicted_many(xs)])
        return np.where(np.isfinite(costs), costs, np.inf)

    def _system(self, pred: np.ndarray, jac: np.ndarray | None):
        """Fit residual vector ``[dz(u), √ε·u_quantised]`` and its Jacobian (``None`` if
        ``jac`` is)."""
        uu, dz = self.whitened(pred)
        inner = math.sqrt(INNER_WEIGHT) * self.quantised
        r = np.concatenate([dz, inner * uu])
        if jac is None:
            return r, None
        outside = (np.abs(uu) > self.halfwidth).astype(float)
        return r, -np.concatenate([outside[:, None] * jac, inner[:, None] * jac])

    def _lm(self, x0: np.ndarray, active: Sequence[int]) -> np.ndarray:
        """Levenberg–Marquardt of the base and ``active`` parameters on the bounds
        (:func:`jaxflex.least_squares.bounded_least_squares_of`, on :meth:`_system`).

        The coordinates are the physical values over their starting magnitudes: in log
        coordinates a parameter pushed against a lower bound near zero (a friction term that
        compensated a missing effect) has a vanishing gradient and cannot come back. The
        fitted columns are padded with held ones (their Jacobian columns zero, not computed) to
        a multiple of :data:`SOLVE_COLUMNS`, so that one compiled solve serves every fit.
        """
        u = self.universe
        mask = u.active_mask(active)
        cols = np.flatnonzero(mask)
        x = np.where(mask, x0, u.null)
        x[cols] = np.clip(x[cols], u.space.lower[cols], u.space.upper[cols])
        # coordinates of order one; a two-sided parameter at zero (an offset) scales by its box,
        # also at a zero rounded off in the unit box (-0.05 + 0.5·0.1 is -7e-18, not 0)
        lower, upper = u.space.lower[cols], u.space.upper[cols]
        scale = np.maximum(np.abs(x[cols]), lower)
        scale = np.where(scale > ZERO_SCALE * (upper - lower), scale, upper - lower)
        size = min(-(-len(cols) // SOLVE_COLUMNS) * SOLVE_COLUMNS, len(x))
        held = np.flatnonzero(~mask)[: size - len(cols)]
        index = np.concatenate([cols, held])
        scales = np.concatenate([scale, np.ones(len(held))])
        p0 = x[index] / scales

        def system(p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
            xt = x.copy()
            xt[index] = p * scales
            pred, jac = self.evaluate(xt, np.zeros_like(mask), cols)
            return self._system(pred, np.pad(jac * scale, ((0, 0), (0, len(held)))))

        fit = bounded_least_squares_of(
            system, 2 * self.n_samples, p0,
            np.concatenate([u.space.lower[cols] / scale, p0[len(cols):]]),
            np.concatenate([u.space.upper[cols] / scale, p0[len(cols):]]),
            free=np.arange(len(index)) < len(cols), rtol=LM_RTOL, atol=LM_RTOL, ftol=LM_RTOL,
            max_steps=self.max_iterations, marquardt=True, secant=True,
        )
        if fit.cost < fit.cost_start:  # else x keeps its exact start values
            x[cols] = fit.value[: len(cols)] * scale
        return x

    def profile_starts(self, requests: Sequence[ProfileRequest]) -> list[tuple[np.ndarray, float]]:
        """Start values of a new slot's parameters (the others kept at ``x``) and the profiled
        cost there, for each ``(x, active, slot, guess)`` of ``requests``.

        A profile along the diagonal of the new parameters' unit box (a grid and the score
        test's one-step estimate), then grids ever finer around the lowest point until its
        neighbours are :data:`PROFILE_WIDTH` apart, of the cost with the fitted parameters
        re-optimised to first order: the residual is projected off the span of their Jacobian
        at ``x``. Without that, parameters that compensated the missing effect would pull its
        start towards the null. Every profile's points of one level are one batched call
        (:meth:`predicted_many`); each profile's result is the one it gives alone.
        """
        bases: dict[tuple, np.ndarray] = {}
        profiles = [_Profile.of(self, request, bases) for request in requests]
        pending, grids = profiles, [p.grid() for p in profiles]
        while pending:
            for profile, grid, costs in zip(pending, grids, self._profiled(pending, grids),
                                            strict=True):
                profile.add(grid, costs)
            pending = [p for p in profiles if p.width > PROFILE_WIDTH]
            grids = [p.finer(PROFILE_REFINED) for p in pending]
        return [p.best() for p in profiles]

    def _profiled(self, profiles: Sequence[_Profile], grids: Sequence[np.ndarray]
                  ) -> list[np.ndarray]:
        """The projected costs of each profile at its grid points, in one batched call."""
        preds = self.predicted_many(np.concatenate([p.at(g) for p, g in
                                                    zip(profiles, grids, strict=True)]))
        costs, at = [], 0
        for profile, grid in zip(profiles, grids, strict=True):
            costs.append(profile.projected(np.stack(
                [self._system(p, None)[0] for p in preds[at:at + len(grid)]])))
            at += len(grid)
        return costs

    def start(self, x: np.ndarray, active: Sequence[int], candidate: int,
              guess: Mapping[str, float], with_cost: bool = False):
        """The slot and start of a candidate (and the profiled cost there): for a profiled
        candidate the member whose profile (:meth:`profile_starts`) reaches the lowest cost."""
        return self.starts([(x, active, candidate, guess)], with_cost)[0]

    def starts(self, requests: Sequence[tuple[np.ndarray, Sequence[int], int,
                                              Mapping[str, float]]],
               with_cost: bool = False) -> list[tuple]:
        """:meth:`start` of each ``(x, active, candidate, guess)``, every member of every
        candidate profiled side by side."""
        u = self.universe
        members = [[i for i, s in enumerate(u.slots) if s.candidate == candidate]
                   for _, _, candidate, _ in requests]
        found = iter(self.profile_starts([(x, active, i, guess)
                                          for (x, active, _, guess), slots
                                          in zip(requests, members, strict=True)
                                          for i in slots]))
        out = []
        for slots in members:
            (x_start, profiled), slot = min(((next(found), i) for i in slots),
                                            key=lambda item: item[0][1])
            out.append((slot, x_start, profiled) if with_cost else (slot, x_start))
        return out

    def predictions(self, x: np.ndarray, records: Dataset) -> tuple[Outputs, ...]:
        return simulate_all(self.universe, x, records, self.record_start,
                            self.problem.objective.channels)

    def predictions_many(self, xs: Sequence[np.ndarray], records: Dataset
                         ) -> list[tuple[Outputs, ...]]:
        """:meth:`predictions` at each of ``xs``: from rest, each record's runs are one batched
        simulation (rows padded to a multiple of :data:`jaxflex.parallel.LANES`, so that few
        sizes compile); from an estimated state, one run after another."""
        if self.record_start[0] != "rest" or len(xs) < 2:
            return [self.predictions(x, records) for x in xs]
        u = self.universe
        params = [{**u.fixed, **dict(zip(u.space.names, map(float, x), strict=True))}
                  for x in xs]
        rows = len(params) + (-len(params) % LANES)
        stacked = {k: np.array([p[k] for p in params] + [params[0][k]] * (rows - len(params)))
                   for k in params[0]}
        runs = [simulate_batch(u.model, stacked, r.input, r.dt) for r in records]
        return [tuple(calibrated(u.model, p, jax.tree.map(lambda a, i=i: a[i], run))
                      for run in runs) for i, p in enumerate(params)]

    def prediction_cost(self, predictions: Sequence[Outputs]) -> float:
        """``C`` of any predictions of the records (e.g. of another model)."""
        cost = 0.0
        for record, pred in zip(self.records, predictions, strict=True):
            for c, w in self.weights.items():
                level = self.noise[c]
                u = (record.channel(c) - np.asarray(pred.channel(c))) / level.sigma
                if level.kind == "quantised":
                    u = np.maximum(np.abs(u) - 0.5 * level.step / level.sigma, 0.0)
                cost += w * float(u @ u)
        return cost

    def discovery_fit(self, x: np.ndarray, active: Sequence[int], cost: float) -> DiscoveryFit:
        u = self.universe
        intervals, covariance = self.intervals(x, active)
        return DiscoveryFit(
            model=u.model_of(active),
            params=u.params(x, active),
            cost=cost,
            n_params=int(u.active_mask(active).sum()),
            n_samples=self.n_samples,
            noise=self.noise,
            intervals=intervals,
            covariance=covariance,
            objective_cost=self.objective_cost(x),
        )

    def objective_cost(self, x: np.ndarray) -> float:
        """The identification objective at ``x`` (:mod:`jaxflex.objective`: the weighted mean
        of the squared NRMSE over records and channels, a fraction), so that the fit's cost
        means what a fit file's ``cost`` means."""
        pred, _ = self.evaluate(x, np.zeros(len(x), bool), ())
        scale = self.problem.objective.layout()[2]
        e = scale * np.asarray(self.problem.sigma) * (pred - np.asarray(self.problem.measured))
        return float(e @ e)

    def intervals(self, x: np.ndarray, active: Sequence[int], level: float = 0.95
                  ) -> tuple[dict[str, tuple[float, float]], np.ndarray]:
        """Gauss–Newton ``level`` intervals of the fitted parameters at ``x`` (own names) and
        their covariance (physical units, rows in the intervals' order): the residuals are
        whitened by the stated noise levels, so the covariance is ``(JᵀJ)⁻¹`` of the fit's own
        system; a parameter the records do not determine gets ``(-inf, inf)``."""
        u = self.universe
        cols = np.flatnonzero(u.active_mask(active))
        pred, jac = self.evaluate(x, np.zeros(len(x), bool), cols)
        jac = self._system(pred, jac)[1]
        if not np.all(np.isfinite(jac)):
            return {}, np.full((0, 0), np.nan)
        norms = np.linalg.norm(jac, axis=0)
        scaled = jac / np.where(norms > 0, norms, 1.0)
        inverse = np.divide(1.0, norms, out=np.full_like(norms, np.nan), where=norms > 0)
        cov = np.linalg.pinv(scaled.T @ scaled, rcond=1e-12, hermitian=True)
        cov = cov * np.outer(inverse, inverse)
        var = np.diag(cov)
        half = stats.norm.ppf(0.5 + 0.5 * level) * np.sqrt(np.where(var > 0, var, np.inf))
        half = np.where(np.isfinite(half), half, np.inf)
        lo, hi = x.copy(), x.copy()
        lo[cols], hi[cols] = x[cols] - half, x[cols] + half
        lower, upper = u.params(lo, active), u.params(hi, active)
        intervals = {n: (lower[n], upper[n]) for n in upper if n not in u.fixed}
        own = {v: o for s in active
               for v, o in zip(u.slots[s].names, u.slots[s].own_names, strict=True)}
        names = [own.get(u.space.names[c], u.space.names[c]) for c in cols]
        order = [names.index(n) for n in intervals]
        return intervals, cov[np.ix_(order, order)]

    # --- score tests --------------------------------------------------------------------------
    def score_tests(self, x: np.ndarray, active: Sequence[int], alpha: float,
                    skip: Iterable[int] = ()) -> list[ScoreResult]:
        """Score tests of every candidate not in ``skip`` from one Jacobian at ``x``."""
        u = self.universe
        mask = u.active_mask(active)
        skip = (set(skip) | {u.slots[s].candidate for s in active}
                | set(range(len(u.candidates))) - set(self.tested))
        slots = [s for s, slot in enumerate(u.slots) if slot.candidate not in skip]
        # parameters held on a bound are fixed, not free nuisance: partialling them out would
        # hand their unexplained pull to the projection
        unit = np.asarray(u.space.to_unit(u.space.from_vector(np.where(mask, x, u.space.lower))))
        on_bound = (unit <= 1e-9) | (unit >= 1 - 1e-9)
        nuisance = list(np.flatnonzero(mask & ~on_bound))
        tested = [int(i) for s in slots for i in u.index(u.slots[s].tested)]
        pred, jac = self.evaluate(x, self._coords(mask), nuisance + tested)
        _, r = self.whitened(pred)
        jn = jac[:, : len(nuisance)]
        columns = dict(zip(tested, jac[:, len(nuisance):].T, strict=True))
        q = _span(jn)

        families: dict[int, list[ScoreResult]] = {}
        for s in slots:
            slot = u.slots[s]
            cand = u.candidates[slot.candidate]
            jc = np.stack([columns[int(i)] for i in u.index(slot.tested)], axis=1)
            jc = jc - q @ (q.T @ jc)
            families.setdefault(slot.candidate, []).append(
                score_statistic(cand, slot, [u.space[n] for n in slot.tested], jc.T @ r,
                                jc.T @ jc)
            )
        m = max(len(families), 1)
        results = []
        for members in families.values():
            best = max(members, key=lambda t: (t.statistic - t.dof, -t.p_value))
            p = min(1.0, best.p_value * best.profile)
            results.append(dataclasses.replace(best, p_value=p, significant=p < alpha / m))
        results.sort(key=lambda t: (t.p_value, -(t.statistic - t.dof)))
        return results


def _span(jac: np.ndarray) -> np.ndarray:
    """Orthonormal columns spanning ``jac``'s columns (scaled to unit norm first; columns that
    add no direction dropped)."""
    norms = np.linalg.norm(jac, axis=0)
    q, rr = np.linalg.qr(jac / np.where(norms > 0, norms, 1.0))
    return q[:, np.abs(np.diag(rr)) > 1e-10]


@dataclass
class _Profile:
    """One profile of :meth:`Engine.profile_starts`: a slot's parameters along the diagonal of
    their unit box (``t`` from 0 to 1), the others kept at ``x``; the points tried so far and
    their costs with the fitted parameters' first-order response projected out (``basis``)."""

    x: np.ndarray
    index: np.ndarray  # the slot's tested parameters in x
    space: ParameterSpace  # theirs
    basis: np.ndarray  # orthonormal columns spanning the fitted parameters' Jacobian at x
    estimate: float | None  # the score test's one-step estimate on the diagonal
    ts: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(0))
    costs: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(0))

    @classmethod
    def of(cls, engine: Engine, request: ProfileRequest, bases: dict) -> _Profile:
        """The profile of ``request``; the fitted parameters' basis shared through ``bases``
        by the profiles from the same fit."""
        x, active, slot, guess = request
        u = engine.universe
        key = (x.tobytes(), tuple(active))
        if key not in bases:
            pred, jac = engine.evaluate(x, np.zeros(len(x), bool),
                                        np.flatnonzero(u.active_mask(active)))
            bases[key] = _span(engine._system(pred, jac)[1])
        space = ParameterSpace([u.space[n] for n in u.slots[slot].tested])
        est = np.array([guess.get(o, np.nan) for o in u.slots[slot].tested_own])
        inside = np.all(np.isfinite(est)) and np.all(est > space.lower) and np.all(
            est < space.upper)
        estimate = (float(np.mean(np.asarray(space.to_unit(space.from_vector(est)))))
                    if inside else None)
        return cls(x, u.index(u.slots[slot].tested), space, bases[key], estimate)

    def grid(self) -> np.ndarray:
        """The first points: :data:`PROFILE_POINTS` evenly spaced and the estimate."""
        grid = np.linspace(0.0, 1.0, PROFILE_POINTS)
        return grid if self.estimate is None else np.sort(np.append(grid, self.estimate))

    def at(self, ts: np.ndarray) -> np.ndarray:
        """Universe vectors at the diagonal points ``ts``."""
        xs = np.repeat(self.x[None], len(ts), axis=0)
        units = np.repeat(np.asarray(ts, dtype=float)[:, None], len(self.index), axis=1)
        xs[:, self.index] = np.asarray(self.space.to_vector(self.space.from_unit(units)))
        return xs

    def projected(self, r: np.ndarray) -> np.ndarray:
        """Costs of the residual rows ``r`` off the fitted parameters' span; non-finite → inf."""
        r = r - (r @ self.basis) @ self.basis.T
        costs = np.einsum("...i,...i->...", r, r)
        return np.where(np.isfinite(costs), costs, np.inf)

    def add(self, ts: np.ndarray, costs: np.ndarray) -> None:
        """Points tried and their costs, kept in the order of ``t``."""
        order = np.argsort(np.concatenate([self.ts, ts]), kind="stable")
        self.ts = np.concatenate([self.ts, ts])[order]
        self.costs = np.concatenate([self.costs, costs])[order]

    @property
    def bracket(self) -> tuple[float, float]:
        """The neighbours of the lowest point tried."""
        k = int(np.argmin(self.costs))
        return float(self.ts[max(k - 1, 0)]), float(self.ts[min(k + 1, len(self.ts) - 1)])

    @property
    def width(self) -> float:
        lo, hi = self.bracket
        return hi - lo

    def finer(self, points: int) -> np.ndarray:
        """``points`` evenly spaced inside the bracket."""
        return np.linspace(*self.bracket, points + 2)[1:-1]

    def best(self) -> tuple[np.ndarray, float]:
        """The lowest point tried (universe vector) and its cost."""
        k = int(np.argmin(self.costs))
        return self.at(self.ts[k:k + 1])[0], float(self.costs[k])


def simulate_all(universe: Universe, x: np.ndarray, records: Dataset,
                 record_start: tuple[str, int] = ("rest", DEFAULT_MODES),
                 channels: Sequence[str] = OUTPUT_COLUMNS) -> tuple[Outputs, ...]:
    """The universe model's readings of ``records`` at ``x``, each from where it starts."""
    params = {**universe.fixed, **dict(zip(universe.space.names, map(float, x), strict=True))}
    return simulate_started(universe.model, params, records, channels, *record_start)

