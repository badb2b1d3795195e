"""Gravity in a motion plane tilted from the horizontal."""

from __future__ import annotations

from typing import ClassVar

import jax.numpy as jnp
from jaxtyping import Array, Float

from jaxflex.effects._base import AbstractEffect, Structure
from jaxflex.parameters import ParameterSpec, Params

GRAVITY = 9.81
"""Standard gravitational acceleration, m/s²."""


class Gravity(AbstractEffect):
    """The plane of motion is tilted by ``phi`` from horizontal.

    Gravity's in-plane component ``g sin(phi)`` points down the slope; with ``θ = 0`` along the
    horizontal line of the tilted plane, a mass element at ``x`` along the link rises by
    ``x sin θ + w cos θ``, so (linearised in ``w``) the generalised force is

        ``Q = −g sin(phi) cos θ · F``,  ``F = ∫ [x, N(x)] dm`` = ``structure.first_moment``,

    one load shape with amplitude ``−g sin(phi) cos θ``: on the joint it is the holding torque
    ``−m g sin(phi) (L/2) cos θ`` of the link (plus any payload in the first moment). The
    simulator starts the beam at rest in its static deflection under this load at ``θ = 0``.
    """

    name: ClassVar[str] = "gravity"
    parameters: ClassVar[tuple[ParameterSpec, ...]] = (
        ParameterSpec(
            "phi",
            "rad",
            lower=1e-3,
            upper=0.5,
            reference=0.05,
            description="tilt of the motion plane from horizontal",
            null=0.0,
        ),
    )
    limits: ClassVar[dict[str, tuple[float, float]]] = {"phi": (0.0, 1.5707963267948966)}
    """A plane tilted at most to the vertical."""
    description: ClassVar[str] = (
        "The arm moves in a plane tilted by phi from the horizontal, so gravity's in-plane "
        "component g sin(phi) pulls the link (and any payload) down the slope: a joint torque "
        "-m g sin(phi) (L/2) cos(theta) and a transverse load bending the beam. A levelling "
        "error of the base gives it."
    )
    signature: ClassVar[str] = (
        "joint-angle residual growing with cos(theta): the arm drifts or stops short on the "
        "way down the slope and overshoots on the way up; an offset in the resting tip "
        "deflection; frequencies unchanged"
    )

    def loads(self, structure: Structure, params: Params) -> Float[Array, "1 n"]:
        return structure.first_moment[None, :]

    def load_amplitudes(self, params: Params, angle: Array, velocity: Array) -> Float[Array, " 1"]:
        return (-GRAVITY * jnp.sin(params["phi"]) * jnp.cos(angle))[None]
