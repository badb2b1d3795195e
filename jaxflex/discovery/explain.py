"""The claims of a discovery report, each derived from named statistics by one stated rule.

Every sentence that :class:`~jaxflex.discovery.DiscoveryReport` prints or writes (its table,
its explanations, the JSON of ``jaxflex discover --json``) and every verdict in the titles of
its diagnosis figures comes from here. A candidate's **evidence** is a dict of named
statistics, collected by :func:`collect_evidence` at each step of the loop; its **status** is
what happened to it (:func:`annotate`, once the run is over and withdrawals are known); its
**claims** are the sentences :data:`RULES` allow on that evidence, one rule per claim. The
rules are written down in the documentation (*Physical effects → How discover words its
findings*), which quotes :attr:`Rule.when` verbatim.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from jaxflex.diagnosis import Diagnosis
from jaxflex.diagnosis.report import QUANTISED_EXCESS_LIMIT, RMS_RATIO_LIMIT, ChannelDiagnosis
from jaxflex.discovery.candidates import Variant
from jaxflex.discovery.scores import ScoreResult
from jaxflex.effects import AbstractEffect

CONCENTRATION = 1.5

"""A condition holds the misfit "concentrated" when its share of the misfit exceeds this multiple
of its share of the time (the diagnosis summary's threshold)."""


RATE_SHARE = 0.5

"""A late torque leaves a residual ``≈ −d·ẏ``: at the residual's peak lag the model's own output
rate must correlate with the torque at least this fraction of its strongest correlation."""


LOWERS_FREQUENCIES = frozenset({"payload", "root_compliance"})

"""Effects that can only lower the resonances (added mass, added compliance)."""


ALTERNATIVE_LR = 3.84

"""Two confirmed candidates fit about equally well when their refits' likelihood ratios differ by
less than this: the χ²₁ 95 % quantile, the smallest difference of −2 log L a likelihood-ratio
test of one parameter resolves."""


TELLS_APART: dict[frozenset[str], str] = {
    frozenset({"payload", "root_compliance"}):
        "a payload adds inertia to the whole arm, a compliant clamp none: a record with a slow "
        "sweep (the rigid-body response to the torque) or an accelerometer at the tip tells "
        "them apart",
    frozenset({"delay", "motor_lag"}):
        "a delay's phase lag grows with frequency without end, a lag's stops at 90°: a record "
        "with a chirp well above 1/(2π T_m) tells them apart",
    frozenset({"payload", "gravity"}):
        "a payload's torque follows the acceleration, gravity's the angle: a record held at "
        "several angles, or a slow sweep over a wide angle, tells them apart",
    frozenset({"stribeck", "torque_offset"}):
        "Stribeck friction acts only near zero speed and opposes the motion, an offset acts "
        "always in one direction: a record with slow reversals both ways tells them apart",
}
"""What tells two effects apart, by pair: an input that excites them differently or a sensor."""


BY_HOOK: dict[str, str] = {
    "structure": "changes mass or stiffness: a record through the first resonance (a chirp) or "
                 "an accelerometer at the tip",
    "friction": "acts through the joint speed: a slow record with reversals",
    "loads": "depends on the angle: a record over a wide range of angles",
    "input_torque": "changes the torque's timing: a chirp to high frequency",
    "readings": "changes only what a sensor reads: a second sensor of the same quantity",
}
"""What shows an effect, by the model hook it acts through, where :data:`TELLS_APART` names no
pair."""


@dataclass(frozen=True)
class Rule:
    """One kind of claim: what it says and the condition on the statistics that allows it."""

    name: str
    says: str
    when: str


RULES: dict[str, Rule] = {r.name: r for r in (
    Rule("ranking", "the order of a step's candidates and the criterion it follows",
         "candidates confirmed by a refit come first, by the refit's likelihood ratio LR "
         "(largest first); the others follow by the score test's p-value (smallest first, "
         "ties by the larger S − dof)"),
    Rule("explains", "the effect explains the misfit it removed",
         "the effect was added at this step and kept in the final model"),
    Rule("withdrawn", "the effect was added, then withdrawn",
         "the effect was added at this step, removed less than MIN_EXPLAINED (90 %) of the "
         "misfit above the noise and did not lower the held-out error (the mean over the "
         "channels), and the final residuals are not noise"),
    Rule("lower", "not added: its refit gain is lower than the added effect's",
         "the refit confirmed the effect but another confirmed candidate's LR is larger"),
    Rule("on_bound", "not added: its refit ends on a bound of its own parameters",
         "the refit ended within ON_BOUND (0.1 %) of a bound of one of the effect's own "
         "parameters (not the null side), after that bound was moved out once to the effect's "
         "physical limit where it states one and the bound was not given: the bound, not the "
         "records, set the value, so it is not an explanation"),
    Rule("not_confirmed", "not added: the refit did not confirm it",
         "the effect was refitted and its LR p-value is not below the step's level, or the "
         "BIC did not fall, or its parameters ended on their null-side bound"),
    Rule("not_refitted", "significant, but not refitted",
         "the score (or profile) test is significant at the step's level, but S is below "
         "CONFIRM_RATIO (10 %) of the best S or more significant candidates filled the "
         "refits"),
    Rule("not_significant", "not significant",
         "the score test's p-value is not below the step's level (and no profile scan "
         "found it)"),
    Rule("refit_gain", "what a refit lowers",
         "stated for every candidate: a refit's LR and share of the misfit above the noise "
         "when it was refitted, else the score S, the first-order drop of −2 log L"),
    Rule("alternative", "another candidate fits about equally well",
         "two candidates were confirmed and their refits' LRs differ by less than "
         f"ALTERNATIVE_LR ({ALTERNATIVE_LR:g}, the χ²₁ 95 % quantile); both are named with "
         "what tells them apart (a stated table by pair, else by the hook each acts through)"),
    Rule("base_on_bound", "a base parameter ends on a bound",
         "a fitted base parameter lies within ON_BOUND (0.1 %) of one of its bounds at the "
         "step's fit: the bound, not the records, set it (it may stand in for a missing "
         "effect)"),
    Rule("resonance", "a resonance shift points to the effect",
         "the effect changes mass or stiffness and a resonance's measured and model "
         "frequencies differ by more than the records' frequency resolution 1/T; for an "
         "effect that can only lower the resonances (payload, root compliance), only when "
         "the model resonates too high"),
    Rule("lag", "the residual follows the torque as a late torque leaves it",
         "the effect delays the torque (an input effect with a parameter in seconds), the "
         "residual–torque correlation peaks outside its 95 % band at a positive lag, and "
         "there the model's own output rate correlates with the torque with the opposite "
         f"sign and at least {RATE_SHARE:g} of its peak strength"),
    Rule("concentration", "the misfit lies where the effect acts",
         "the effect acts through friction or a load and one operating condition holds more "
         f"than {CONCENTRATION:g} times its share of the time of the misfit"),
    Rule("torque_map", "the missing torque's shape, and the formula effect made of it",
         "stated where the residuals are not noise and no candidate was confirmed at the last "
         "step: the missing hub torque is estimated at the final model and mapped on terms of "
         "the state and input (jaxflex.torque_regression, BOOTSTRAP (20) resamples); at noise "
         "level, or explaining under PARTLY (30 %) of its variance (a sensor, not the "
         "dynamics), no formula is proposed and the map's words say so; otherwise its terms "
         "become a formula effect, each coefficient a parameter bounded by ±BOUND_FACTOR (5) "
         "times the map's value, refitted as a candidate at the run's level alone (LR, BIC, "
         "bound rules); it is added, and 'the missing torque looks like' its refitted "
         "formula with the fitted and held-out errors before and after, only when the refit "
         "confirms it and, with held-out records, their error falls (without held-out "
         "records the LR test alone decides; the map was found on the same records, so the "
         "held-out error is the test that counts); where the missing torque cannot be "
         "estimated on the model, the error says why"),
    Rule("noise", "a channel's residual is consistent with the measurement noise",
         f"the channel's own noise test passes: white noise, RMS within {RMS_RATIO_LIMIT:g} σ "
         "and Ljung–Box p not below the level; quantised, the residual beyond ±q/2 within "
         f"{QUANTISED_EXCESS_LIMIT:g} steps RMS; the title states the statistic either way"),
)}
"""The rules, by name; a claim is made only where its rule's condition holds."""


def _inner(effect: AbstractEffect) -> AbstractEffect:
    return effect.inner if isinstance(effect, Variant) else effect


def _hooks(effect: AbstractEffect) -> set[str]:
    """Which model hooks an effect overrides."""
    inner = _inner(effect)
    return {h for h in ("structure", "friction", "loads", "input_torque", "signal_torque")
            if getattr(type(inner), h) is not getattr(AbstractEffect, h)}


def delays_the_torque(effect: AbstractEffect) -> bool:
    """An input effect with a parameter in seconds (a delay, a lag): the lag rule applies."""
    return "input_torque" in _hooks(effect) and any(
        p.unit == "s" for p in _inner(effect).parameters)


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
            unit = "" if unit in ("1", "-") else unit
            parts.append(f"{name} = {value:.3g} {unit}".rstrip())
    return ", ".join(parts)


def _p(p: float) -> str:
    return f"{p:.2g}"


def _ms(seconds: float) -> str:
    """A time in milliseconds, to three digits (``"0.96 ms"``, ``"58 ms"``)."""
    return f"{1e3 * seconds:.3g} ms"


def percent(share: float) -> str:
    """A share as a whole percentage, ``"12 %"``; never ``"-0 %"``."""
    text = f"{100 * share:.0f}"
    return f"{'0' if text == '-0' else text} %"


# --- the statistics -----------------------------------------------------------------------------


def _resonance(effect: AbstractEffect, diagnosis: Diagnosis | None) -> dict[str, Any] | None:
    """The resonance shift that points most to ``effect``: the largest relative to the
    resolution, among the significant ones of the allowed sign (``cited``), else the largest."""
    if ("structure" not in _hooks(effect) or diagnosis is None or diagnosis.frf is None
            or not diagnosis.frf.resonances):
        return None
    lowers = _inner(effect).name in LOWERS_FREQUENCIES

    def allowed(s):
        return s.significant and (not lowers or s.shift_hz > 0)

    def size(s):
        return abs(s.shift_hz) / s.resolution_hz if s.resolution_hz > 0 else math.inf

    shifts = diagnosis.frf.resonances
    s = max(shifts, key=lambda s: (allowed(s), size(s)))
    return {"measured_hz": s.measured_hz, "model_hz": s.model_hz, "shift_hz": s.shift_hz,
            "resolution_hz": s.resolution_hz, "lowers_only": lowers, "cited": allowed(s)}


def _lag(channel: ChannelDiagnosis) -> dict[str, Any]:
    xc, rate = channel.input_correlation, channel.rate_correlation
    k = xc.peak_index
    rate_at = float(rate.values[k]) if rate is not None else math.nan
    rate_peak = float(max(abs(rate.values))) if rate is not None else math.nan
    cited = bool(xc.significant and xc.peak_lag_s > 0 and rate is not None
                 and xc.peak_value * rate_at < 0 and abs(rate_at) >= RATE_SHARE * rate_peak)
    return {"channel": channel.channel, "lag_s": xc.peak_lag_s, "value": xc.peak_value,
            "band": xc.band, "rate_value": rate_at, "rate_peak": rate_peak, "cited": cited}


def _lag_evidence(effect: AbstractEffect, diagnosis: Diagnosis | None) -> dict[str, Any] | None:
    """The residual–torque correlation of the first channel where it points to a late torque
    (``cited``), else of the first channel; only for an effect that delays the torque."""
    if not delays_the_torque(effect) or diagnosis is None or not diagnosis.channels:
        return None
    lags = [_lag(c) for c in diagnosis.channels.values()]
    return next((g for g in lags if g["cited"]), lags[0])


def _concentration(effect: AbstractEffect, diagnosis: Diagnosis | None) -> dict[str, Any] | None:
    if not _hooks(effect) & {"friction", "loads"} or diagnosis is None:
        return None
    conds = sorted(diagnosis.localisation.conditions, key=lambda c: -c.concentration)
    if not conds:
        return None
    c = conds[0]
    return {"condition": c.condition, "share": c.combined, "time_share": c.time_share,
            "concentration": c.concentration, "cited": bool(c.concentration > CONCENTRATION)}


def collect_evidence(result: ScoreResult, effect: AbstractEffect, diagnosis: Diagnosis | None,
                     refit: Any = None, *, level: float, holdout_error: float | None = None,
                     skipped: str | None = None) -> dict[str, Any]:
    """The named statistics of one candidate at one step.

    ``refit`` is its :class:`~jaxflex.discovery.Confirmation` (``None`` if not refitted),
    ``level`` the step's level of each test (α over the candidates), ``holdout_error`` the
    step's held-out relative error (the mean over the channels) and ``skipped`` why a
    significant candidate was not refitted (``"ratio"``: its S is below the refit threshold,
    ``"full"``: more significant ones filled the refits).
    """
    ev: dict[str, Any] = {
        "score": {"S": result.statistic, "dof": result.dof, "p_value": result.p_value,
                  "level": level, "significant": result.significant},
        "estimate": dict(result.estimate),
        "units": dict(result.units),
        "profile": None if result.profile_drop is None else {
            "drop": result.profile_drop, "p_value": result.profile_p_value,
            "significant": bool(result.profile_p_value is not None
                                and result.profile_p_value < level)},
        "refit": None,
        "refit_skipped": skipped,
        "holdout_error_before": holdout_error,
        "resonance": _resonance(effect, diagnosis),
        "lag": _lag_evidence(effect, diagnosis),
        "concentration": _concentration(effect, diagnosis),
    }
    own = {p.name: p.unit for p in effect.parameters}  # with those fitted from a start (v_s)
    ev["units"] |= {n: u for n, u in own.items() if n not in ev["units"]}
    if refit is not None:
        names = dict.fromkeys([*result.parameters, *own])
        seconds = {n: refit.params[n] for n, u in own.items() if u == "s" and n in refit.params}
        if ev["lag"] is not None and seconds:  # the refit's own time, beside the peak lag
            ev["lag"]["fitted_s"] = seconds
        ev["refit"] = {"lr": refit.lr, "p_value": refit.p_value, "level": refit.level,
                       "delta_bic": refit.delta_bic, "explained": refit.explained,
                       "confirmed": refit.confirmed, "at_null": refit.at_null,
                       "on_bound": dict(refit.on_bound),
                       "bounds": {n: list(b) for n, b in refit.bounds.items()},
                       "widened": {n: list(b) for n, b in refit.widened.items()},
                       "params": {n: refit.params[n] for n in names if n in refit.params},
                       "holdout_error": refit.holdout_error}
    return ev


def ranking_key(result: ScoreResult) -> tuple:
    """The order of :data:`RULES` ``"ranking"``: confirmed by LR, then by score p-value."""
    refit = result.evidence.get("refit")
    if refit is not None and refit["confirmed"]:
        return (0, -refit["lr"], 0.0)
    return (1, result.p_value, -(result.statistic - result.dof))


def ranked_by(result: ScoreResult) -> str:
    """The criterion that placed ``result``: ``"LR"`` or ``"p-value"``."""
    return "LR" if ranking_key(result)[0] == 0 else "p-value"


# --- the claims ---------------------------------------------------------------------------------


def status_of(result: ScoreResult, added: str | None, chosen: str | None,
              withdrawn: Sequence[str]) -> str:
    """The status rule of a candidate: what happened to it at its step.

    ``added`` is the effect the next kept step added (``None``: none), ``chosen`` the one the
    loop chose at this step (the first confirmed), ``withdrawn`` the run's withdrawn effects.
    """
    ev = result.evidence
    refit = ev.get("refit")
    if result.effect == added:
        return "explains"
    if result.effect == chosen and result.effect in withdrawn:
        return "withdrawn"
    if refit is not None:
        if refit["confirmed"]:
            return "lower"
        return "on_bound" if refit.get("on_bound") else "not_confirmed"
    profile = ev.get("profile") or {}
    if ev["score"]["significant"] or profile.get("significant"):
        return "not_refitted"
    return "not_significant"


def _held(ev: Mapping[str, Any]) -> str:
    before, after = ev.get("holdout_error_before"), (ev.get("refit") or {}).get("holdout_error")
    if before is None or after is None:
        return ""
    return f"; held-out error (mean over the channels) {100 * before:.3g} % → {100 * after:.3g} %"


def _refit_gain(ev: Mapping[str, Any]) -> str:
    refit = ev.get("refit")
    if refit is not None:
        if refit["lr"] < 0:  # an LR is never negative: the refit ended worse
            return (f"its refit ({_magnitude(refit['params'], ev['units'])}) ended worse than "
                    f"the model without it: −2 log L rose by {-refit['lr']:.3g}{_held(ev)}")
        return (f"its refit ({_magnitude(refit['params'], ev['units'])}) lowers −2 log L by "
                f"LR = {refit['lr']:.3g} (p = {_p(refit['p_value'])}), "
                f"{percent(refit['explained'])} of the misfit above the noise{_held(ev)}")
    return (f"to first order a refit would lower −2 log L by S = {ev['score']['S']:.3g} "
            f"(one-step estimate {_magnitude(ev['estimate'], ev['units'])})")


def _amount(value: float, unit: str) -> str:
    """``0.4 rad/(N m)``, a mass in grams, a time in milliseconds (as :func:`_magnitude`)."""
    return _magnitude({"x": value}, {"x": unit})[len("x = "):]


def bound_words(name: str, side: str, bound: float, unit: str) -> str:
    """``"the upper bound of c_r (0.4 rad/(N m))"``."""
    return f"the {side} bound of {name} ({_amount(bound, unit)})"


def ends_on_bound(refit: Mapping[str, Any], units: Mapping[str, str]) -> str:
    """Why a refit that ended on a bound is no explanation, in words: which bound, and whether
    it was moved out to the effect's physical limit first."""
    parts = []
    for name, side in refit["on_bound"].items():
        bound = refit["bounds"][name][0 if side == "lower" else 1]
        unit = units.get(name, "")
        text = bound_words(name, side, bound, unit)
        before = (refit.get("widened") or {}).get(name)
        if before is not None:
            old = before[0 if side == "lower" else 1]
            text += (f", its physical limit (the bound {_amount(old, unit)} was moved out to it "
                     "and the effect refitted)")
        parts.append(text)
    return f"its refit ends on {' and '.join(parts)}: not an explanation"


def _verdict(status: str, ev: Mapping[str, Any], chosen: str | None,
             min_explained: float) -> str:
    refit = ev.get("refit") or {}
    score = ev["score"]
    if status == "explains":
        return (f"added and kept: the refit ({_magnitude(refit['params'], ev['units'])}) "
                f"explains {percent(refit['explained'])} of the misfit above the noise "
                f"(LR = {refit['lr']:.3g}, p = {_p(refit['p_value'])}){_held(ev)}")
    if status == "withdrawn":
        return (f"added, then withdrawn (it removed less than {100 * min_explained:.0f} % of "
                f"the misfit above the noise and did not lower the held-out error): "
                f"{_refit_gain(ev)}")
    if status == "lower":
        return (f"not added, its refit gain is lower than {chosen}'s: "
                f"{_refit_gain(ev)}")
    if status == "on_bound":
        return f"not added: {ends_on_bound(refit, ev['units'])}: {_refit_gain(ev)}"
    if status == "not_confirmed":
        why = []
        if refit["lr"] >= 0:  # else the refit gain says it ended worse
            if not refit["p_value"] < refit["level"]:
                why.append(f"LR p = {_p(refit['p_value'])} not below {_p(refit['level'])}")
            if not refit["delta_bic"] < 0:
                why.append(f"BIC rises by {refit['delta_bic']:.3g}")
        if refit["at_null"]:
            why.append("its parameters ended on their null-side bound")
        because = f" ({'; '.join(why)})" if why else ""
        return f"not added, not confirmed{because}: {_refit_gain(ev)}"
    if status == "not_refitted":
        why = {"ratio": "S below 10 % of the best",
               "full": "more significant candidates filled the refits"}.get(
            ev.get("refit_skipped"), "no refit was run")
        return (f"significant (S = {score['S']:.3g}, p = {_p(score['p_value'])}) but not "
                f"refitted ({why}): {_refit_gain(ev)}")
    level = (f", not below {_p(score['level'])}" if math.isfinite(score["level"]) else "")
    return f"not significant (p = {_p(score['p_value'])}{level}): {_refit_gain(ev)}"


def claims(result: ScoreResult, status: str, *, chosen: str | None = None,
           min_explained: float = 0.9,
           alternatives: Sequence[Mapping[str, Any]] = ()) -> list[dict[str, str]]:
    """The claims ``result``'s evidence allows, each ``{"rule": name, "text": sentence}``;
    ``alternatives`` are the step's (:func:`alternatives`): those that name the result add
    theirs."""
    ev = result.evidence
    out = [{"rule": status, "text": _verdict(status, ev, chosen, min_explained)}]
    out += [{"rule": "alternative", "text": a["text"]} for a in alternatives
            if result.effect in a["effects"]]
    res = ev.get("resonance")
    if res and res["cited"]:
        side = "high" if res["shift_hz"] > 0 else "low"
        out.append({"rule": "resonance", "text": (
            f"resonance measured at {res['measured_hz']:.2f} Hz, model {res['model_hz']:.2f} Hz "
            f"({abs(res['shift_hz']):.2f} Hz too {side}, resolution "
            f"{res['resolution_hz']:.2g} Hz)")})
    lag = ev.get("lag")
    if lag and lag["cited"]:
        fitted = "".join(f"; the refit's {n} is {_ms(v)}, a late response of any size leaves "
                         f"this sign" for n, v in (lag.get("fitted_s") or {}).items())
        out.append({"rule": "lag", "text": (
            f"{lag['channel']} residual correlates most with the torque "
            f"{_ms(lag['lag_s'])} before it ({lag['value']:+.2f}, band "
            f"±{lag['band']:.2g}), where the model's own {lag['channel']} rate correlates "
            f"{lag['rate_value']:+.2f}: the residual has the opposite sign of the rate, as a "
            f"late response leaves it{fitted}")})
    conc = ev.get("concentration")
    if conc and conc["cited"]:
        out.append({"rule": "concentration", "text": (
            f"{percent(conc['share'])} of the misfit in '{conc['condition']}' "
            f"({percent(conc['time_share'])} of the time)")})
    return out


def sentence(result: ScoreResult) -> str:
    """The candidate's explanation: its claims joined (the verdict first, then the evidence)."""
    where = f" ({result.setting})" if result.setting else ""
    parts = [c["text"] for c in result.claims]
    text = f"{result.effect}{where}: {parts[0]}"
    if len(parts) > 1:
        text += ". Evidence: " + "; ".join(parts[1:])
    return text + "."


def explain(result: ScoreResult, effect: AbstractEffect, diagnosis: Diagnosis | None,
            level: float | None = None) -> str:
    """The claims on one score test outside the loop (no refit): its verdict by the score
    alone and the evidence of ``diagnosis`` that points to ``effect``, by :data:`RULES`.

    ``level`` is the test's level (default: none stated; ``result.significant`` decides)."""
    ev = collect_evidence(result, effect, diagnosis, level=math.nan if level is None else level)
    r = dataclasses.replace(result, evidence=ev)
    status = status_of(r, None, None, ())
    r = dataclasses.replace(r, status=status, claims=tuple(claims(r, status)))
    return sentence(r)


def tells_apart(a: str, b: str, effects: Mapping[str, AbstractEffect] | None = None) -> str:
    """What tells candidates ``a`` and ``b`` apart: :data:`TELLS_APART`'s sentence for the pair,
    else :data:`BY_HOOK`'s for the hook each acts through (``effects``: each candidate's effect
    by name; one not given: by its registry entry)."""
    from jaxflex.effects import get_effect

    def effect(name: str) -> AbstractEffect:
        return (effects or {}).get(name) or get_effect(name)

    names = frozenset({_inner(effect(a)).name, _inner(effect(b)).name})
    if names in TELLS_APART:
        return TELLS_APART[names]
    words = [f"{n} " + "; ".join(BY_HOOK[h] for h in sorted(_hooks(effect(n)) or {"readings"}))
             for n in (a, b)]
    return " — ".join(words) + " — tells them apart"


def alternatives(ranking: Sequence[ScoreResult],
                 effects: Mapping[str, AbstractEffect] | None = None) -> list[dict[str, Any]]:
    """The :data:`RULES` ``"alternative"`` of a ranked step: each confirmed candidate whose
    refit's LR lies within :data:`ALTERNATIVE_LR` of the first's, with the first, the LRs and
    what tells them apart (``effects``: each candidate's effect, by name)."""
    if not ranking or ranked_by(ranking[0]) != "LR":
        return []
    first = ranking[0]
    lr0 = first.evidence["refit"]["lr"]
    out = []
    for r in ranking[1:]:
        refit = r.evidence.get("refit")
        if refit is None or not refit["confirmed"] or lr0 - refit["lr"] >= ALTERNATIVE_LR:
            continue
        apart = tells_apart(first.effect, r.effect, effects)
        out.append({
            "effects": [first.effect, r.effect], "lr": [lr0, refit["lr"]],
            "difference": lr0 - refit["lr"], "threshold": ALTERNATIVE_LR,
            "tells_apart": apart,
            "text": (f"{first.effect} and {r.effect} fit about equally well (LR {lr0:.1f} and "
                     f"{refit['lr']:.1f} differ by {lr0 - refit['lr']:.2g} < "
                     f"{ALTERNATIVE_LR:g}, the χ²₁ 95 % quantile): {apart}")})
    return out


def annotate(steps: Sequence[Any], withdrawn: Sequence[str], min_explained: float,
             effects: Mapping[str, AbstractEffect] | None = None) -> list[Any]:
    """The steps with every ranked candidate's status, claims and explanation set, and each
    step's :func:`alternatives` (``effects``: each candidate's effect, by name)."""
    out = []
    for i, step in enumerate(steps):
        added = steps[i + 1].added if i + 1 < len(steps) else None
        added = None if added in withdrawn else added  # a withdrawn effect explains nothing
        ranking = list(step.ranking)
        chosen = (ranking[0].effect if ranking and ranked_by(ranking[0]) == "LR" else None)
        close = alternatives(ranking, effects)
        new = []
        for rank, r in enumerate(ranking, start=1):
            status = status_of(r, added, chosen, withdrawn)
            r = dataclasses.replace(r, status=status, rank=rank)
            r = dataclasses.replace(r, claims=tuple(
                claims(r, status, chosen=chosen, min_explained=min_explained,
                       alternatives=close)))
            new.append(dataclasses.replace(r, explanation=sentence(r)))
        out.append(dataclasses.replace(step, ranking=tuple(new), alternatives=tuple(close)))
    return out


def ranking_line(structure: str, ranking: Sequence[ScoreResult], top: int = 3) -> str:
    """The ``"ranking"`` claim of one step: its first ``top`` candidates, in order, each with
    the value of the criterion that placed it."""
    parts = []
    for r in ranking[:top]:
        lr = (r.evidence.get("refit") or {}).get("lr")
        if ranked_by(r) == "LR":
            parts.append(f"{r.effect} (LR={lr:.3g}; S={r.statistic:.3g})")
        else:
            extra = (f", profile drop {r.profile_drop:.3g}" if r.profile_drop else "")
            parts.append(f"{r.effect} (p={_p(r.p_value)}, S={r.statistic:.3g}{extra})")
    return (f"after '{structure}', ranked by refit LR among the confirmed, then by score "
            f"p-value: {', '.join(parts)}")


def noise_claim(channel: ChannelDiagnosis, alpha: float) -> tuple[bool, str, str]:
    """The ``"noise"`` rule for one channel's residual: (consistent, the verdict, the statistic
    that decided it), e.g. ``(False, "misfit", "RMS 77 σ > 1.3 σ; Ljung-Box p = 0 < 0.01")``."""
    if channel.noise.kind == "quantised":
        beyond = channel.beyond_quantisation
        ok = channel.consistent(alpha)
        stat = (f"{beyond:.2g} steps RMS beyond ±q/2 {'≤' if ok else '>'} "
                f"{QUANTISED_EXCESS_LIMIT:g}" if beyond is not None else "no quantisation test")
    else:
        ratio, p = channel.rms_ratio, channel.whiteness.p_value
        ok = channel.consistent(alpha)
        stat = (f"RMS {ratio:.2g} σ {'≤' if ratio <= RMS_RATIO_LIMIT else '>'} "
                f"{RMS_RATIO_LIMIT:g} σ; Ljung-Box p = {_p(p)} "
                f"{'≥' if channel.whiteness.white(alpha) else '<'} {_p(alpha)}")
    return ok, "consistent with noise" if ok else "misfit", stat


__all__ = [
    "ALTERNATIVE_LR",
    "RULES",
    "Rule",
    "TELLS_APART",
    "alternatives",
    "annotate",
    "claims",
    "collect_evidence",
    "explain",
    "noise_claim",
    "percent",
    "ranking_key",
    "ranking_line",
    "tells_apart",
]
