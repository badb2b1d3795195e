"""Stribeck friction: static friction above the Coulomb level, fading with speed."""

from __future__ import annotations

import math
from typing import ClassVar

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array

from jaxflex.effects._base import AbstractEffect
from jaxflex.parameters import ParameterSpec, Params

STRIBECK_VELOCITY_GRID: tuple[float, ...] = (0.03, 0.1, 0.3)
"""Stribeck velocities (rad/s) that :meth:`Stribeck.grid` profiles over."""

EXCESS = ParameterSpec(
    "delta_tau_s",
    "N m",
    lower=1e-3,
    upper=0.2,
    reference=0.03,
    description="static minus Coulomb friction torque (tau_s - tau_c)",
    null=0.0,
)
"""The Stribeck excess: zero is the plain Coulomb law, so score tests and refits judge it."""


def velocity_spec(v_s: float) -> ParameterSpec:
    """The Stribeck velocity as a fitted parameter starting at ``v_s``: no null (the law
    vanishes with ``delta_tau_s`` whatever ``v_s``), so a score test leaves it out."""
    return ParameterSpec(
        "v_s",
        "rad/s",
        lower=min(0.005, v_s),
        upper=max(2.0, v_s),
        reference=v_s,
        description="Stribeck velocity: the joint speed over which static friction fades",
    )


class _Parameters:
    """``parameters``: the excess torque and the velocity starting at the instance's ``v_s``
    (on the class, the default instance's)."""

    def __get__(self, instance: Stribeck | None, owner: type[Stribeck]):
        return (EXCESS, velocity_spec((owner() if instance is None else instance).v_s))


class Stribeck(AbstractEffect):
    """Adds ``Δτ_s · exp(−(|θ'|/v_s)^δ) · tanh(θ'/ω_s)`` to the joint friction.

    ``Δτ_s = tau_s − tau_c ≥ 0`` is the excess of the breakaway (static) torque over the Coulomb
    level; at rest the total friction reaches ``tau_s`` and above a few ``v_s`` it falls back to
    ``tau_c + b_v θ'``. The Stribeck velocity ``v_s`` is a parameter too, fitted with ``Δτ_s``
    once the effect is in a model; the field ``v_s`` is where it starts (and its value where
    the parameters do not give it). It is undefined when ``Δτ_s = 0``, so it has no null: a
    score test at the null tests ``Δτ_s`` alone with ``v_s`` at its start, and the discovery
    loop profiles the start over :meth:`grid`. The shape exponent ``δ`` is a fixed field.
    ``|θ'|^δ`` is written as ``(θ'²/v_s²)^{δ/2}`` with a zero-safe power, so the law is
    differentiable at rest for any ``δ > 0``; it keeps ``f(0) = 0`` and ``sign f(v) = sign v``,
    which the simulator's implicit friction solve relies on.
    """

    v_s: float = eqx.field(static=True, default=0.1)
    delta: float = eqx.field(static=True, default=2.0)

    name: ClassVar[str] = "stribeck"
    parameters = _Parameters()  # type: ignore[assignment]
    description: ClassVar[str] = (
        "Stribeck friction in the joint: near rest the friction torque rises from the Coulomb "
        "level tau_c to a breakaway level tau_s = tau_c + delta_tau_s, and decays back as "
        "exp(-(|v|/v_s)^delta) once the joint slides faster than the Stribeck velocity v_s "
        "(fitted; shape delta = 2). Lubricated gears and bearings show it."
    )
    signature: ClassVar[str] = (
        "joint-angle residuals concentrated at starts and stops (later breakaway, earlier "
        "sticking, a smaller final angle); fast motion and the resonances are unchanged"
    )

    def __check_init__(self) -> None:
        for label in ("v_s", "delta"):
            value = getattr(self, label)
            if not (isinstance(value, (int, float)) and value > 0 and math.isfinite(value)):
                raise ValueError(f"stribeck: {label} must be a positive number, got {value!r}")

    @classmethod
    def grid(cls, velocities: tuple[float, ...] = STRIBECK_VELOCITY_GRID) -> tuple[Stribeck, ...]:
        """One effect per start of the Stribeck velocity, for profiling ``v_s`` in a discovery
        loop."""
        return tuple(cls(v_s=v) for v in velocities)

    def friction(self, params: Params, velocity: Array, omega_s: float) -> Array:
        v_s = params["v_s"] if "v_s" in params else self.v_s
        ratio = velocity**2 / v_s**2  # (|v|/v_s)²
        positive = ratio > 0.0
        power = jnp.where(positive, jnp.where(positive, ratio, 1.0) ** (0.5 * self.delta), 0.0)
        return params["delta_tau_s"] * jnp.exp(-power) * jnp.tanh(velocity / omega_s)
