"""Geometry, material and settings of the single-link flexible arm (reference-testbed defaults)."""

from __future__ import annotations

import math
from dataclasses import fields, replace

import equinox as eqx


class Testbed(eqx.Module):
    """Fixed (not identified) properties of the arm and the experiment.

    Defaults follow the reference testbed: a 0.5 m aluminium strip, 25 mm × 2 mm, clamped on the
    joint axis, ten Hermite elements, a smooth-Coulomb velocity scale of 0.01 rad/s and 1 kHz
    sampling of 2 s records. ``clamp_offset`` is the distance from the joint axis to the clamp
    (the link's root); ``length`` runs from the clamp to the tip.
    """

    length: float = 0.50
    width: float = 0.025
    thickness: float = 0.002
    density: float = 2700.0
    n_elements: int = eqx.field(static=True, default=10)
    omega_s: float = 0.01
    dt: float = 1e-3
    duration: float = 2.0
    clamp_offset: float = 0.0

    def __check_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            if f.name == "clamp_offset":
                if not (isinstance(value, (int, float)) and math.isfinite(value) and value >= 0):
                    raise ValueError(
                        f"testbed setting clamp_offset={value!r} must be a number >= 0"
                    )
            elif isinstance(value, (int, float)) and not (math.isfinite(value) and value > 0):
                raise ValueError(f"testbed setting {f.name}={value!r} must be a positive number")
        if not isinstance(self.n_elements, int) or self.n_elements < 1:
            raise ValueError(f"testbed setting n_elements={self.n_elements!r} must be an int >= 1")

    @property
    def area(self) -> float:
        """Cross-section area A (m²)."""
        return self.width * self.thickness

    @property
    def second_moment(self) -> float:
        """Second moment of area I = b h³ / 12 (m⁴) for bending in the plane of motion."""
        return self.width * self.thickness**3 / 12.0

    @property
    def mass_per_length(self) -> float:
        """rho·A (kg/m)."""
        return self.density * self.area

    @property
    def link_inertia(self) -> float:
        """Inertia of the rigid link about the joint, rho·A·((r + L)³ − r³)/3 (kg m²)."""
        r = self.clamp_offset
        return self.mass_per_length * ((r + self.length) ** 3 - r**3) / 3.0

    @property
    def n_samples(self) -> int:
        """Samples in a record of ``duration`` at step ``dt`` (both ends included)."""
        return int(round(self.duration / self.dt)) + 1

    def replace(self, **changes: float | int) -> Testbed:
        """A copy with some settings changed (unknown names raise a ValueError)."""
        known = {f.name for f in fields(self)}
        unknown = sorted(set(changes) - known)
        if unknown:
            raise ValueError(
                f"unknown testbed setting(s) {unknown}; known settings: {sorted(known)}"
            )
        return replace(self, **changes)


TESTBED_SETTINGS: tuple[str, ...] = tuple(f.name for f in fields(Testbed))
"""Names of the :class:`Testbed` settings (geometry, sampling, mesh) ``--set`` can change."""
