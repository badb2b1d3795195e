"""Geometry, material and settings of the single-link flexible arm (reference-testbed defaults)."""

from __future__ import annotations

import math
import sys
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
        fault = link_fault(**{f.name: getattr(self, f.name) for f in fields(self)
                              if f.name in _LINK_SETTINGS})
        if fault is not None:
            name, why = fault
            raise ValueError(f"testbed setting {name}={getattr(self, name)!r} {why}")

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


_LINK_SETTINGS = ("length", "width", "thickness", "density", "n_elements", "clamp_offset")


def _normal(value: float) -> bool:
    """A positive finite float that keeps its precision: neither zero, subnormal nor infinite."""
    return math.isfinite(value) and value >= sys.float_info.min


def link_fault(
    *, length: float, width: float, thickness: float, density: float, n_elements: int,
    clamp_offset: float = 0.0, moduli: tuple[float, ...] = (1.0,),
) -> tuple[str, str] | None:
    """``(setting, why)`` when the link's section, material or mesh gives a bending stiffness,
    mass or inertia that floating point cannot hold (zero, subnormal or infinite), else None.

    ``moduli`` are the Young's moduli E to form E·I with (the bounds of E; by default I alone).
    The setting blamed is the factor farthest (in decades, times its power) from the reference
    testbed's value: the one most likely mistyped.
    """
    values = {"length": length, "width": width, "thickness": thickness, "density": density,
              "clamp_offset": clamp_offset}
    cube = lambda x: x * x * x  # noqa: E731  (x**3 raises on overflow; this gives inf)
    per_element = length / n_elements
    second = width * cube(thickness) / 12.0
    rho_a = density * width * thickness
    inertia = rho_a * (cube(clamp_offset + length) - cube(clamp_offset)) / 3.0
    bending = [e * second for e in moduli]
    volume = cube(per_element)
    element = [b / volume if volume else math.inf for b in bending]
    checks = [
        (bending, {"thickness": 3, "width": 1}, "gives a bending stiffness E·I that is not a "
         f"positive finite number (I = w·h³/12 = {second!r} m⁴)"),
        ([rho_a], {"density": 1, "width": 1, "thickness": 1},
         f"gives a mass per length ρ·A = {rho_a!r} kg/m that is not a positive finite number"),
        (element, {"length": -3, "thickness": 3, "width": 1}, "gives an element stiffness "
         f"E·I/l³ (l = {per_element!r} m) that is not a positive finite number"),
        ([rho_a * per_element], {"length": 1, "density": 1, "thickness": 1, "width": 1},
         f"gives an element mass ρ·A·l (l = {per_element!r} m) that is not a positive finite "
         "number"),
        ([inertia], {"clamp_offset": 2, "length": 3, "density": 1},
         f"gives a link inertia {inertia!r} kg m² that is not a positive finite number"),
    ]
    for results, powers, why in checks:
        if not all(_normal(x) for x in results):
            return _farthest(values, powers), why
    return None


def _farthest(values: dict[str, float], powers: dict[str, int]) -> str:
    """Of the settings in ``powers``, the one farthest in decades (times its power) from the
    reference testbed's value."""

    def decades(name: str) -> float:
        value, usual = values[name], getattr(Testbed, name) or 0.1
        return abs(powers[name] * math.log10(value / usual)) if value > 0 else -math.inf

    return max(powers, key=decades)


TESTBED_SETTINGS: tuple[str, ...] = tuple(f.name for f in fields(Testbed))
"""Names of the :class:`Testbed` settings (geometry, sampling, mesh) ``--set`` can change."""
