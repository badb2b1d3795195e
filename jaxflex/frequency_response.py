"""Analytic frequency response and modes of the linear part of the model.

The linear part is the structure with Rayleigh damping and the *viscous* joint friction only:
``(K + jω D − ω² M) q̂ = e_θ τ̂`` with ``D = α P M P + β K + b_v e_θ e_θᵀ``. The smooth Coulomb
term is left out (it has no small-signal linearisation that holds over a motion: its slope at
rest, tau_c/omega_s, describes a stuck joint), so compare this FRF with measured FRFs of motions
that keep sliding, or use :func:`jaxflex.metrics.h1_frf` on simulated records instead.
"""

from __future__ import annotations

from collections.abc import Mapping

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Complex, Float

from jaxflex.modal import free_hub_modes
from jaxflex.model import Model

FRF_OUTPUTS = ("tip_acceleration", "joint_angle", "tip_deflection")
"""Outputs whose frequency response from the joint torque can be computed."""


def _params(model: Model, params: Mapping[str, ArrayLike]) -> dict[str, Array]:
    model.space.validate(params)
    return {k: jnp.asarray(v, dtype=jnp.float64) for k, v in params.items()}


def natural_frequencies(model: Model, params: Mapping[str, ArrayLike]) -> Float[np.ndarray, " m"]:
    """Undamped free-hub natural frequencies of the flexible modes, Hz, ascending."""
    values = _params(model, params)
    return np.asarray(free_hub_modes(model.structure(values)).frequencies_hz)


def mode_shapes(
    model: Model, params: Mapping[str, ArrayLike], n_modes: int = 3
) -> tuple[Float[np.ndarray, " nodes"], Float[np.ndarray, "nodes k"], Float[np.ndarray, " k"]]:
    """``(x, w, hub)``: nodal deflection of the first ``n_modes`` modes, tip normalised to 1,
    and the hub rotation of each mode in the same scaling (rad per metre of tip deflection)."""
    values = _params(model, params)
    modes = free_hub_modes(model.structure(values))
    shapes = np.asarray(modes.shapes)[:, :n_modes]
    deflection = np.vstack([np.zeros((1, shapes.shape[1])), shapes[1::2]])
    scale = deflection[-1].copy()
    scale[scale == 0] = 1.0
    x = np.linspace(0.0, model.testbed.length, deflection.shape[0])
    return x, deflection / scale, shapes[0] / scale


@eqx.filter_jit
def _frf_core(model: Model, params, omega: Array) -> tuple[Array, Array, Array]:
    structure = model.structure(params)
    mass, stiffness = structure.mass, structure.stiffness
    n = mass.shape[0]
    projector = jnp.eye(n).at[0, 0].set(0.0)
    damping = params["alpha"] * projector @ mass @ projector + params["beta"] * stiffness
    damping = damping.at[0, 0].add(params["b_v"])
    force = jnp.zeros(n).at[0].set(1.0)

    def solve(w):
        dynamic = stiffness + 1j * w * damping - w**2 * mass
        return jnp.linalg.solve(dynamic, force.astype(jnp.complex128))

    q = jax.vmap(solve)(omega)
    angle = q[:, 0]
    tip = q @ structure.tip
    acceleration = -(omega**2) * (structure.length * angle + tip)
    return acceleration, angle, tip


def frf(
    model: Model,
    params: Mapping[str, ArrayLike],
    frequencies_hz: Float[ArrayLike, " f"],
    output: str = "tip_acceleration",
) -> Complex[np.ndarray, " f"]:
    """Complex FRF from joint torque to ``output`` at ``frequencies_hz`` (all > 0).

    ``tip_acceleration`` is ``−ω²(L θ̂ + ŵ(L))`` in (m/s²)/(N m); ``joint_angle`` rad/(N m).
    """
    if output not in FRF_OUTPUTS:
        raise ValueError(f"unknown FRF output {output!r}; choose one of {list(FRF_OUTPUTS)}")
    freqs = np.asarray(frequencies_hz, dtype=np.float64)
    if freqs.ndim != 1 or freqs.size == 0 or not np.all(np.isfinite(freqs)) or np.any(freqs <= 0):
        raise ValueError("frequencies_hz must be a non-empty 1-D array of positive, finite values")
    values = _params(model, params)
    acceleration, angle, tip = _frf_core(model, values, jnp.asarray(2 * np.pi * freqs))
    return np.asarray(
        {"tip_acceleration": acceleration, "joint_angle": angle, "tip_deflection": tip}[output]
    )
