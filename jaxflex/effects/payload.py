"""A payload at the tip: a point mass and, optionally, its rotary inertia."""

from __future__ import annotations

from collections.abc import Mapping
from typing import ClassVar

import equinox as eqx
import jax.numpy as jnp

from jaxflex.effects._base import AbstractEffect, Structure
from jaxflex.parameters import ParameterSpec, Params
from jaxflex.testbed import Testbed

MASS = ParameterSpec(
    "m_p",
    "kg",
    lower=1e-3,
    upper=0.2,
    reference=0.02,
    description="payload mass at the tip",
    null=0.0,
)
"""The payload's mass; its default bounds suit the reference strip (``--bound m_p=LO:HI``
widens them)."""
ROTARY_INERTIA = ParameterSpec(
    "J_p",
    "kg m^2",
    lower=1e-7,
    upper=1e-4,
    reference=5e-6,
    description="payload inertia about its own centre",
    null=0.0,
)
"""The payload's rotary inertia about its own centre (a rotary payload only)."""
LINK_MASSES = 10.0
"""A payload's physical limit: at most this many times the link's own mass (its rotary inertia:
that mass at the link's length from its centre)."""


class _PayloadParameters:
    """``Payload.parameters``: on an instance ``m_p`` (and ``J_p`` if rotary); on the class,
    every parameter a payload may add."""

    def __get__(self, instance: Payload | None, owner: type | None = None):
        if instance is not None and not instance.rotary:
            return (MASS,)
        return (MASS, ROTARY_INERTIA)


class Payload(AbstractEffect):
    """Tip mass ``m_p`` (and rotary inertia ``J_p`` if ``rotary=True``) fixed to the link end.

    The payload moves with the tip: its velocity is ``L θ' + ẇ_L`` and its angular velocity
    ``θ' + ẇ'_L``, so its kinetic energy ``½ m_p (L θ' + ẇ_L)² + ½ J_p (θ' + ẇ'_L)²`` adds two
    rank-one terms to the mass matrix::

        M += m_p (L e_θ + e_wL)(L e_θ + e_wL)ᵀ + J_p (e_θ + e_w'L)(e_θ + e_w'L)ᵀ

    i.e. ``M_θθ += m_p L² + J_p``, ``M_θ,wL += m_p L``, ``M_θ,w'L += J_p``, ``M_wL,wL += m_p``,
    ``M_w'L,w'L += J_p``. ``e_wL`` is ``structure.tip``; ``w'_L`` is the last coordinate.
    The payload also joins the first moment (``m_p (L e_θ + e_wL)``), so a gravity effect
    acts on it.
    """

    rotary: bool = eqx.field(static=True, default=False)

    name: ClassVar[str] = "payload"
    description: ClassVar[str] = (
        "A rigid payload clamped to the free end of the link: a point mass m_p at x = L and, "
        "with rotary=True, a rotary inertia J_p about its centre. It adds m_p L² + J_p to the "
        "inertia about the joint and loads the tip of the beam, which lowers every bending "
        "frequency; its weight joins the first moment, so gravity acts on it."
    )
    signature: ClassVar[str] = (
        "lowers every resonance, the first most (relative to the link mass); the rigid-body "
        "response slows (more inertia per torque); the friction-dominated stops are unchanged"
    )

    parameters = _PayloadParameters()  # type: ignore[assignment]

    def physical_limits(self, testbed: Testbed, params: Mapping[str, float]
                        ) -> dict[str, tuple[float, float]]:
        """Up to :data:`LINK_MASSES` times the link's mass (a heavier payload is a different
        arm, not an unlogged accelerometer or clamp)."""
        mass = LINK_MASSES * testbed.mass_per_length * testbed.length
        return {"m_p": (0.0, mass), "J_p": (0.0, mass * testbed.length**2)}

    def structure(self, structure: Structure, params: Params) -> Structure:
        n = structure.mass.shape[0]
        hub = jnp.zeros(n).at[0].set(1.0)
        translation = structure.length * hub + structure.tip  # d(tip position)/dq
        mass = structure.mass + params["m_p"] * jnp.outer(translation, translation)
        if self.rotary:
            rotation = hub.at[n - 1].set(1.0)  # d(tip angle)/dq: θ + w'_L
            mass = mass + params["J_p"] * jnp.outer(rotation, rotation)
        first_moment = structure.first_moment + params["m_p"] * translation
        return eqx.tree_at(lambda s: (s.mass, s.first_moment), structure, (mass, first_moment))
