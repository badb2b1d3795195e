"""Hermite-cubic Euler–Bernoulli beam elements on a rotating hub: pure array functions.

The link is clamped to the hub at ``x = 0`` and meshed with ``n`` equal elements of length
``le = L/n``; each node carries the transverse displacement ``w`` and rotation ``w'`` in the frame
that rotates with the hub. The generalised coordinates are ``q = [theta, w_1, w'_1, …, w_n, w'_n]``
(node 0 is clamped). With ``T = ½ J_h θ'² + ½ ∫ rhoA (x θ' + ẇ)² dx`` and
``V = ½ ∫ EI (w'')² dx`` the matrices are constant:

* ``M_θθ = J_h + rhoA L³/3``,  ``M_θq = ∫ rhoA x N(x) dx``,  ``M_qq = Σ consistent element mass``,
* ``K_qq = Σ EI/le³ [[12, 6le, −12, 6le], …]`` and no stiffness on ``theta``.

Everything here is linear in ``rhoA`` and ``EI``, so the patterns are built once per mesh
(NumPy, exact) and scaled inside JIT-compiled code.
"""

from __future__ import annotations

import numpy as np
from jaxtyping import Float


def element_mass(le: float) -> Float[np.ndarray, "4 4"]:
    """Consistent mass of one element per unit rhoA: ``le/420·[[156, 22le, 54, −13le], …]``."""
    return (le / 420.0) * np.array(
        [
            [156.0, 22 * le, 54.0, -13 * le],
            [22 * le, 4 * le**2, 13 * le, -3 * le**2],
            [54.0, 13 * le, 156.0, -22 * le],
            [-13 * le, -3 * le**2, -22 * le, 4 * le**2],
        ]
    )


def element_stiffness(le: float) -> Float[np.ndarray, "4 4"]:
    """Bending stiffness of one element per unit EI: ``1/le³·[[12, 6le, −12, 6le], …]``."""
    return (1.0 / le**3) * np.array(
        [
            [12.0, 6 * le, -12.0, 6 * le],
            [6 * le, 4 * le**2, -6 * le, 2 * le**2],
            [-12.0, -6 * le, 12.0, -6 * le],
            [6 * le, 2 * le**2, -6 * le, 4 * le**2],
        ]
    )


def element_rotation_coupling(x0: float, le: float) -> Float[np.ndarray, "4"]:
    """``∫ x N(x) dx`` over an element starting at ``x0`` (per unit rhoA): the θ–q mass row."""
    return x0 * np.array([le / 2, le**2 / 12, le / 2, -(le**2) / 12]) + np.array(
        [3 * le**2 / 20, le**3 / 30, 7 * le**2 / 20, -(le**3) / 20]
    )


def element_shape_integral(le: float) -> Float[np.ndarray, "4"]:
    """``∫ N(x) dx`` over an element (per unit rhoA): the load of a uniform transverse field."""
    return np.array([le / 2, le**2 / 12, le / 2, -(le**2) / 12])


class BeamPatterns:
    """Assembled matrices of a clamped beam on a hub, per unit rhoA and per unit EI.

    Attributes are NumPy arrays over ``q = [theta, w_1, w'_1, …]`` (size ``1 + 2n``):
    ``mass`` (per unit rhoA, without the hub), ``stiffness`` (per unit EI), ``first_moment``
    (``[∫x dm, ∫N dm]`` per unit rhoA: the load of a uniform field), ``tip`` (selects ``w(L)``),
    ``tip_slope`` (selects ``w'(L)``) and ``root_curvature`` (gives ``w''(0)``).
    """

    def __init__(self, length: float, n_elements: int) -> None:
        if n_elements < 1:
            raise ValueError(f"n_elements must be >= 1, got {n_elements}")
        n = n_elements
        le = length / n
        size = 2 * (n + 1)  # all nodal DOFs, node 0 included (dropped at the end)
        mass_qq = np.zeros((size, size))
        stiffness_qq = np.zeros((size, size))
        coupling = np.zeros(size)
        shape_integral = np.zeros(size)
        me, ke = element_mass(le), element_stiffness(le)
        for e in range(n):
            idx = slice(2 * e, 2 * e + 4)
            mass_qq[idx, idx] += me
            stiffness_qq[idx, idx] += ke
            coupling[idx] += element_rotation_coupling(e * le, le)
            shape_integral[idx] += element_shape_integral(le)

        dof = 1 + 2 * n
        self.n_elements = n
        self.length = length
        self.element_length = le
        self.n_dof = dof
        self.mass = np.zeros((dof, dof))
        self.mass[0, 0] = length**3 / 3.0
        self.mass[0, 1:] = self.mass[1:, 0] = coupling[2:]
        self.mass[1:, 1:] = mass_qq[2:, 2:]
        self.stiffness = np.zeros((dof, dof))
        self.stiffness[1:, 1:] = stiffness_qq[2:, 2:]
        self.first_moment = np.concatenate([[length**2 / 2.0], shape_integral[2:]])
        self.tip = np.zeros(dof)
        self.tip[dof - 2] = 1.0
        self.tip_slope = np.zeros(dof)
        self.tip_slope[dof - 1] = 1.0
        # w''(0) of element 1 with w(0) = w'(0) = 0: N3''(0) = 6/le², N4''(0) = −2/le.
        self.root_curvature = np.zeros(dof)
        self.root_curvature[1] = 6.0 / le**2
        self.root_curvature[2] = -2.0 / le
        # Root-rotation DOF w'(0) (clamped in the base model): its stiffness row, for effects
        # that release the clamp (a compliant root).
        self.root_rotation_stiffness = stiffness_qq[1, 1]
        self.root_rotation_coupling = np.concatenate([[0.0], stiffness_qq[1, 2:]])
