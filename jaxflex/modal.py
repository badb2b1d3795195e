"""Modal decomposition of the hub–beam system, the basis the simulator integrates in.

Because ``K`` and the Rayleigh damping ``D = α·P M P + β·K`` both vanish on the hub coordinate
``e_θ``, the rigid rotation ``φ₀ = e_θ/√J`` (``J = M_θθ``) decouples exactly. The remaining
*free-hub* flexible modes solve ``K_qq φ = ω² (M_qq − m mᵀ/J) φ`` (the hub row condensed out, a
symmetric positive-definite problem) and carry a hub rotation ``p = −mᵀφ/J``. In the
M-orthonormal basis ``q = e_θ θ_r + Φ η``:

* ``θ_r'' = u/J``  (the rigid angle, driven by the joint torque ``u``),
* ``η'' + (c + αJ(p pᵀ − diag p²)) η' + ω² η = p u``  with ``c = α(1 + J p²) + β ω²``,

because ``Φᵀ P M P Φ = I + J p pᵀ`` and ``Φᵀ K Φ = diag ω²``. The joint angle is
``θ = θ_r + pᵀη``. The mass-proportional damping therefore only couples modes through a
rank-one term, which the simulator applies explicitly; everything else is diagonal.
"""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array, Float, Scalar

from jaxflex._linalg import cholesky, eigh, solve_lower, solve_upper
from jaxflex.effects._base import Structure


class Modes(eqx.Module):
    """Free-hub flexible modes of one structure (``m = n_dof − 1`` of them, ascending)."""

    omega: Float[Array, " m"]  # natural frequencies, rad/s
    shapes: Float[Array, "n m"]  # M-orthonormal mode shapes over q (first row = hub share p)
    inertia: Scalar  # J = M_θθ, the total inertia about the joint

    @property
    def hub(self) -> Float[Array, " m"]:
        """``p``: the joint rotation of each mode."""
        return self.shapes[0]

    @property
    def frequencies_hz(self) -> Float[Array, " m"]:
        return self.omega / (2.0 * jnp.pi)

    def modal_damping(self, alpha: Scalar, beta: Scalar) -> Float[Array, " m"]:
        """Diagonal modal damping ``c_j = α(1 + J p_j²) + β ω_j²``."""
        return alpha * (1.0 + self.inertia * self.hub**2) + beta * self.omega**2

    def project(self, vectors: Float[Array, "... n"]) -> Float[Array, "... m"]:
        """Flexible modal components ``Φᵀ f`` of generalised force vectors ``f``."""
        return vectors @ self.shapes


def free_hub_modes(structure: Structure) -> Modes:
    """Solve the free-hub eigenproblem of ``structure`` (differentiable, via Cholesky + eigh)."""
    mass, stiffness = structure.mass, structure.stiffness
    inertia = mass[0, 0]
    coupling = mass[1:, 0]
    condensed_mass = mass[1:, 1:] - jnp.outer(coupling, coupling) / inertia
    chol = cholesky(condensed_mass)
    left = solve_lower(chol, stiffness[1:, 1:])  # L⁻¹ K
    sym = solve_lower(chol, left.T).T  # L⁻¹ K L⁻ᵀ
    sym = 0.5 * (sym + sym.T)
    eigvals, eigvecs = eigh(sym)
    elastic = solve_upper(chol.T, eigvecs)  # Φ_q = L⁻ᵀ Y
    hub = -(coupling @ elastic) / inertia
    shapes = jnp.concatenate([hub[None, :], elastic], axis=0)
    omega = jnp.sqrt(jnp.maximum(eigvals, 0.0))
    return Modes(omega=omega, shapes=shapes, inertia=inertia)
