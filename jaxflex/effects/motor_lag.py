"""First-order motor/amplifier lag between the commanded and the joint torque."""

from __future__ import annotations

from typing import ClassVar

import jax
import jax.numpy as jnp
from jaxtyping import Array, Float

from jaxflex.effects._base import AbstractEffect
from jaxflex.parameters import ParameterSpec, Params

_UNDERFLOW = 700.0
"""``exp(−h/T)`` is taken as exactly 0 below ``T = h/700`` (it is < 1e-304 there)."""


class MotorLag(AbstractEffect):
    """The joint torque ``τ_j`` follows the recorded torque ``τ`` through ``T τ_j' = τ − τ_j``.

    For the zero-order-hold input the lag is discretised exactly: with ``a = exp(−h/T)``,

        ``τ_j[i+1] = a·τ_j[i] + (1 − a)·τ[i]``,  ``τ_j[0] = 0``,

    and the simulator receives the average of ``τ_j`` over each step,

        ``τ̄[i] = τ[i] + (τ_j[i] − τ[i])·g``,  ``g = (T/h)(1 − a)``.

    At ``T = 0``, ``a = g = 0`` and ``τ̄ = τ`` exactly; ``a`` is flat there (all its derivatives
    vanish) and ``∂g/∂T = 1/h``, so the gradient at the null is finite: a small lag acts like a
    small delay.
    """

    name: ClassVar[str] = "motor_lag"
    parameters: ClassVar[tuple[ParameterSpec, ...]] = (
        ParameterSpec(
            "T_m",
            "s",
            lower=1e-4,
            upper=0.05,
            reference=0.005,
            description="motor torque time constant",
            null=0.0,
        ),
    )
    limits: ClassVar[dict[str, tuple[float, float]]] = {"T_m": (0.0, 0.5)}
    """An electrical time constant of half a second is no motor's."""
    description: ClassVar[str] = (
        "The joint torque lags the commanded torque as a first-order system with time constant "
        "T_m: the current loop of the amplifier and the motor inductance (L/R) do not let the "
        "torque jump. A step command produces 1 - exp(-t/T_m)."
    )
    signature: ClassVar[str] = (
        "residuals at torque steps shaped like the output derivative (as for a delay) but the "
        "FRF magnitude also rolls off above 1/(2 pi T_m) Hz, with a phase lag saturating at 90°"
    )

    def input_torque(self, params: Params, torque: Float[Array, " m"], h: float) -> Array:
        lag = params["T_m"]
        resolved = lag > h / _UNDERFLOW
        decay = jnp.where(resolved, jnp.exp(-h / jnp.where(resolved, lag, 1.0)), 0.0)
        average_weight = lag / h * (1.0 - decay)  # g = (T/h)(1 − a)

        def step(state, tau):  # τ_j[i+1] = a τ_j[i] + (1 − a) τ[i]; emits τ_j[i]
            return decay * state + (1.0 - decay) * tau, state

        _, state = jax.lax.scan(step, jnp.zeros((), torque.dtype), torque)
        return torque + (state - torque) * average_weight
