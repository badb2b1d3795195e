"""Physical explanations of a score test's result in the words of the diagnosis."""

from __future__ import annotations

from collections.abc import Mapping

from jaxflex.diagnosis import (
    Diagnosis,
)
from jaxflex.discovery.candidates import Variant
from jaxflex.discovery.scores import ScoreResult
from jaxflex.effects import Effect


def _hooks(effect: Effect) -> set[str]:
    """Which model hooks an effect overrides."""
    inner = effect.inner if isinstance(effect, Variant) else effect
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
            channel = ("joint_angle" if "joint_angle" in diagnosis.channels
                       else next(iter(diagnosis.channels)))
            xc = diagnosis.channels[channel].input_correlation
            label = "angle" if channel == "joint_angle" else channel
            features.append(f"{label} residual correlates with the torque "
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


__all__ = [
    "explain",
]
