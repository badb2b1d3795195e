"""A compliant clamp: a rotational spring between the hub and the root of the link."""

from __future__ import annotations

import functools
from collections.abc import Mapping
from typing import ClassVar

import equinox as eqx
import jax.numpy as jnp

from jaxflex.effects._base import AbstractEffect, Structure
from jaxflex.fem import BeamPatterns
from jaxflex.parameters import ParameterSpec, Params
from jaxflex.testbed import Testbed

LINK_COMPLIANCES = 10.0
"""A clamp's physical limit: its compliance at most this many times the link's own bending
compliance ``L/(E I)`` (softer, the link hangs on a hinge: a different arm)."""


@functools.lru_cache(maxsize=16)
def _patterns(length: float, n_elements: int) -> BeamPatterns:
    return BeamPatterns(length, n_elements)


class RootCompliance(AbstractEffect):
    """Releases the clamp ``w'(0) = 0`` into a rotational spring of compliance ``c_r``.

    The root rotation ``ψ = w'(0)`` gets the spring energy ``ψ²/(2 c_r)`` and couples to the
    beam through the stiffness row ``[k_ψψ, kᵀ]`` of the first element. Its inertia is
    neglected (it only moves part of the first element), so ``ψ`` follows the beam statically,
    ``ψ = −c_r kᵀq / (1 + c_r k_ψψ)``, and condenses out of the stiffness:

        ``K_qq ← K_qq − c_r k kᵀ / (1 + c_r k_ψψ)``.

    ``c_r = 0`` is the clamp; ``c_r → ∞`` a pin. ``k_ψψ = EI·root_rotation_stiffness`` and
    ``k = EI·root_rotation_coupling`` come from :class:`~jaxflex.fem.BeamPatterns`; ``EI`` is
    read off the assembled stiffness (its last diagonal entry is ``4 EI/le``), so the effect
    follows the model's testbed without being told it. It must therefore see the plain beam
    stiffness (no other effect may change the tip-rotation stiffness before it).
    """

    name: ClassVar[str] = "root_compliance"
    parameters: ClassVar[tuple[ParameterSpec, ...]] = (
        ParameterSpec(
            "c_r",
            "rad/(N m)",
            lower=3e-3,
            upper=0.4,
            reference=0.03,
            description="rotational compliance of the link clamp",
            null=0.0,
        ),
    )
    description: ClassVar[str] = (
        "The link is not rigidly clamped to the hub: the clamp (screws, a flexible coupling, the "
        "gearbox output) acts as a rotational spring of compliance c_r between the hub and the "
        "root of the beam. The root rotation is condensed statically into the beam stiffness "
        "(its own inertia is neglected), so the link is softer at the root: the bending "
        "frequencies fall and the tip deflects more for the same root strain."
    )
    signature: ClassVar[str] = (
        "lowers the resonances, the first most; the tip deflects more per root strain (strain "
        "gauges under-read the tip motion); rigid-body motion and friction unchanged"
    )

    def physical_limits(self, testbed: Testbed, params: Mapping[str, float]
                        ) -> dict[str, tuple[float, float]]:
        """Up to :data:`LINK_COMPLIANCES` times ``L/(E I)`` at the fitted Young's modulus."""
        bending = float(params["E"]) * testbed.second_moment
        return {"c_r": (0.0, LINK_COMPLIANCES * testbed.length / bending)}

    def structure(self, structure: Structure, params: Params) -> Structure:
        n = structure.mass.shape[0]
        pattern = _patterns(structure.length, (n - 1) // 2)
        bending = structure.stiffness[n - 1, n - 1] / pattern.stiffness[n - 1, n - 1]  # EI
        coupling = bending * jnp.asarray(pattern.root_rotation_coupling)  # k
        root = bending * pattern.root_rotation_stiffness  # k_ψψ
        compliance = params["c_r"]
        stiffness = structure.stiffness - compliance * jnp.outer(coupling, coupling) / (
            1.0 + compliance * root
        )
        return eqx.tree_at(lambda s: s.stiffness, structure, stiffness)
