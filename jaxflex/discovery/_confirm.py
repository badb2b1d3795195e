"""Confirmation of a candidate by refitting it: the likelihood-ratio test, the BIC, and the
profile scan used when the score test's first-order picture fails."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Iterable, Mapping, Sequence

import numpy as np

from jaxflex.discovery._engine import Engine, ProfileRequest
from jaxflex.discovery.report import Confirmation
from jaxflex.discovery.scores import ScoreResult, lr_test
from jaxflex.parameters import ParameterSpace, ParameterSpec

BOUND_TOL = 1e-3

"""A refit effect whose parameters all end this close (unit box) to their null-side bound is
not confirmed: the fit used it only to polish the others."""


ON_BOUND = 1e-3

"""A parameter ends on a bound when it lies within this fraction of the bound's value of it (of
the range, for a parameter on a linear scale)."""


def on_bound(params: Mapping[str, float], specs: Iterable[ParameterSpec],
             null_side: bool = True) -> dict[str, str]:
    """The parameters of ``params`` that end on a bound of their ``specs``, each with the side
    (``"lower"``, ``"upper"``); with ``null_side=False`` not the bound where an effect
    vanishes (its null at or beyond that bound: :attr:`Confirmation.at_null` judges it)."""
    out = {}
    for spec in specs:
        if spec.name not in params:
            continue
        value = float(params[spec.name])
        for side, bound in (("lower", spec.lower), ("upper", spec.upper)):
            if not null_side and spec.null is not None and (
                    spec.null <= spec.lower if side == "lower" else spec.null >= spec.upper):
                continue
            scale = abs(bound) if spec.log_scale else spec.upper - spec.lower
            if abs(value - bound) <= ON_BOUND * scale:
                out[spec.name] = side
    return out


def _own_specs(engine: Engine, slot: int) -> list[ParameterSpec]:
    """The specs of a slot's parameters under the effect's own names (the universe's bounds)."""
    u = engine.universe
    s = u.slots[slot]
    return [dataclasses.replace(u.space[n], name=o)
            for n, o in zip(s.names, s.own_names, strict=True)]


def _widened(engine: Engine, slot: int, x1: np.ndarray, active: Sequence[int],
             ends: Mapping[str, str]) -> dict[str, tuple[float, float]]:
    """The new bounds (universe names) of the slot's parameters that ended on a bound: that
    bound moved out to the effect's physical limit
    (:meth:`~jaxflex.effects.AbstractEffect.physical_limits`), where the limit lies beyond it
    and the bounds were not given (a given bound is the user's word)."""
    u = engine.universe
    s = u.slots[slot]
    limits = s.effect.physical_limits(u.base.testbed, u.params(x1, active))
    out = {}
    for name, own in zip(s.names, s.own_names, strict=True):
        if (own not in ends or own not in limits or name in u.bounds
                or name in engine.widened):  # widened once only
            continue
        spec, (lo, hi) = u.space[name], limits[own]
        if ends[own] == "upper" and hi > spec.upper * (1 + ON_BOUND):
            out[name] = (spec.lower, float(hi))
        elif (ends[own] == "lower" and lo < spec.lower - ON_BOUND * abs(spec.lower)
              and not (spec.log_scale and lo <= 0)):
            out[name] = (float(lo), spec.upper)
    return out


def profile_scan(engine: Engine, x: np.ndarray, active: Sequence[int],
                 ranking: Sequence[ScoreResult], level: float, skip: Iterable[str] = ()):
    """Each candidate's profile drop: the cost at the fit minus the lowest cost along its 1-D
    profile (fitted parameters re-optimised to first order, :meth:`Engine.profile_starts`);
    the candidates in ``skip`` (refitted already) keep their entry as it is.

    The score test is local: when the misfit is large (an effect that shifts a resonance by
    a good fraction of its width) the first-order picture at the null can point away from an
    effect that a finite step explains. The scan runs when the residuals are not noise yet no
    refitted candidate explained most of the misfit; its drop is judged like a likelihood
    ratio at ``level``.
    """
    u = engine.universe
    names = [c.name for c in u.candidates]
    skip = set(skip)
    scanned = [r for r in ranking if r.effect not in skip]
    profiles = dict(zip((r.effect for r in scanned), engine.starts(
        [(x, active, names.index(r.effect), r.estimate) for r in scanned], with_cost=True),
        strict=True))
    current = engine.forward_cost(x)  # its prediction kept from the profiles' Jacobian
    out, starts = [], {}
    for r in ranking:
        if r.effect not in profiles:
            out.append(r)
            continue
        slot, start, profiled = profiles[r.effect]
        drop = max(current - profiled, 0.0)
        p = lr_test(drop, [u.space[n] for n in u.slots[slot].tested])
        starts[r.effect] = (slot, start)
        out.append(dataclasses.replace(r, profile_drop=drop, profile_p_value=p))
    return out, starts


def confirm(engine: Engine, x: np.ndarray, cost: float, active: Sequence[int],
            requests: Sequence[tuple[int, Mapping[str, float], tuple[int, np.ndarray] | None]],
            level: float) -> list[tuple[Confirmation, int, np.ndarray, float]]:
    """Refit the model with one more candidate, for each ``(candidate, guess, start)`` of
    ``requests``: its likelihood-ratio test at ``level``, BIC; the refits side by side
    (:meth:`Engine.fit_many`). Each gives ``(confirmation, slot, x1, cost1)``.

    Confirmed when the LR test rejects the null at ``level``, the BIC falls and the effect did
    not end on its null-side bound. ``start``: a (slot, start vector) found already; otherwise
    each member of a profiled candidate is refitted and the best kept. Where base parameters of
    ``x`` lie on a bound (they compensated the missing effect as far as they could: a compliant
    clamp's low first mode pins the Young's modulus at its minimum) and the base model was
    identified from scratch, the candidate is refitted from the search's centre too
    (:meth:`Engine.released`), its start profiled there: from ``x`` its profile only adds what
    the compensation left, and the refit stays in that basin."""
    u = engine.universe
    released = engine.released(x, active) if engine.centred else None
    asked: list[ProfileRequest] = []  # the profiles to take, side by side

    def profiled(at: np.ndarray, members: Sequence[int], guess: Mapping[str, float]
                 ) -> list[int]:
        asked.extend((at, active, i, guess) for i in members)
        return list(range(len(asked) - len(members), len(asked)))

    # (request, a (slot, start) found already or the places in `asked` of the best one's profiles)
    chosen: list[tuple[int, tuple[int, np.ndarray] | list[int]]] = []
    for n, (candidate, guess, start) in enumerate(requests):
        members = [i for i, s in enumerate(u.slots) if s.candidate == candidate]
        if start is not None:
            chosen.append((n, start))
        else:  # every member of a profile: the profiled cost may misjudge a large effect
            chosen += [(n, [k]) for k in profiled(x, members, guess)]
        if released is not None:
            chosen.append((n, profiled(released, members, guess)))
    found = engine.profile_starts(asked)
    tries = []  # (request, slot, start)
    for n, choice in chosen:
        if isinstance(choice, list):
            k = min(choice, key=lambda k: found[k][1])
            choice = (asked[k][2], found[k][0])
        tries.append((n, *choice))
    fits = engine.fit_many([(x_start, list(active) + [slot]) for _, slot, x_start in tries])
    ends = []
    for n in range(len(requests)):
        (x1, cost1), slot = min(((fit, slot) for (m, slot, _), fit in zip(tries, fits,
                                                                           strict=True)
                                 if m == n), key=lambda item: item[0][1])
        ends.append((slot, x1, cost1, {}))
    ends = _widen(engine, ends, active)
    return [(_confirmation(engine, cost, active, candidate, slot, x1, cost1, level, widened),
             slot, x1, cost1)
            for (candidate, _, _), (slot, x1, cost1, widened) in zip(requests, ends,
                                                                     strict=True)]


def _widen(engine: Engine, ends: list, active: Sequence[int]) -> list:
    """The refits ``(slot, x1, cost1, {})`` where one ended on a bound of its own parameters
    (not its null side) that physics allows to move: that bound moved out to the effect's
    physical limit (:func:`_widened`, for the rest of the run: the universe keeps it) and the
    candidate refitted from its end, once; each with the bounds it had before (own names)."""
    u = engine.universe
    wider: dict[str, tuple[float, float]] = {}
    which = []
    for k, (slot, x1, _, _) in enumerate(ends):
        params = u.params(x1, list(active) + [slot])
        found = _widened(engine, slot, x1, active,
                         on_bound(params, _own_specs(engine, slot), null_side=False))
        if found:
            wider |= found
            which.append(k)
    if not wider:
        return ends
    before = {n: (u.space[n].lower, u.space[n].upper) for n in wider}
    engine.universe = dataclasses.replace(u, space=u.space.with_bounds(wider))
    engine.widened |= set(wider)
    refits = engine.fit_many([(ends[k][1], list(active) + [ends[k][0]]) for k in which])
    out = list(ends)
    for k, (x1, cost1) in zip(which, refits, strict=True):
        s = u.slots[ends[k][0]]
        old = {o: before[n] for n, o in zip(s.names, s.own_names, strict=True) if n in before}
        out[k] = (ends[k][0], x1, cost1, old)
    return out


def _confirmation(engine: Engine, cost: float, active: Sequence[int], candidate: int,
                  slot: int, x1: np.ndarray, cost1: float, level: float,
                  widened: Mapping[str, tuple[float, float]]) -> Confirmation:
    """The likelihood-ratio test and BIC change of the refit ``x1`` (cost ``cost1``) of
    ``candidate`` in ``slot`` against the fit of cost ``cost``; ``widened``: the bounds its
    parameters had before they were widened (own names)."""
    u = engine.universe
    specs = [u.space[n] for n in u.slots[slot].tested]
    lr = cost - cost1
    sub = ParameterSpace(specs)
    unit = np.asarray(sub.to_unit(sub.from_vector(x1[u.index(u.slots[slot].tested)])))
    p = lr_test(lr, specs)
    delta_bic = len(u.slots[slot].names) * math.log(engine.n_samples) - lr  # every fitted one
    at_null = bool(np.all(unit < BOUND_TOL))
    params = u.params(x1, list(active) + [slot])
    own = _own_specs(engine, slot)
    ends = {} if at_null else on_bound(params, own, null_side=False)
    return Confirmation(
        effect=u.candidates[candidate].name,
        lr=lr,
        p_value=p,
        delta_bic=delta_bic,
        explained=lr / max(cost - engine.noise_cost, 1e-12),
        confirmed=bool(p < level and delta_bic < 0 and not at_null and not ends),
        params=params,
        member=u.slots[slot].member,
        setting=u.candidates[candidate].label(u.slots[slot].member),
        level=level,
        at_null=at_null,
        on_bound=ends,
        bounds={s.name: (s.lower, s.upper) for s in own},
        widened=dict(widened),
    )

