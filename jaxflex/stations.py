"""Stations: positions along the link where sensors read the beam, as rows over the FEM DOFs.

Inside element ``e`` (``x = e·le + ξ·le``) the Hermite cubics interpolate the deflection

    ``w(x) = N1(ξ) w_e + le N2(ξ) w'_e + N3(ξ) w_{e+1} + le N4(ξ) w'_{e+1}``

with ``N1 = 1 − 3ξ² + 2ξ³``, ``N2 = ξ − 2ξ² + ξ³``, ``N3 = 3ξ² − 2ξ³``, ``N4 = ξ³ − ξ²``, and
the curvature ``w''(x)`` with their second derivatives divided by ``le²``. Node 0 is clamped
(``w = w' = 0``), so its columns are dropped, as in :class:`~jaxflex.fem.BeamPatterns`. The rows
are computed once per mesh in NumPy; the simulator maps them to modal coordinates.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from jaxtyping import Float


def _element_and_xi(length: float, n_elements: int, x: float) -> tuple[int, float]:
    """The element holding ``x`` and its local coordinate ξ ∈ [0, 1].

    A position within 1e-12 of an element's length of a node is put exactly on it, so the clamp
    and the tip rows are exactly those of :class:`~jaxflex.fem.BeamPatterns`.
    """
    s = x / length * n_elements  # position in element lengths
    node = round(s)
    if abs(s - node) <= 1e-12:
        s = float(node)
    e = min(int(s), n_elements - 1)
    return e, s - e


def beam_rows(
    length: float, n_elements: int, positions: Sequence[float]
) -> tuple[Float[np.ndarray, "k n"], Float[np.ndarray, "k n"]]:
    """Rows giving the deflection ``w(x)`` and curvature ``w''(x)`` at each position.

    Columns follow ``q = [θ, w_1, w'_1, …, w_n, w'_n]``; positions are measured from the clamp
    (``0 ≤ x ≤ length``). At ``x = length`` the deflection row is exactly the tip row.
    """
    le = length / n_elements
    dof = 1 + 2 * n_elements
    deflection = np.zeros((len(positions), dof))
    curvature = np.zeros((len(positions), dof))
    for k, x in enumerate(positions):
        if not 0.0 <= x <= length:
            raise ValueError(f"position {x!r} m lies outside the link [0, {length!r}] m")
        e, xi = _element_and_xi(length, n_elements, x)
        shape = np.array(
            [
                1 - 3 * xi**2 + 2 * xi**3,
                le * (xi - 2 * xi**2 + xi**3),
                3 * xi**2 - 2 * xi**3,
                le * (xi**3 - xi**2),
            ]
        )
        bend = np.array(
            [(-6 + 12 * xi) / le**2, (-4 + 6 * xi) / le, (6 - 12 * xi) / le**2, (6 * xi - 2) / le]
        )
        columns = np.arange(2 * e - 1, 2 * e + 3)  # w_e, w'_e, w_{e+1}, w'_{e+1}; node 0 → −1, 0
        keep = columns >= 1
        deflection[k, columns[keep]] = shape[keep]
        curvature[k, columns[keep]] = bend[keep]
    return deflection, curvature
