"""Stribeck friction: static friction above the Coulomb level, fading with speed."""

from __future__ import annotations

import math
from typing import ClassVar

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array

from jaxflex.effects._base import Effect
from jaxflex.parameters import ParameterSpec, Params

STRIBECK_VELOCITY_GRID: tuple[float, ...] = (0.03, 0.1, 0.3)
"""Stribeck velocities (rad/s) that :meth:`Stribeck.grid` profiles over."""


class Stribeck(Effect):
    """Adds ``Δτ_s · exp(−(|θ'|/v_s)^δ) · tanh(θ'/ω_s)`` to the joint friction.

    ``Δτ_s = tau_s − tau_c ≥ 0`` is the excess of the breakaway (static) torque over the Coulomb
    level; at rest the total friction reaches ``tau_s`` and above a few ``v_s`` it falls back to
    ``tau_c + b_v θ'``. The Stribeck velocity ``v_s`` and shape exponent ``δ`` are fixed
    constructor fields, not fitted: ``v_s`` is undefined when ``Δτ_s = 0``, so a score test at
    the null uses the default ``v_s = 0.1 rad/s`` and the discovery loop may profile it over
    :meth:`grid`. ``|θ'|^δ`` is written as ``(θ'²/v_s²)^{δ/2}`` with a zero-safe power, so the law
    is differentiable at rest for any ``δ > 0``; it keeps ``f(0) = 0`` and
    ``sign f(v) = sign v``, which the simulator's implicit friction solve relies on.
    """

    v_s: float = eqx.field(static=True, default=0.1)
    delta: float = eqx.field(static=True, default=2.0)

    name: ClassVar[str] = "stribeck"
    parameters: ClassVar[tuple[ParameterSpec, ...]] = (
        ParameterSpec(
            "delta_tau_s",
            "N m",
            lower=1e-3,
            upper=0.2,
            reference=0.03,
            description="static minus Coulomb friction torque (tau_s - tau_c)",
            null=0.0,
        ),
    )
    description: ClassVar[str] = (
        "Stribeck friction in the joint: near rest the friction torque rises from the Coulomb "
        "level tau_c to a breakaway level tau_s = tau_c + delta_tau_s, and decays back as "
        "exp(-(|v|/v_s)^delta) once the joint slides faster than the Stribeck velocity v_s "
        "(default 0.1 rad/s, shape delta = 2). Lubricated gears and bearings show it."
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
        """One effect per Stribeck velocity, for profiling ``v_s`` in a discovery loop."""
        return tuple(cls(v_s=v) for v in velocities)

    def friction(self, params: Params, velocity: Array, omega_s: float) -> Array:
        ratio = velocity**2 / self.v_s**2  # (|v|/v_s)²
        positive = ratio > 0.0
        power = jnp.where(positive, jnp.where(positive, ratio, 1.0) ** (0.5 * self.delta), 0.0)
        return params["delta_tau_s"] * jnp.exp(-power) * jnp.tanh(velocity / omega_s)
