"""A pure time delay between the commanded and the applied joint torque."""

from __future__ import annotations

from typing import ClassVar

import jax
import jax.numpy as jnp
from jaxtyping import Array, Float

from jaxflex.effects._base import AbstractEffect
from jaxflex.parameters import ParameterSpec, Params


class Delay(AbstractEffect):
    """The joint receives the recorded torque ``d`` seconds late.

    The recorded torque is a zero-order hold on a grid of step ``h``; its delayed copy, averaged
    over each step, is exactly the linear interpolation

        ``τ_d[i] = (1 − φ)·τ[i − k] + φ·τ[i − k − 1]``,   ``k = ⌊d/h⌋``, ``φ = d/h − k``,

    with zeros before the start. It is linear in ``φ`` within a step, so it is differentiable in
    ``d`` everywhere except at whole steps, where it takes the right derivative — at ``d = 0``
    ``∂τ_d/∂d = (τ[i−1] − τ[i])/h``, the score of a small delay.
    """

    name: ClassVar[str] = "delay"
    parameters: ClassVar[tuple[ParameterSpec, ...]] = (
        ParameterSpec(
            "d",
            "s",
            lower=1e-4,
            upper=0.05,
            reference=0.005,
            description="input time delay",
            null=0.0,
        ),
    )
    limits: ClassVar[dict[str, tuple[float, float]]] = {"d": (0.0, 0.5)}
    """A dead time of half a second is a different drive, not a latency."""
    description: ClassVar[str] = (
        "A dead time d between the torque the record shows and the torque the joint feels: "
        "communication and amplifier latency, or a torque estimate time-stamped early. "
        "The whole response shifts later by d without changing shape."
    )
    signature: ClassVar[str] = (
        "residuals look like the time derivative of the outputs (largest at torque steps and "
        "fast transients); the FRF phase lags linearly with frequency, magnitudes unchanged"
    )

    def input_torque(self, params: Params, torque: Float[Array, " m"], h: float) -> Array:
        steps = params["d"] / h
        whole = jax.lax.stop_gradient(jnp.floor(steps))
        frac = steps - whole
        index = jnp.arange(torque.shape[0]) - whole.astype(jnp.int32)

        def shifted(i):
            return jnp.where(i >= 0, torque[jnp.maximum(i, 0)], 0.0)

        return (1.0 - frac) * shifted(index) + frac * shifted(index - 1)
