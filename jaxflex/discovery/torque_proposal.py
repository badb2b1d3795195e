"""What ``discover`` proposes where the library explains nothing: the missing torque's map
turned into a formula effect, and the words of the ``"torque_map"`` claim.

When no library candidate is confirmed at the last step and the residuals are not noise, the
missing hub torque is estimated at the final model
(:func:`jaxflex.missing_torque.estimate_missing_torque`) and regressed on terms of the state
and input (:func:`jaxflex.torque_regression.torque_map`, :data:`BOOTSTRAP` resamples). Where
the map's verdict is one of :data:`PROPOSES`, :func:`formula_of` writes its selected terms as a
:class:`~jaxflex.effects.formula.FormulaTorque` whose coefficients are parameters (``c1``,
``c2``, ...), and ``discover`` refits it as a candidate; :func:`claim` words the outcome.
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping
from typing import Any

from jaxflex.effects.formula import FormulaError, FormulaTorque
from jaxflex.torque_regression import MAP_RULES, TorqueMap, term_product

BOOTSTRAP = 20
"""The map's bootstrap resamples inside ``discover`` (``torque_map`` itself takes 50): enough
for the inclusion probabilities at the :data:`~jaxflex.torque_regression.STABLE` threshold,
few enough to keep the run short."""

BOUND_FACTOR = 5.0
"""Each coefficient ``cK`` of the proposed formula is bounded by ``±BOUND_FACTOR·|coefficient|``
around 0 (0 is its null: the formula vanishes there, so the score test judges it), its
reference the map's coefficient."""

PROPOSES = ("explained", "partly")
"""The map's verdicts (:data:`~jaxflex.torque_regression.MAP_RULES`) whose expression is refitted
as a formula effect: the missing torque is (partly) a function of state and input."""

EFFECT_NAME = "missing_torque"
"""The proposed formula effect's name in models, fits and reports."""


def formula_of(tmap: TorqueMap, name: str = EFFECT_NAME) -> FormulaTorque | None:
    """The map's selected terms as a formula torque ``c1*term1 + c2*term2 + ...`` (the
    constant ``1`` a parameter alone), or ``None`` where the verdict proposes nothing or the
    map selected no term the formula can state (a term that mixes the state with the input)."""
    if tmap.verdict not in PROPOSES or not tmap.coefficients:
        return None
    parts, parameters = [], {}
    for k, (term, value) in enumerate(tmap.coefficients.items(), start=1):
        c = f"c{k}"
        parts.append(term_product(c, term))
        width = BOUND_FACTOR * abs(value) if value != 0 else 1.0
        parameters[c] = (float(value), -width, width)
    try:
        return FormulaTorque(" + ".join(parts), parameters, name=name)
    except FormulaError:
        return None


def fitted_expression(effect: FormulaTorque, params: Mapping[str, float]) -> str:
    """The formula with its fitted coefficients written in (four significant digits)."""
    text = re.sub(r"\b(c\d+)\b", lambda m: f"{params[m.group(1)]:.4g}", effect.expression)
    return text.replace("+ -", "- ")


def _errors(errors: Mapping[str, float | None]) -> str:
    """``"fitted NRMSE 4.1 %, held-out error 6.3 %"`` of the mean errors (percent)."""
    out = f"fitted NRMSE {errors['fitted']:.3g} %"
    if errors.get("held_out") is not None:
        out += f", held-out error {errors['held_out']:.3g} %"
    return out


def claim(outcome: Mapping[str, Any]) -> str:
    """The ``"torque_map"`` claim of :data:`~jaxflex.discovery.explain.RULES` on ``outcome``
    (what ``discover`` stores as the report's ``torque_map``)."""
    tmap = outcome["map"]
    verdict = tmap["verdict"]
    if verdict not in PROPOSES:
        if verdict == "noise":
            return f"the torque map is {MAP_RULES[verdict][1]}; no formula is proposed"
        return (f"the torque map finds the missing torque {MAP_RULES[verdict][1]} (explained "
                f"variance {100 * tmap['explained']:.0f} %); no formula is proposed")
    if outcome["effect"] is None:
        return (f"the torque map suggests {tmap['expression']} ({tmap['words']}), but no "
                "formula torque can state it; not added")
    before, after = outcome["error_before"], outcome["error_after"]
    if outcome["added"]:
        return (f"the missing torque looks like {outcome['fitted_expression']} ({tmap['words']}, "
                f"explained variance {100 * tmap['explained']:.0f} %): added as "
                f"{outcome['effect']}; {_errors(before)} before, {_errors(after)} after")
    refit = outcome["refit"]
    if not refit["confirmed"]:
        why = ("its parameters ended on a bound" if refit["on_bound"] else
               f"the refit did not confirm it (LR = {refit['lr']:.3g}, p = "
               f"{refit['p_value']:.2g}, ΔBIC = {refit['delta_bic']:.3g})")
    else:
        why = (f"it did not lower the held-out error ({after['held_out']:.3g} % against "
               f"{before['held_out']:.3g} %)")
    return f"the torque map suggests {tmap['expression']} ({tmap['words']}), but {why}; not added"


def errors(nrmse: Mapping[str, float], held: Mapping[str, Any] | None) -> dict[str, float | None]:
    """A step's errors as the claim states them: the fitted NRMSE and held-out relative error
    (percent), each the mean over the channels."""
    fitted = float(sum(nrmse.values()) / len(nrmse))
    if held is None:
        return {"fitted": fitted, "held_out": None}
    values = list(held["relative_error"].values())
    mean = 100 * float(sum(values) / len(values))
    return {"fitted": fitted, "held_out": mean if math.isfinite(mean) else None}


__all__ = ["BOOTSTRAP", "BOUND_FACTOR", "EFFECT_NAME", "PROPOSES", "claim", "errors",
           "fitted_expression", "formula_of"]
