"""Find what the model is missing: score tests of candidate effects, add-and-refit, discovery.

The discovery likelihood
    Residuals are whitened per channel by the measurement noise, ``u = (y − ŷ)/σ_c``. The
    accelerometer's noise is white, so its residuals enter as they are. An encoder's
    quantisation error is bounded by ``±q/2`` but constant while the arm rests, so treating it as
    white noise would read a resting arm's rounding error as overwhelming evidence; a quantised
    channel therefore enters through the part of the residual beyond the quantisation bound,
    ``dz(u) = sign(u)·max(|u| − h, 0)`` with ``h = q/(2σ) = √3``. The statistics cost is
    ``C(θ) = Σ dz(u)²`` (white channels: ``dz(u) = u``), i.e. ``−2 log L`` up to a constant with
    the noise levels fixed (estimated once, at the start). Fits minimise ``C`` plus a small
    ``ε·Σ u²`` over the quantised samples, which keeps the angle on the measured counts.

Score (Lagrange-multiplier) test
    Every candidate effect vanishes at its null parameters, so the model *with* the effect at
    its null is the fitted model, and the gradient of ``C`` with respect to the effect's
    parameters there says whether switching it on would help — before fitting it. With the
    whitened Jacobian ``J = [J_n, J_c]`` (``n``: the fitted parameters, ``c``: the candidate's)
    and residual ``r``, partialling the nuisance parameters out (``P_n`` projects on ``J_n``;
    fitted parameters held on a bound are fixed, not nuisance):

        ``J_c⊥ = (I − P_n) J_c``,  ``g = J_c⊥ᵀ r``,  ``V = J_c⊥ᵀ J_c⊥``,  ``S = gᵀ V⁻¹ g``,

    which is ``gᵀ (I⁻¹)_cc g`` with the Gauss–Newton information ``I = JᵀJ`` (noise-whitened) —
    the drop of ``C`` one Gauss–Newton step on the candidate would give. ``S ~ χ²_k`` under the
    null. The library's nulls lie on a boundary (a mass, a delay cannot be negative): for one
    parameter the test is one-sided, ``S = max(z, 0)²`` with ``z = g/√V`` and ``p = ½ P(χ²₁ > S)``
    (the 50:50 χ̄² mixture); with several, ``χ²_k`` of the unconstrained ``S`` (valid, somewhat
    conservative). ``β̂ = V⁻¹ g`` estimates the effect's size. The quantised channel enters ``J``
    with all its samples (as if its noise were white with ``σ = q/√12``), which is conservative.
    All candidates share one Jacobian: the model is extended by every candidate at once (at
    their nulls it is still the fitted model), one forward-mode pass gives every column. That
    extended model always holds the whole library, so every call on the same records — score
    tests, refits, a discovery run — reuses one compiled function.

    A Stribeck velocity ``v_s`` is undefined under the null (``Δτ_s = 0`` switches every ``v_s``
    off): the test profiles it over :meth:`~jaxflex.effects.Stribeck.grid` — a score statistic
    per grid value, the largest kept, its p-value multiplied by the grid size (Bonferroni).
    Any effect class with a ``grid()`` is profiled the same way.

The loop (:func:`discover`)
    Fit the base model; then repeat: diagnose the residuals (:mod:`jaxflex.diagnosis`), score-test
    every candidate not yet in the model (significant at ``alpha/m``, Bonferroni over the ``m``
    candidates), refit the best few (warm start, a 1-D profile of the new parameters, then
    Levenberg–Marquardt of all), confirm each by the likelihood-ratio test ``LR = C₀ − C₁`` at
    ``alpha/m`` and a falling BIC (``C + d·ln N``), and add the one with the largest LR. The
    score test is local: when the misfit is too large for a first-order picture and no score is
    significant while the residuals are not noise, each candidate's 1-D profile (the fitted
    parameters re-optimised to first order) is scanned instead. Ties are real: a delay and a
    first-order lag have the same derivative at their null; the refits tell them apart. Stop when
    no candidate is significant and confirmed. An effect is kept only if the final residuals
    are consistent with the noise or it explained most (:data:`MIN_EXPLAINED`) of the misfit
    above the noise when it was added; otherwise it is withdrawn, and whatever the residuals
    still hold is reported as ``unexplained`` — where in time and frequency, and how large.
"""

from __future__ import annotations

import dataclasses
import math
import os
import time
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float

from jaxflex._io import provenance, to_jsonable
from jaxflex._progress import Progress
from jaxflex.compare import DEFAULT_T_END, FRFSettings, _compare_record
from jaxflex.data import Dataset, Record
from jaxflex.diagnosis import (
    Diagnosis,
    Noise,
    NoiseLevel,
    chi2_sf,
    diagnose,
    estimate_noise,
    noise_levels,
)
from jaxflex.diagnosis.noise import CHANNELS, UNITS
from jaxflex.effects import Effect, get_effect, library
from jaxflex.effects._base import Structure
from jaxflex.model import Model
from jaxflex.objective import Objective, as_dataset, build_objective
from jaxflex.parameters import ParameterSpace, ParameterSpec, Params
from jaxflex.simulate import Outputs, simulate

ALPHA = 0.01
"""Default family-wise significance level of each step (Bonferroni over the candidates)."""
INNER_WEIGHT = 1e-2
"""``ε``: weight of quantised residuals inside the quantisation band in fits (not in tests)."""
MIN_EXPLAINED = 0.9
"""An effect that leaves structure behind is kept only if it removed this share of the misfit."""
MAX_CONFIRM = 3
"""Candidates refitted per step to confirm the score ranking."""
PROFILE_POINTS = 13
"""Start values of a new effect's parameters tried before the refit (unit-box diagonal)."""
GOLDEN_STEPS = 12
"""Golden-section steps refining the best start value."""
PATTERN_ROUNDS = 2
"""Pattern searches (each followed by Levenberg–Marquardt when it helps) per fit."""
PATTERN = (0.5, 0.8, 0.9, 0.95, 0.98, 0.99, 1.01, 1.02, 1.05, 1.1, 1.25, 2.0)
"""Factors a fit's pattern search tries on each effect parameter."""
BUDGET = (60, 40)
"""(generations, population) of the differential evolution that identifies the base model from
scratch: a reduced budget (the paper: 100 × 100) — seeded around the rigid-body estimate and
refined by Levenberg–Marquardt, the search only has to find the right basin."""
FAST_BUDGET = (15, 20)
"""The budget under ``JAXFLEX_FAST=1`` (tests, notebooks)."""
LM_STEPS = 30
"""Levenberg–Marquardt steps per refit (each one Jacobian)."""
LM_RTOL = 1e-8
"""A refit stops when an accepted step lowers the cost by less than this fraction."""
BOUND_TOL = 1e-3
"""A refit effect whose parameters all end this close (unit box) to their null-side bound is
not confirmed: the fit used it only to polish the others."""
CONFIRM_RATIO = 0.1
"""Candidates are refitted to confirm them if their score reaches this fraction of the best."""


# --- candidates ----------------------------------------------------------------------------------


class _Variant(Effect):
    """An effect under a suffixed name with suffixed parameters, so that several settings of one
    effect (e.g. Stribeck velocities) can sit side by side in one model."""

    inner: Effect
    suffix: str = eqx.field(static=True)

    @property
    def name(self) -> str:  # type: ignore[override]
        return f"{self.inner.name}{self.suffix}"

    @property
    def parameters(self) -> tuple[ParameterSpec, ...]:  # type: ignore[override]
        return tuple(
            dataclasses.replace(p, name=p.name + self.suffix) for p in self.inner.parameters
        )

    def _own(self, params: Params) -> Params:
        return {**params, **{p.name: params[p.name + self.suffix] for p in self.inner.parameters}}

    def structure(self, structure: Structure, params: Params) -> Structure:
        return self.inner.structure(structure, self._own(params))

    def friction(self, params: Params, velocity: Array, omega_s: float) -> Array:
        return self.inner.friction(self._own(params), velocity, omega_s)

    def loads(self, structure: Structure, params: Params) -> Array:
        return self.inner.loads(structure, self._own(params))

    def load_amplitudes(self, params: Params, angle: Array, velocity: Array) -> Array:
        return self.inner.load_amplitudes(self._own(params), angle, velocity)

    def input_torque(self, params: Params, torque: Array, h: float) -> Array:
        return self.inner.input_torque(self._own(params), torque, h)


@dataclass(frozen=True)
class Candidate:
    """A candidate effect: one instance, or a profile of instances over a static setting."""

    name: str
    effects: tuple[Effect, ...]

    @property
    def parameters(self) -> tuple[ParameterSpec, ...]:
        return tuple(self.effects[0].parameters)

    def label(self, i: int) -> str:
        """The setting of profile member ``i`` (e.g. ``"v_s=0.1"``), '' for a single effect."""
        if len(self.effects) == 1:
            return ""
        member = self.effects[i]
        parts = []
        for f in dataclasses.fields(member):
            value = getattr(member, f.name)
            varies = len({repr(getattr(e, f.name)) for e in self.effects}) > 1
            if varies and isinstance(value, (int, float, str)):
                parts.append(f"{f.name}={value:g}" if isinstance(value, float) else
                             f"{f.name}={value}")
        return ", ".join(parts)


def _parameter_names(candidate: Candidate) -> tuple[str, ...]:
    """The parameter names of a candidate."""
    return tuple(p.name for p in candidate.parameters)


def _candidate(item: str | Effect | Candidate) -> Candidate:
    """A candidate from a name (profiled if its class has ``grid()``), an effect or itself."""
    if isinstance(item, Candidate):
        cand = item
    elif isinstance(item, str):
        effect = get_effect(item)
        grid = getattr(type(effect), "grid", None)
        cand = Candidate(item, tuple(grid()) if callable(grid) else (effect,))
    elif isinstance(item, Effect):
        cand = Candidate(item.name, (item,))
    else:
        raise TypeError(f"a candidate must be an effect name or Effect, got {type(item).__name__}")
    for spec in cand.parameters:
        if spec.null is None:
            raise ValueError(
                f"candidate {cand.name!r}: parameter {spec.name} has no null value (the value "
                "at which the effect vanishes); a score test needs one"
            )
    if not cand.parameters:
        raise ValueError(f"candidate {cand.name!r} has no parameters to test")
    return cand


def candidate_set(
    candidates: Iterable[str | Effect | Candidate] | None = None,
) -> tuple[Candidate, ...]:
    """Candidates by name or instance; ``None``: every library effect (Stribeck profiled)."""
    if candidates is None:
        candidates = [e.name for e in library()]
    elif isinstance(candidates, (str, Effect)):
        candidates = [candidates]
    result = tuple(_candidate(c) for c in candidates)
    names = [c.name for c in result]
    if len(set(names)) != len(names):
        raise ValueError(f"a candidate appears twice: {names}")
    if not result:
        raise ValueError("no candidate effects given")
    return result


# --- the universe: the model with every candidate at its null ------------------------------------


@dataclass(frozen=True)
class _Slot:
    """One candidate profile member inside the universe model."""

    candidate: int
    member: int
    effect: Effect  # the original effect
    names: tuple[str, ...]  # its parameter names in the universe
    own_names: tuple[str, ...]  # its own parameter names


@dataclass(frozen=True)
class _Universe:
    model: Model  # the starting model followed by every candidate member
    base: Model  # the starting model
    candidates: tuple[Candidate, ...]
    slots: tuple[_Slot, ...]
    space: ParameterSpace
    null: np.ndarray  # null of each candidate parameter (0 for the base ones, unused)
    log: np.ndarray  # log-scale flag per parameter

    @classmethod
    def build(cls, base: Model, candidates: Sequence[Candidate]) -> _Universe:
        members, slots = [], []
        for i, cand in enumerate(candidates):
            if cand.name in base.effect_names:
                raise ValueError(f"candidate {cand.name!r} is already in the model")
            for j, effect in enumerate(cand.effects):
                variant = _Variant(effect, f"__{i}_{j}")
                members.append(variant)
                slots.append(_Slot(i, j, effect, tuple(p.name for p in variant.parameters),
                                   tuple(p.name for p in effect.parameters)))
        model = base.with_effects(*members)
        space = model.space
        null = np.array([0.0 if s.null is None else s.null for s in space.specs])
        log = np.array([s.log_scale for s in space.specs])
        return cls(model, base, tuple(candidates), tuple(slots), space, null, log)

    @property
    def n_base(self) -> int:
        return len(self.base.space)

    def index(self, names: Iterable[str]) -> np.ndarray:
        return np.array([self.space.names.index(n) for n in names], dtype=int)

    def vector(self, params: Mapping[str, ArrayLike], active: Sequence[int] = ()) -> np.ndarray:
        """Universe vector: the base parameters and active slots from ``params`` (own names),
        every other candidate parameter at its null."""
        x = self.null.copy()
        for k, n in enumerate(self.base.space.names):
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
        """Own-named parameters of the base and the active slots."""
        out = {n: float(x[k]) for k, n in enumerate(self.base.space.names)}
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


class _Problem(eqx.Module):
    """Whitened predictions of the universe model over the records (module docstring)."""

    objective: Objective
    measured: Float[Array, " N"]  # y/σ, in the objective's element order

    sigma: Float[Array, " N"]

    def predicted(self, x: Float[Array, " d"]) -> Float[Array, " N"]:
        """``ŷ/σ`` for the universe parameter vector ``x``."""
        sims = self.objective.simulate(self.objective.space.from_vector(x))
        return jnp.concatenate([s.reshape(-1) for s in sims]) / self.sigma


def _block_impl(problem: _Problem, phi, logflag, tangents):
    """Predictions at ``phi`` and their derivatives along ``BLOCK`` tangents (forward mode).

    ``x = exp(φ)`` where ``logflag``, else ``x = φ``. One compiled function serves every
    Jacobian of a run (score tests and every refit): the tangents select the columns.
    """

    def pred(p):
        return problem.predicted(jnp.where(logflag, jnp.exp(p), p))

    return jax.vmap(lambda t: jax.jvp(pred, (phi,), (t,)), out_axes=(None, 0))(tangents)


_block = eqx.filter_jit(_block_impl)
_forward = eqx.filter_jit(lambda problem, x: problem.predicted(x))
BLOCK = 8
"""Tangent columns per forward-mode pass."""


# --- results -------------------------------------------------------------------------------------


@dataclass(frozen=True)
class ScoreResult:
    """The score test of one candidate at the current fit.

    ``statistic`` is ``S`` (one-sided tests: ``max(z, 0)²``), ``p_value`` its p-value after the
    profile correction (``profile`` members × the best member's), ``estimate`` the one-step
    estimate ``β̂`` of the candidate's parameters (physical units, from the null) and ``setting``
    the profile member it came from (e.g. ``"v_s=0.1"``). ``profile_drop`` and its p-value are
    set when the loop scanned the candidate's nonlinear profile (see :func:`_profile_scan`).
    """

    effect: str
    parameters: tuple[str, ...]
    statistic: float
    dof: int
    p_value: float
    one_sided: bool
    z: float | None
    estimate: dict[str, float]
    units: dict[str, str]
    setting: str = ""
    profile: int = 1
    significant: bool = False
    member: int = 0
    explanation: str = ""
    profile_drop: float | None = None
    profile_p_value: float | None = None

    def to_dict(self) -> dict[str, Any]:
        return {
            "effect": self.effect,
            "statistic": self.statistic,
            "p_value": self.p_value,
            "dof": self.dof,
            "one_sided": self.one_sided,
            "estimate": self.estimate,
            "setting": self.setting or None,
            "significant": self.significant,
            "profile_drop": self.profile_drop,
            "profile_p_value": self.profile_p_value,
            "explanation": self.explanation,
        }


@dataclass(frozen=True)
class DiscoveryFit:
    """A fitted model structure: the model, its parameters and the discovery-likelihood cost.

    ``cost`` is ``C`` of the module docstring (``−2 log L`` up to a constant), ``bic`` is
    ``C + n_params·ln(n_samples)``.
    """

    model: Model | None  # None for the rigid-body rung of the ladder
    params: dict[str, float]
    cost: float
    n_params: int
    n_samples: int
    noise: dict[str, NoiseLevel]

    @property
    def effects(self) -> tuple[str, ...]:
        return () if self.model is None else self.model.effect_names

    @property
    def bic(self) -> float:
        return self.cost + self.n_params * math.log(self.n_samples)


@dataclass(frozen=True)
class Confirmation:
    """The refit of one candidate: its likelihood-ratio test and BIC change.

    ``lr = C₀ − C₁`` (the drop of ``−2 log L``), ``p_value`` its p-value (one parameter on a
    boundary: ``½ P(χ²₁ > lr)``), ``delta_bic`` the BIC change, ``explained`` the share of the
    misfit above the noise it removed; ``member`` the profile member refitted (``setting``).
    """

    effect: str
    lr: float
    p_value: float
    delta_bic: float
    explained: float
    confirmed: bool
    params: dict[str, float]
    member: int = 0
    setting: str = ""


@dataclass(frozen=True)
class Step:
    """One model structure of a discovery run and how well it fits."""

    added: str | None
    fit: DiscoveryFit
    nrmse: dict[str, float]  # percent, mean over records
    frf_nrmse: float  # percent, mean over records
    holdout: dict[str, dict[str, float]] | None
    diagnosis: Diagnosis | None
    ranking: tuple[ScoreResult, ...] = ()
    confirmations: tuple[Confirmation, ...] = ()
    lr: float | None = None
    p_value: float | None = None
    explained: float | None = None
    label: str = ""
    predictions: tuple[Outputs, ...] = field(default=(), repr=False)

    @property
    def effects(self) -> tuple[str, ...]:
        return self.fit.effects

    @property
    def bic(self) -> float:
        return self.fit.bic

    @property
    def structure(self) -> str:
        return self.label or (" + ".join(("base",) + self.effects))

    def to_dict(self) -> dict[str, Any]:
        return {
            "added": self.added,
            "structure": self.structure,
            "effects": list(self.effects),
            "params": dict(self.fit.params),
            "nrmse": dict(self.nrmse),
            "frf_nrmse": self.frf_nrmse,
            "holdout": self.holdout,
            "bic": self.bic,
            "cost": self.fit.cost,
            "n_params": self.fit.n_params,
            "lr": self.lr,
            "lr_p_value": self.p_value,
            "explained": self.explained,
        }


@dataclass(frozen=True)
class DiscoveryReport:
    """What :func:`discover` found: the steps, the ranking at each step, what is unexplained."""

    steps: tuple[Step, ...]
    unexplained: dict[str, Any] | None
    withdrawn: tuple[str, ...]
    alpha: float
    candidates: tuple[str, ...]
    records: Dataset
    holdout: Dataset | None
    settings: dict[str, Any]
    wall_time: float
    noise_floor: dict[str, float]

    @property
    def final(self) -> Step:
        return self.steps[-1]

    @property
    def base(self) -> Step:
        """The first flexible model (after the rigid-body rung, if any)."""
        return next(s for s in self.steps if s.label != "rigid")

    @property
    def model(self) -> Model:
        return self.final.fit.model

    @property
    def params(self) -> dict[str, float]:
        return self.final.fit.params

    @property
    def added(self) -> tuple[str, ...]:
        """Effects added, in order."""
        return tuple(s.added for s in self.steps if s.added)

    @property
    def noise(self) -> dict[str, NoiseLevel]:
        """The noise level each channel used (given or estimated; ``describe()`` says how)."""
        return self.final.fit.noise

    @property
    def rankings(self) -> tuple[tuple[ScoreResult, ...], ...]:
        return tuple(s.ranking for s in self.steps if s.ranking)

    def table(self) -> str:
        """The step table: structure → NRMSE per output, FRF NRMSE, held-out error, BIC."""
        head = ["step", "structure", "angle NRMSE %", "tip acc NRMSE %", "FRF NRMSE %",
                "held-out angle %", "held-out acc %", "BIC"]
        rows = []
        for i, s in enumerate(self.steps):
            ho = s.holdout["relative_error"] if s.holdout else None
            rows.append([
                str(i), s.structure, f"{s.nrmse['joint_angle']:.4g}",
                f"{s.nrmse['tip_acceleration']:.4g}", _fmt(s.frf_nrmse),
                _fmt(100 * ho["joint_angle"]) if ho else "-",
                _fmt(100 * ho["tip_acceleration"]) if ho else "-",
                f"{s.bic:.6g}" if math.isfinite(s.bic) else "-",
            ])
        widths = [max(len(r[k]) for r in rows + [head]) for k in range(len(head))]
        lines = ["  ".join(c.ljust(w) for c, w in zip(row, widths, strict=True)).rstrip()
                 for row in [head] + rows]
        floor = ", ".join(f"{k} {v:.3g} %" for k, v in self.noise_floor.items())
        lines.append(f"noise floor (NRMSE the measurement noise alone gives): {floor}")
        for channel, level in self.noise.items():
            lines.append(f"noise level {channel}: σ = {level.sigma:.4g} {UNITS[channel]} "
                         f"({level.describe()})")
        for s in self.steps:
            if s.ranking:
                top = ", ".join(
                    f"{r.effect} (S={r.statistic:.3g}, p={r.p_value:.2g}"
                    + (f", profile drop {r.profile_drop:.3g}" if r.profile_drop else "") + ")"
                    for r in s.ranking[:3])
                lines.append(f"after '{s.structure}': top candidates {top}")
        if self.withdrawn:
            lines.append(f"withdrawn (did not explain the misfit): {', '.join(self.withdrawn)}")
        if self.unexplained:
            lines.append(f"UNEXPLAINED: {self.unexplained['message']}")
        else:
            lines.append("residuals are consistent with the measurement noise")
        return "\n".join(lines) + "\n"

    def explanations(self) -> list[str]:
        """Plain-language explanation of every added effect and the top-ranked candidates."""
        lines = []
        for s in self.steps:
            for r in s.ranking[:3]:
                if r.explanation:
                    lines.append(r.explanation)
        return lines

    def to_dict(self) -> dict[str, Any]:
        """The JSON contract of ``jaxflex discover --json``."""
        return to_jsonable({
            "steps": [s.to_dict() for s in self.steps],
            "ranking": [[r.to_dict() for r in s.ranking] for s in self.steps if s.ranking],
            "unexplained": self.unexplained,
            "withdrawn": list(self.withdrawn),
            "noise_floor": self.noise_floor,
            "settings": self.settings,
            "wall_time_s": self.wall_time,
            "provenance": provenance(),
        })


def _fmt(x: float) -> str:
    return f"{x:.4g}" if x is not None and math.isfinite(x) else "-"


# --- the engine: one compiled Jacobian for the whole run ----------------------------------------


@dataclass
class _Engine:
    """The universe over the records with the noise model; evaluates costs, Jacobians, fits.

    Every Jacobian of a run (score tests, each Levenberg–Marquardt step of each refit) comes
    from the one compiled forward-mode block :func:`_block_impl`; fits run their (tiny) normal
    equations in NumPy. Coordinates: ``φ = log x`` for active log-scale parameters, else ``x``.
    """

    universe: _Universe
    problem: _Problem
    records: Dataset
    noise: dict[str, NoiseLevel]
    halfwidth: np.ndarray  # per element: quantisation half-step in units of σ (0: white)
    quantised: np.ndarray  # per element: bool
    tested: tuple[int, ...] = ()  # the candidates (universe indices) to test and add
    anchor: np.ndarray | None = None  # the run's starting point: where pinned parameters return
    max_iterations: int = LM_STEPS

    @classmethod
    def build(cls, model: Model, candidates: Sequence[Candidate], records: Dataset,
              params: Mapping[str, float], noise: Noise | None) -> _Engine:
        """The engine testing ``candidates`` on ``model``; the channels' noise levels are the
        given ones, the others estimated from the residuals of ``params``
        (:func:`jaxflex.diagnosis.estimate_noise`).

        The universe holds every library effect (and the given candidates) whichever are
        tested, so that every call on the same model and record layout — score tests, a refit,
        an added effect, a discovery run — reuses one compiled Jacobian.
        """
        names = [c.name for c in candidates]
        pool = [c for c in candidate_set() if c.name not in names] + list(candidates)
        pool = sorted((c for c in pool if c.name not in model.effect_names),
                      key=lambda c: c.name)
        universe = _Universe.build(model, pool)
        levels = noise_levels(noise)
        if any(c not in levels for c in CHANNELS):
            x = universe.vector(params)
            preds = _simulate_all(universe, x, records)
            residuals = [{c: r.channel(c) - np.asarray(p.channel(c)) for c in CHANNELS}
                         for r, p in zip(records, preds, strict=True)]
            levels = estimate_noise(records, residuals, given=levels)
        for c, level in levels.items():
            if not (math.isfinite(level.sigma) and level.sigma > 0):
                raise ValueError(f"noise level of {c} must be positive, got {level.sigma!r}; "
                                 "give it with noise={...}")
        objective = build_objective(records, universe.model, channels=CHANNELS)
        _, channel, _ = objective.layout()
        sigma = np.array([levels[c].sigma for c in CHANNELS])[channel]
        half = np.array([0.5 * levels[c].step / levels[c].sigma
                         if levels[c].kind == "quantised" else 0.0 for c in CHANNELS])[channel]
        measured = np.concatenate([np.asarray(m).reshape(-1) for m in objective.measured])
        problem = _Problem(objective, jnp.asarray(measured / sigma), jnp.asarray(sigma))
        tested = tuple(i for i, c in enumerate(pool) if c.name in names)
        anchor = np.clip(universe.vector(params), universe.space.lower, universe.space.upper)
        return cls(universe, problem, records, levels, half, half > 0, tested, anchor)

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
        """(``ŷ/σ``, Jacobian columns ``∂(ŷ/σ)/∂φ`` for ``cols``) at ``x``."""
        phi = np.where(logflag, np.log(np.where(logflag, x, 1.0)), x)
        cols = list(cols)
        d = len(x)
        pred, blocks = None, []
        for start in range(0, max(len(cols), 1), BLOCK):
            chunk = cols[start:start + BLOCK]
            tangents = np.zeros((BLOCK, d))
            tangents[np.arange(len(chunk)), chunk] = 1.0
            y, jt = _block(self.problem, jnp.asarray(phi), jnp.asarray(logflag),
                           jnp.asarray(tangents))
            pred = np.asarray(y)
            blocks.append(np.asarray(jt)[: len(chunk)].T)
        return pred, np.concatenate(blocks, axis=1) if blocks else np.zeros((pred.size, 0))

    def whitened(self, pred: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(``u``, ``dz(u)``): the whitened residual and its part beyond quantisation."""
        u = np.asarray(self.problem.measured) - pred
        return u, np.sign(u) * np.maximum(np.abs(u) - self.halfwidth, 0.0)

    def stat_cost(self, pred: np.ndarray) -> float:
        """``C = Σ dz(u)²`` (module docstring)."""
        return float(np.sum(self.whitened(pred)[1] ** 2))

    def fit_cost(self, pred: np.ndarray) -> float:
        u, dz = self.whitened(pred)
        return float(np.sum(dz**2) + INNER_WEIGHT * np.sum(u[self.quantised] ** 2))

    # --- fitting ------------------------------------------------------------------------------
    def fit(self, x0: np.ndarray, active: Sequence[int]) -> tuple[np.ndarray, float]:
        """Fit the base and ``active`` slot parameters from ``x0``; returns ``(x, C)``.

        Levenberg–Marquardt, then a pattern search over each effect parameter (factors
        :data:`PATTERN`) and Levenberg–Marquardt again while that finds a lower cost: an effect
        may be piecewise smooth (a delay on a zero-order-hold grid has a kink at every
        sub-step), and a gradient method stops at a kink. Inactive candidates stay at their
        nulls.
        """
        u = self.universe
        x = self._lm(x0, active)
        effect_cols = [i for s in active for i in u.index(u.slots[s].names)]
        for _ in range(PATTERN_ROUNDS):
            base_cost = self.forward_cost(x)
            best, best_cost = x, base_cost
            for i in effect_cols:
                for factor in PATTERN:
                    xt = best.copy()
                    xt[i] = np.clip(best[i] * factor, u.space.lower[i], u.space.upper[i])
                    c = self.forward_cost(xt)
                    if c < best_cost:
                        best, best_cost = xt, c
            if not best_cost < base_cost * (1 - LM_RTOL):
                break
            x = self._lm(best, active)
        x = self._release_bounds(x, active)
        pred = np.asarray(_forward(self.problem, jnp.asarray(x)))
        return x, self.stat_cost(pred)

    def _release_bounds(self, x: np.ndarray, active: Sequence[int]) -> np.ndarray:
        """Refit once more with base parameters that ended on a bound put back at their start.

        A parameter that compensated a missing effect (a viscous friction pushed to zero) can
        stay pinned on its bound after the effect is added: on the bound the gradient still
        points outwards, a local minimum of the constrained problem.
        """
        if self.anchor is None:
            return x
        u = self.universe
        base = np.arange(u.n_base)
        unit = np.asarray(u.space.to_unit(u.space.from_vector(np.where(
            u.active_mask(active), x, u.space.lower))))[base]
        pinned = base[(unit <= 1e-9) | (unit >= 1 - 1e-9)]
        pinned = [i for i in pinned if not np.isclose(x[i], self.anchor[i])]
        if not pinned:
            return x
        trial = x.copy()
        trial[pinned] = self.anchor[pinned]
        trial = self._lm(trial, active)
        return trial if self.forward_cost(trial) < self.forward_cost(x) else x

    def forward_cost(self, x: np.ndarray) -> float:
        """The fit cost at ``x`` (one simulation, no derivatives)."""
        cost = self.fit_cost(np.asarray(_forward(self.problem, jnp.asarray(x))))
        return cost if math.isfinite(cost) else math.inf

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
        """Levenberg–Marquardt of the base and ``active`` parameters on the bounds (active-set
        projection).

        The coordinates are the physical values over their starting magnitudes: in log
        coordinates a parameter pushed against a lower bound near zero (a friction term that
        compensated a missing effect) has a vanishing gradient and cannot come back.
        """
        u = self.universe
        mask = u.active_mask(active)
        cols = np.flatnonzero(mask)
        linear = np.zeros_like(mask)
        x = np.where(mask, x0, u.null)
        x[cols] = np.clip(x[cols], u.space.lower[cols], u.space.upper[cols])
        scale = np.maximum(np.abs(x[cols]), u.space.lower[cols])  # coordinates of order one
        lo, hi = u.space.lower[cols] / scale, u.space.upper[cols] / scale
        phi = x[cols] / scale

        def at(p):
            xt = x.copy()
            xt[cols] = p * scale
            pred, jac = self.evaluate(xt, linear, cols)
            jac = jac * scale
            r, jf = self._system(pred, jac)
            cost = float(r @ r)
            return xt, r, jf, cost if math.isfinite(cost) else math.inf

        x, r, jf, cost = at(phi)
        lam, nu = 1e-3, 2.0
        for _ in range(self.max_iterations):
            g = jf.T @ r
            a = jf.T @ jf
            diag = np.maximum(np.diag(a), 1e-12 * max(np.max(np.diag(a)), 1e-300))
            # parameters on a bound that the gradient pushes outwards stay there this step
            span = hi - lo
            pinned = ((phi <= lo + 1e-9 * span) & (g > 0)) | ((phi >= hi - 1e-9 * span) & (g < 0))
            free = ~pinned
            step = np.zeros_like(phi)
            if free.any():
                sub = np.ix_(free, free)
                step[free] = np.linalg.solve(a[sub] + lam * np.diag(diag[free]), -g[free])
            trial = np.clip(phi + step, lo, hi)
            step = trial - phi
            predicted = -(2 * step @ g + step @ a @ step)
            xt, r_t, jf_t, cost_t = at(trial)
            if cost_t < cost:
                rho = (cost - cost_t) / predicted if predicted > 0 else 0.0
                lam *= max(1 / 3, 1 - (2 * rho - 1) ** 3)
                nu = 2.0
                small = cost - cost_t <= LM_RTOL * cost and lam < 1.0
                phi, x, r, jf, cost = trial, xt, r_t, jf_t, cost_t
                if small:
                    break
            else:
                lam *= nu
                nu *= 2.0
                if lam > 1e10:
                    break
        return x

    def profile_start(self, x: np.ndarray, active: Sequence[int], slot: int,
                      guess: Mapping[str, float]) -> tuple[np.ndarray, float]:
        """Start values of a new slot's parameters (the others kept at ``x``) and the profiled
        cost there.

        A profile along the diagonal of the new parameters' unit box (a grid, the score test's
        one-step estimate, then golden-section refinement) of the cost with the fitted
        parameters re-optimised to first order: the residual is projected off the span of
        their Jacobian at ``x``. Without that, parameters that compensated the missing effect
        would pull its start towards the null.
        """
        u = self.universe
        idx = u.index(u.slots[slot].names)
        sub = ParameterSpace([u.space[n] for n in u.slots[slot].names])
        cols = np.flatnonzero(u.active_mask(active))
        pred, jac = self.evaluate(x, np.zeros(len(x), bool), cols)
        _, jf = self._system(pred, jac)
        norms = np.linalg.norm(jf, axis=0)
        q, rr = np.linalg.qr(jf / np.where(norms > 0, norms, 1.0))
        q = q[:, np.abs(np.diag(rr)) > 1e-10]

        def cost_at(t):
            xt = x.copy()
            xt[idx] = np.asarray(sub.to_vector(sub.from_unit(np.full(len(idx), t))))
            r, _ = self._system(np.asarray(_forward(self.problem, jnp.asarray(xt))), None)
            r = r - q @ (q.T @ r)
            cost = float(r @ r)
            return cost if math.isfinite(cost) else math.inf, xt

        grid = np.linspace(0.0, 1.0, PROFILE_POINTS)
        costs = [cost_at(t)[0] for t in grid]
        est = np.array([guess.get(o, np.nan) for o in u.slots[slot].own_names])
        if np.all(np.isfinite(est)) and np.all(est > sub.lower) and np.all(est < sub.upper):
            t_est = float(np.mean(np.asarray(sub.to_unit(sub.from_vector(est)))))
            grid, costs = np.append(grid, t_est), costs + [cost_at(t_est)[0]]
            order = np.argsort(grid)
            grid, costs = grid[order], [costs[i] for i in order]
        k = int(np.argmin(costs))
        lo, hi = grid[max(k - 1, 0)], grid[min(k + 1, len(grid) - 1)]
        ratio = (math.sqrt(5.0) - 1.0) / 2.0
        a, b = hi - ratio * (hi - lo), lo + ratio * (hi - lo)
        fa, fb = cost_at(a)[0], cost_at(b)[0]
        for _ in range(GOLDEN_STEPS):
            if fa < fb:
                hi, b, fb = b, a, fa
                a = hi - ratio * (hi - lo)
                fa = cost_at(a)[0]
            else:
                lo, a, fa = a, b, fb
                b = lo + ratio * (hi - lo)
                fb = cost_at(b)[0]
        best = min([(costs[k], grid[k]), (fa, a), (fb, b)])
        return cost_at(best[1])[1], best[0]

    def start(self, x: np.ndarray, active: Sequence[int], candidate: int,
              guess: Mapping[str, float], with_cost: bool = False):
        """The slot and start of a candidate (and the profiled cost there): for a profiled
        candidate the member whose profile (:meth:`profile_start`) reaches the lowest cost."""
        u = self.universe
        slots = [i for i, s in enumerate(u.slots) if s.candidate == candidate]
        starts = [(self.profile_start(x, active, i, guess), i) for i in slots]
        (x_start, profiled), slot = min(starts, key=lambda item: item[0][1])
        return (slot, x_start, profiled) if with_cost else (slot, x_start)

    def predictions(self, x: np.ndarray, records: Dataset) -> tuple[Outputs, ...]:
        return _simulate_all(self.universe, x, records)

    def prediction_cost(self, predictions: Sequence[Outputs]) -> float:
        """``C`` of any predictions of the records (e.g. of another model)."""
        cost = 0.0
        for record, pred in zip(self.records, predictions, strict=True):
            for c in CHANNELS:
                level = self.noise[c]
                u = (record.channel(c) - np.asarray(pred.channel(c))) / level.sigma
                if level.kind == "quantised":
                    u = np.maximum(np.abs(u) - 0.5 * level.step / level.sigma, 0.0)
                cost += float(u @ u)
        return cost

    def discovery_fit(self, x: np.ndarray, active: Sequence[int], cost: float) -> DiscoveryFit:
        u = self.universe
        return DiscoveryFit(
            model=u.model_of(active),
            params=u.params(x, active),
            cost=cost,
            n_params=int(u.active_mask(active).sum()),
            n_samples=self.n_samples,
            noise=self.noise,
        )

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
        tested = [int(i) for s in slots for i in u.index(u.slots[s].names)]
        pred, jac = self.evaluate(x, self._coords(mask), nuisance + tested)
        _, r = self.whitened(pred)
        jn = jac[:, : len(nuisance)]
        columns = dict(zip(tested, jac[:, len(nuisance):].T, strict=True))
        norms = np.linalg.norm(jn, axis=0)
        q, rr = np.linalg.qr(jn / np.where(norms > 0, norms, 1.0))
        q = q[:, np.abs(np.diag(rr)) > 1e-10]

        families: dict[int, list[ScoreResult]] = {}
        for s in slots:
            slot = u.slots[s]
            cand = u.candidates[slot.candidate]
            jc = np.stack([columns[int(i)] for i in u.index(slot.names)], axis=1)
            jc = jc - q @ (q.T @ jc)
            families.setdefault(slot.candidate, []).append(
                _score(cand, slot, [u.space[n] for n in slot.names], jc.T @ r, jc.T @ jc)
            )
        m = max(len(families), 1)
        results = []
        for members in families.values():
            best = max(members, key=lambda t: (t.statistic - t.dof, -t.p_value))
            p = min(1.0, best.p_value * best.profile)
            results.append(dataclasses.replace(best, p_value=p, significant=p < alpha / m))
        results.sort(key=lambda t: (t.p_value, -(t.statistic - t.dof)))
        return results


def _simulate_all(universe: _Universe, x: np.ndarray, records: Dataset) -> tuple[Outputs, ...]:
    params = dict(zip(universe.space.names, map(float, x), strict=True))
    return tuple(simulate(universe.model, params, r.torque, dt=r.dt) for r in records)


def _one_sided(spec: ParameterSpec) -> int:
    """+1 if the null is the lower boundary, −1 the upper, 0 if it lies inside the bounds."""
    if spec.null <= spec.lower:
        return 1
    if spec.null >= spec.upper:
        return -1
    return 0


def _score(cand: Candidate, slot: _Slot, specs: Sequence[ParameterSpec], g: np.ndarray,
           v: np.ndarray) -> ScoreResult:
    """The score statistic of one profile member from ``g = J_c⊥ᵀ r`` and ``V = J_c⊥ᵀ J_c⊥``."""
    k = len(specs)
    side = _one_sided(specs[0]) if k == 1 else 0
    if not np.all(np.isfinite(v)) or not np.trace(v) > 0:
        stat, p, z, beta = 0.0, 1.0, None, np.zeros(k)
    else:
        beta = np.linalg.pinv(v, rcond=1e-12) @ g
        if side:
            z = side * float(g[0] / math.sqrt(v[0, 0]))
            stat = max(z, 0.0) ** 2
            p = 0.5 * chi2_sf(stat, 1) if stat > 0 else 1.0
        else:
            z, stat = None, float(g @ beta)
            p = chi2_sf(stat, k)
    return ScoreResult(
        effect=cand.name,
        parameters=slot.own_names,
        statistic=float(stat),
        dof=k,
        p_value=float(p),
        one_sided=bool(side),
        z=z,
        estimate={o: float(sp.null + b) for o, sp, b in zip(slot.own_names, specs, beta,
                                                           strict=True)},
        units={o: sp.unit for o, sp in zip(slot.own_names, specs, strict=True)},
        setting=cand.label(slot.member),
        profile=len(cand.effects),
        member=slot.member,
    )


def _full_params(model: Model, params: Mapping[str, ArrayLike] | Any) -> dict[str, float]:
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
    model: Model,
    params: Mapping[str, ArrayLike],
    records: Dataset | Iterable[Record],
    candidates: Iterable[str | Effect | Candidate] | None = None,
    *,
    alpha: float = ALPHA,
    noise: Noise | None = None,
) -> list[ScoreResult]:
    """Score-test every candidate effect at the fit ``params`` of ``model`` (best first).

    ``candidates`` are effect names or instances (default: the library, Stribeck profiled over
    its velocity grid); those already in ``model`` are skipped. ``noise`` gives each channel's
    :class:`~jaxflex.diagnosis.NoiseLevel` (default: estimated from the residuals).
    ``significant`` marks p-values below ``alpha/m`` (Bonferroni over the ``m`` candidates).
    """
    records = as_dataset(records)
    values = _full_params(model, params)
    cands = tuple(c for c in candidate_set(candidates) if c.name not in model.effect_names)
    engine = _Engine.build(model, cands, records, values, noise)
    return engine.score_tests(engine.universe.vector(values), (), alpha)


def _lr_test(lr: float, specs: Sequence[ParameterSpec]) -> float:
    """p-value of a likelihood-ratio statistic for adding parameters ``specs`` (boundary nulls:
    the 50:50 χ̄² mixture for one parameter)."""
    if not lr > 0:
        return 1.0
    if len(specs) == 1 and _one_sided(specs[0]) != 0:
        return 0.5 * chi2_sf(lr, 1)
    return chi2_sf(lr, len(specs))


def refit(
    model: Model,
    params: Mapping[str, ArrayLike] | Any,
    records: Dataset | Iterable[Record],
    *,
    noise: Noise | None = None,
) -> DiscoveryFit:
    """Fit ``model`` on the discovery likelihood from ``params`` (a mapping or a fit).

    Levenberg–Marquardt of every parameter on the noise-whitened residuals (module docstring);
    ``noise`` defaults to the levels estimated from the residuals at ``params``.
    """
    records = as_dataset(records)
    values = _full_params(model, params)
    engine = _Engine.build(model, (), records, values, noise)
    x, cost = engine.fit(engine.universe.vector(values), ())
    return engine.discovery_fit(x, (), cost)


def add_effect(
    fit: DiscoveryFit | Any,
    effect: str | Effect,
    records: Dataset | Iterable[Record],
    *,
    model: Model | None = None,
    noise: Noise | None = None,
) -> DiscoveryFit:
    """Add ``effect`` to a fitted model and refit everything, warm-started.

    The fitted parameters are kept as the start; the effect's parameters start from the best
    of a short profile over their bounds (and the score test's one-step estimate); then
    Levenberg–Marquardt refines all of them on the discovery likelihood. ``fit`` is a
    :class:`DiscoveryFit` or anything with ``.params`` (then give its ``model``; default the
    reference testbed). A profiled effect name (``"stribeck"``) uses its best-scoring member.
    """
    records = as_dataset(records)
    base = model if model is not None else getattr(fit, "model", None)
    base = base() if callable(base) and not isinstance(base, Model) else base
    base = base if isinstance(base, Model) else Model()
    values = _full_params(base, fit)
    cand = _candidate(effect)
    if cand.name in base.effect_names:
        raise ValueError(f"effect {cand.name!r} is already in the model")
    levels = dict(fit.noise) if isinstance(fit, DiscoveryFit) else {}
    levels.update(noise_levels(noise))
    engine = _Engine.build(base, (cand,), records, values, levels)
    x0 = engine.universe.vector(values)
    best = engine.score_tests(x0, (), 1.0)[0]
    slot, start = engine.start(x0, (), engine.candidate(cand.name), best.estimate)
    x, cost = engine.fit(start, [slot])
    return engine.discovery_fit(x, [slot], cost)


# --- explanations --------------------------------------------------------------------------------


def _hooks(effect: Effect) -> set[str]:
    """Which model hooks an effect overrides."""
    inner = effect.inner if isinstance(effect, _Variant) else effect
    return {h for h in ("structure", "friction", "loads", "input_torque")
            if getattr(type(inner), h) is not getattr(Effect, h)}


def _magnitude(values: Mapping[str, float], units: Mapping[str, str]) -> str:
    """Parameter values in readable units (grams, milliseconds)."""
    parts = []
    for name, value in values.items():
        unit = units.get(name, "")
        if unit == "kg" and abs(value) < 1:
            parts.append(f"{name} = {1e3 * value:.3g} g")
        elif unit == "s" and abs(value) < 1:
            parts.append(f"{name} = {1e3 * value:.3g} ms")
        else:
            parts.append(f"{name} = {value:.3g} {unit}".rstrip())
    return ", ".join(parts)


def explain(result: ScoreResult, effect: Effect, diagnosis: Diagnosis | None,
            fitted: Mapping[str, float] | None = None) -> str:
    """One sentence linking a ranked effect to the residual features it accounts for.

    The features come from the diagnosis, chosen by the hooks the effect acts through: a
    changed structure shows as shifted resonances, a changed input as residuals lagging the
    torque, friction and loads as misfit concentrated in some operating condition. The size is
    the refit value when ``fitted`` is given, else the score test's one-step estimate.
    """
    hooks = _hooks(effect)
    features = []
    if diagnosis is not None:
        if "structure" in hooks and diagnosis.frf is not None and diagnosis.frf.resonances:
            s = max(diagnosis.frf.resonances, key=lambda s: abs(s.shift_hz) / s.measured_hz)
            features.append(f"resonance measured at {s.measured_hz:.2f} Hz, model "
                            f"{s.model_hz:.2f} Hz")
        if "input_torque" in hooks:
            xc = diagnosis.channels["joint_angle"].input_correlation
            features.append(f"angle residual correlates with the torque "
                            f"{1e3 * xc.peak_lag_s:+.0f} ms later")
        if hooks & {"friction", "loads"}:
            conds = sorted(diagnosis.localisation.conditions, key=lambda c: -c.concentration)
            if conds and conds[0].concentration > 1.2:
                c = conds[0]
                features.append(f"{100 * c.combined:.0f} % of the misfit in '{c.condition}' "
                                f"({100 * c.time_share:.0f} % of the time)")
    if fitted is not None:
        size = "refit with " + _magnitude(fitted, result.units)
    else:
        size = "one-step estimate " + _magnitude(result.estimate, result.units)
    where = f" ({result.setting})" if result.setting else ""
    verdict = "explains it" if result.significant else "is not significant"
    head = "; ".join(features) if features else "residual structure"
    return (f"{result.effect}{where}: {head}; {size} {verdict} "
            f"(score {result.statistic:.3g}, p = {result.p_value:.2g}). "
            f"Signature: {effect.signature}").strip()


# --- the loop ------------------------------------------------------------------------------------


def _metrics(records: Dataset, preds: Sequence[Outputs], holdout: Dataset | None,
             holdout_preds: Sequence[Outputs] | None) -> tuple[dict, float, dict | None]:
    """(NRMSE per output, FRF NRMSE, held-out errors), means over the records, as
    :func:`jaxflex.compare.compare` computes them."""
    rows = [_compare_record(r, p, "fit", DEFAULT_T_END, FRFSettings(), None, None)
            for r, p in zip(records, preds, strict=True)]
    nrmse = {o: float(np.nanmean([r.nrmse[o] for r in rows])) for o in CHANNELS}
    frf = [r.frf_nrmse for r in rows if math.isfinite(r.frf_nrmse)]
    held = None
    if holdout is not None and holdout_preds is not None:
        rows = [_compare_record(r, p, "held-out", DEFAULT_T_END, FRFSettings(), None, None)
                for r, p in zip(holdout, holdout_preds, strict=True)]
        held = {key: {o: float(np.nanmean([getattr(r, key)[o] for r in rows]))
                      for o in CHANNELS} for key in ("nrmse", "relative_error")}
    return nrmse, float(np.mean(frf)) if frf else math.nan, held


def _rigid(records: Dataset):
    """The convex rigid-body estimate (no torque offset: the flexible models have none either),
    or ``None`` where the records do not determine it."""
    from jaxflex.rigid import estimate_rigid

    try:
        return estimate_rigid(records, offset=False)
    except ValueError:
        return None


def _rigid_step(engine: _Engine, estimate, records: Dataset, holdout: Dataset | None,
                alpha: float) -> Step:
    """The first rung of the ladder: the rigid-body model (no link flexibility)."""
    from jaxflex.rigid import rigid_simulate

    length = engine.universe.base.testbed.length
    preds = tuple(rigid_simulate(estimate, r.torque, r.dt, length=length) for r in records)
    held = None
    if holdout is not None:
        held = [rigid_simulate(estimate, r.torque, r.dt, length=length) for r in holdout]
    nrmse, frf, held = _metrics(records, preds, holdout, held)
    params = {"J_tot": estimate.J_tot, "b_v": estimate.b_v, "tau_c": estimate.tau_c}
    fit = DiscoveryFit(model=None, params=params, cost=engine.prediction_cost(preds),
                       n_params=len(params),
                       n_samples=engine.n_samples, noise=engine.noise)
    return Step(added=None, fit=fit, nrmse=nrmse, frf_nrmse=frf, holdout=held,
                diagnosis=diagnose(records, preds, noise=engine.noise, alpha=alpha),
                label="rigid", predictions=preds)


def _initial_params(records: Dataset, model: Model, initial: Any, budget: tuple[int, int],
                    seed: int, progress: bool, rigid) -> dict[str, float]:
    """The starting fit of the base model: ``initial``, or :func:`jaxflex.identify.identify`
    (differential evolution, ``budget = (generations, population)``, seeded around the
    rigid-body estimate, then Levenberg–Marquardt)."""
    if initial is not None:
        return _full_params(model, initial)
    from jaxflex.identify import identify

    seeds = None
    if rigid is not None:
        from jaxflex.rigid import warm_start

        space = model.space
        units = warm_start(rigid, space, population=budget[1], seed=seed)
        seeds = [{k: float(v) for k, v in space.from_unit(u).items()} for u in units]
    fit = identify(records, model, seed=seed, generations=budget[0], population=budget[1],
                   progress=progress, init_population=seeds, intervals=False)
    return _full_params(model, fit)


def load_example() -> tuple[Dataset, Dataset]:
    """The bundled example: (three records to fit, one held out) of an arm with a hidden effect.

    Made by ``benchmarks/make_example_data.py`` (base parameters away from the reference values,
    the spec's sensor noise, a fixed seed); the files' comments give the answer.
    """
    from importlib import resources

    from jaxflex.data import load_record

    folder = resources.files("jaxflex") / "data"
    files = sorted(p for p in folder.iterdir() if p.name.startswith("example_"))
    if not files:
        raise FileNotFoundError(f"no example records in {folder}; run "
                                "benchmarks/make_example_data.py")
    records = [load_record(Path(str(p))) for p in files]
    fit = Dataset(r for r in records if "holdout" not in r.name)
    return fit, Dataset(r for r in records if "holdout" in r.name)


def _fast() -> bool:
    return os.environ.get("JAXFLEX_FAST", "") not in ("", "0")


def discover(
    records: Dataset | Iterable[Record],
    holdout: Dataset | Iterable[Record] | None = None,
    model: Model | None = None,
    candidates: Iterable[str | Effect | Candidate] | None = None,
    max_steps: int = 4,
    alpha: float = ALPHA,
    seed: int = 0,
    progress: bool = False,
    *,
    initial: Mapping[str, ArrayLike] | Any = None,
    budget: int | tuple[int, int] | None = None,
    noise: Noise | None = None,
    max_confirm: int = MAX_CONFIRM,
) -> DiscoveryReport:
    """Find the effects the model is missing, one at a time (see the module docstring).

    ``model`` is the starting structure (default: the reference testbed). ``initial`` is its
    fitted parameters (a mapping or a fit); without it the base model is identified from scratch
    by differential evolution and Levenberg–Marquardt (:func:`jaxflex.identify.identify`), with
    ``budget`` generations or ``(generations, population)`` (default :data:`BUDGET`,
    :data:`FAST_BUDGET` with ``JAXFLEX_FAST=1``). ``alpha`` is the family-wise level of each
    step, Bonferroni over the candidates. ``noise`` gives channels' noise levels, a white σ in
    the channel's unit or a :class:`~jaxflex.diagnosis.NoiseLevel` (e.g.
    ``{"joint_angle": 1e-4}``); the others are estimated from the first fit's residuals
    (:func:`jaxflex.diagnosis.estimate_noise`), and the report states each level and how it was
    obtained. Returns a :class:`DiscoveryReport`.
    """
    t0 = time.perf_counter()
    records = as_dataset(records)
    holdout = as_dataset(holdout) if holdout is not None else None
    model = Model() if model is None else model
    if not isinstance(model, Model):
        raise TypeError(f"model must be a jaxflex Model, got {type(model).__name__}")
    if isinstance(max_steps, bool) or not isinstance(max_steps, int) or max_steps < 0:
        raise ValueError(f"max_steps={max_steps!r} must be an int >= 0")
    if not 0 < alpha < 1:
        raise ValueError(f"alpha={alpha!r} must lie in (0, 1)")
    if budget is None:
        budget = FAST_BUDGET if _fast() else BUDGET
    budget = (int(budget), BUDGET[1]) if isinstance(budget, (int, np.integer)) else budget
    if len(budget) != 2 or min(budget) < 1:
        raise ValueError(f"budget={budget!r} must be generations or (generations, population)")
    budget = (int(budget[0]), int(budget[1]))
    cands = tuple(c for c in candidate_set(candidates) if c.name not in model.effect_names)
    rigid = _rigid(records)
    start = _initial_params(records, model, initial, budget, seed, progress, rigid)
    engine = _Engine.build(model, cands, records, start, noise)
    u = engine.universe
    names = [c.name for c in u.candidates]

    x, cost = engine.fit(u.vector(start), ())
    active: list[int] = []
    steps: list[Step] = []
    if rigid is not None:
        steps.append(_rigid_step(engine, rigid, records, holdout, alpha))
    added: dict[str, Any] = {}
    for _ in Progress(range(max_steps + 1), label="discover", enabled=progress):
        preds = engine.predictions(x, records)
        diag = diagnose(records, preds, noise=engine.noise, alpha=alpha)
        held_preds = engine.predictions(x, holdout) if holdout is not None else None
        nrmse, frf, held = _metrics(records, preds, holdout, held_preds)
        ranking: list[ScoreResult] = []
        confirmations: list[Confirmation] = []
        best = None
        if len(active) < max_steps and len(active) < len(cands):
            ranking = engine.score_tests(x, active, alpha)
            m = len(ranking)
            top = max((r.statistic for r in ranking), default=0.0)
            contenders = [r for r in ranking
                          if r.significant and r.statistic >= CONFIRM_RATIO * top]
            starts: dict[str, tuple[int, np.ndarray]] = {}
            if not contenders and not diag.consistent_with_noise:
                ranking, starts = _profile_scan(engine, x, active, ranking, alpha / m)
                contenders = sorted((r for r in ranking if r.profile_drop is not None
                                     and r.profile_p_value < alpha / m),
                                    key=lambda r: -r.profile_drop)
            for r in contenders[:max_confirm]:
                conf, slot, x1, cost1 = _confirm(engine, x, cost, active,
                                                 names.index(r.effect), r.estimate, alpha / m,
                                                 starts.get(r.effect))
                confirmations.append(conf)
                if conf.confirmed and (best is None or conf.lr > best[0].lr):
                    best = (conf, slot, x1, cost1)
            ranking = _final_ranking(ranking, confirmations, u.candidates, diag)
        steps.append(Step(
            added=added.get("name"), fit=engine.discovery_fit(x, active, cost), nrmse=nrmse,
            frf_nrmse=frf, holdout=held, diagnosis=diag, ranking=tuple(ranking),
            confirmations=tuple(confirmations), lr=added.get("lr"),
            p_value=added.get("p"), explained=added.get("explained"), predictions=preds,
        ))
        if best is None:
            break
        conf, slot, x, cost = best
        active = active + [slot]
        added = {"name": conf.effect, "lr": conf.lr, "p": conf.p_value,
                 "explained": conf.explained}

    steps, withdrawn = _withdraw(steps)
    unexplained = steps[-1].diagnosis.unexplained()
    if unexplained is not None:
        if steps[-1].ranking or withdrawn:
            note = "no candidate effect explains it"
        elif sum(s.added is not None for s in steps) >= max_steps:
            note = f"the loop stopped at max_steps={max_steps} before testing more candidates"
        else:
            note = "every candidate is in the model already"
        if withdrawn:
            note += (f" ({', '.join(withdrawn)} reduced the misfit but left most of it; "
                     "withdrawn)")
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
                  "budget": budget if initial is None else None,
                  "initial": "given" if initial is not None else "differential evolution",
                  "noise": {c: v.to_dict() for c, v in engine.noise.items()},
                  "min_explained": MIN_EXPLAINED},
        wall_time=time.perf_counter() - t0,
        noise_floor={c: d.noise_floor_nrmse for c, d in steps[-1].diagnosis.channels.items()},
    )


def _profile_scan(engine: _Engine, x: np.ndarray, active: Sequence[int],
                  ranking: Sequence[ScoreResult], level: float):
    """Each candidate's profile drop: the cost at the fit minus the lowest cost along its 1-D
    profile (fitted parameters re-optimised to first order, :meth:`_Engine.profile_start`).

    The score test is local: when the misfit is large (an effect that shifts a resonance by
    a good fraction of its width) the first-order picture at the null can point away from an
    effect that a finite step explains. The scan runs when no score is significant yet the
    residuals are not noise; its drop is judged like a likelihood ratio at ``level``.
    """
    u = engine.universe
    names = [c.name for c in u.candidates]
    current = engine.forward_cost(x)
    out, starts = [], {}
    for r in ranking:
        candidate = names.index(r.effect)
        slot, start, profiled = engine.start(x, active, candidate, r.estimate, with_cost=True)
        drop = max(current - profiled, 0.0)
        p = _lr_test(drop, [u.space[n] for n in u.slots[slot].names])
        starts[r.effect] = (slot, start)
        out.append(dataclasses.replace(r, profile_drop=drop, profile_p_value=p))
    return out, starts


def _confirm(engine: _Engine, x: np.ndarray, cost: float, active: Sequence[int],
             candidate: int, guess: Mapping[str, float], level: float,
             start: tuple[int, np.ndarray] | None = None):
    """Refit the model with one more candidate; its likelihood-ratio test at ``level``, BIC.

    Confirmed when the LR test rejects the null at ``level``, the BIC falls and the effect did
    not end on its null-side bound. ``start``: a (slot, start vector) found already; otherwise
    each member of a profiled candidate is refitted and the best kept."""
    u = engine.universe
    if start is not None:
        tries = [start]
    else:  # every member of a profile: the profiled cost may misjudge a large effect
        slots = [i for i, s in enumerate(u.slots) if s.candidate == candidate]
        tries = [(i, engine.profile_start(x, active, i, guess)[0]) for i in slots]
    fits = [(engine.fit(x_start, list(active) + [slot]), slot) for slot, x_start in tries]
    (x1, cost1), slot = min(fits, key=lambda item: item[0][1])
    specs = [u.space[n] for n in u.slots[slot].names]
    lr = cost - cost1
    sub = ParameterSpace(specs)
    unit = np.asarray(sub.to_unit(sub.from_vector(x1[u.index(u.slots[slot].names)])))
    p = _lr_test(lr, specs)
    delta_bic = len(specs) * math.log(engine.n_samples) - lr
    conf = Confirmation(
        effect=u.candidates[candidate].name,
        lr=lr,
        p_value=p,
        delta_bic=delta_bic,
        explained=lr / max(cost - engine.noise_cost, 1e-12),
        confirmed=bool(p < level and delta_bic < 0 and not np.all(unit < BOUND_TOL)),
        params=u.params(x1, list(active) + [slot]),
        member=u.slots[slot].member,
        setting=u.candidates[candidate].label(u.slots[slot].member),
    )
    return conf, slot, x1, cost1


def _final_ranking(ranking: Sequence[ScoreResult], confirmations: Sequence[Confirmation],
                   cands: Sequence[Candidate], diag: Diagnosis) -> list[ScoreResult]:
    """The ranking after the refits: confirmed candidates by their likelihood ratio, then the
    others by their score; each with its explanation (refit values where refitted)."""
    names = [c.name for c in cands]
    refits = {c.effect: c for c in confirmations}
    out = []
    for r in ranking:
        cand = cands[names.index(r.effect)]
        conf = refits.get(r.effect)
        member = conf.member if conf else r.member
        fitted = {n: conf.params[n] for n in _parameter_names(cand)} if conf else None
        if conf and conf.member != r.member:
            r = dataclasses.replace(r, setting=conf.setting, member=member)
        out.append(dataclasses.replace(
            r, explanation=explain(r, cand.effects[member], diag, fitted)))
    confirmed = {c.effect: c.lr for c in confirmations if c.confirmed}
    return sorted(out, key=lambda r: (r.effect not in confirmed, -confirmed.get(r.effect, 0.0)))


def _withdraw(steps: list[Step]) -> tuple[list[Step], list[str]]:
    """Steps without effects that leave structure behind yet removed less than
    :data:`MIN_EXPLAINED` of the misfit: the run is cut before the first such effect."""
    if steps[-1].diagnosis.consistent_with_noise:
        return steps, []
    for i, step in enumerate(steps):
        if step.added is not None and step.explained < MIN_EXPLAINED:
            return steps[:i], [s.added for s in steps[i:] if s.added]
    return steps, []


__all__ = [
    "ALPHA",
    "Candidate",
    "Confirmation",
    "DiscoveryFit",
    "DiscoveryReport",
    "ScoreResult",
    "Step",
    "add_effect",
    "candidate_set",
    "refit",
    "discover",
    "explain",
    "load_example",
    "score_tests",
]
