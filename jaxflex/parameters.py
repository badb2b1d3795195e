"""Named physical parameters, their bounds, and the coordinates optimisers search in.

A parameter set is a plain ``dict[str, Array]`` (a pytree), so it can be vmapped, differentiated
and printed. A :class:`ParameterSpace` fixes an order and maps between physical values (in the
units of the spec) and the unit box ``u ∈ [0, 1]^d`` that the evolutionary algorithms search and
the bounded refinement works in (log scale for parameters spanning decades).

A coordinate round trip can land one ulp past a bound (``lo·exp(log(hi/lo))`` is not ``hi``).
Every seed and warm start enters the box through one place, :func:`into_unit_box` (via
:meth:`ParameterSpace.unit_seeds` for physical values), which clips after the round trip and
refuses only what lies beyond a bound by more than round-off (:data:`UNIT_SLACK`).
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float

Params = dict[str, Array]
"""A parameter set: name → value (SI units; a leading axis for a population)."""

UNIT_SLACK = 1e-9
"""How far outside ``[0, 1]`` a unit-box coordinate may come back from a round trip through
physical values (log maps, float32 files) and still count as on the bound."""


def _namespace(*values: object):
    """``jax.numpy`` where any value is traced (inside ``jit``, ``vmap``, ``grad``), else NumPy:
    a host-side conversion (a report, a seed, a start) compiles nothing."""
    traced = any(isinstance(leaf, jax.core.Tracer) for leaf in jax.tree.leaves(values))
    return jnp if traced else np


def into_unit_box(u: Float[ArrayLike, "... d"], what: str = "init_population") -> np.ndarray:
    """Unit-box coordinates clipped into ``[0, 1]``: the one way seeds and warm starts enter
    the box. A non-finite coordinate, or one beyond the box by more than :data:`UNIT_SLACK`, is
    an error naming ``what``."""
    u = np.asarray(u, dtype=np.float64)
    if not np.all(np.isfinite(u)) or np.any((u < -UNIT_SLACK) | (u > 1.0 + UNIT_SLACK)):
        raise ValueError(f"{what} must lie in the unit box [0, 1]^d (finite values)")
    return np.clip(u, 0.0, 1.0)


@dataclass(frozen=True)
class ParameterSpec:
    """One identifiable parameter: bounds, unit, and the value at which its effect vanishes."""

    name: str
    unit: str
    lower: float
    upper: float
    reference: float
    description: str = ""
    log_scale: bool = True
    null: float | None = None

    def __post_init__(self) -> None:
        if not self.name.isidentifier():
            raise ValueError(f"parameter name {self.name!r} must be a Python identifier")
        for label in ("lower", "upper", "reference"):
            value = getattr(self, label)
            if not math.isfinite(value):
                raise ValueError(f"parameter {self.name}: {label}={value!r} is not finite")
        if not self.lower < self.upper:
            raise ValueError(
                f"parameter {self.name}: lower bound {self.lower!r} must be below "
                f"upper bound {self.upper!r}"
            )
        if self.log_scale and self.lower <= 0:
            raise ValueError(
                f"parameter {self.name}: a log-scale parameter needs a positive lower bound, "
                f"got {self.lower!r}"
            )

    def with_bounds(self, lower: float, upper: float) -> ParameterSpec:
        """A copy with new bounds (validated)."""
        return ParameterSpec(
            self.name,
            self.unit,
            lower,
            upper,
            self.reference,
            self.description,
            self.log_scale,
            self.null,
        )


BASE_PARAMETERS: tuple[ParameterSpec, ...] = (
    ParameterSpec("E", "Pa", 20e9, 100e9, 5.7002e10, "Young's modulus of the link"),
    ParameterSpec("J_h", "kg m^2", 1e-3, 0.2, 0.0053, "hub moment of inertia"),
    ParameterSpec("b_v", "N m s/rad", 1e-5, 0.3, 6.3016e-4, "viscous joint friction"),
    ParameterSpec("tau_c", "N m", 1e-3, 0.2, 0.1071, "Coulomb joint friction"),
    ParameterSpec("alpha", "1/s", 1e-3, 4.0, 1.8240, "Rayleigh damping, mass-proportional"),
    ParameterSpec("beta", "s", 1e-7, 2e-4, 7.6275e-5, "Rayleigh damping, stiffness-proportional"),
)
"""The six identified parameters of the reference testbed: the paper's bounds and values."""


class ParameterSpace:
    """An ordered set of :class:`ParameterSpec` with coordinate maps for the optimisers."""

    def __init__(self, specs: Iterable[ParameterSpec]) -> None:
        self.specs: tuple[ParameterSpec, ...] = tuple(specs)
        names = [s.name for s in self.specs]
        duplicated = sorted({n for n in names if names.count(n) > 1})
        if duplicated:
            raise ValueError(f"parameter names appear twice: {duplicated}")
        self.names: tuple[str, ...] = tuple(names)
        self._lower = np.array([s.lower for s in self.specs], dtype=np.float64)
        self._upper = np.array([s.upper for s in self.specs], dtype=np.float64)
        self._log = np.array([s.log_scale for s in self.specs], dtype=bool)

    def __len__(self) -> int:
        return len(self.specs)

    def __repr__(self) -> str:
        return f"ParameterSpace({list(self.names)})"

    def __getitem__(self, name: str) -> ParameterSpec:
        for spec in self.specs:
            if spec.name == name:
                return spec
        raise KeyError(f"unknown parameter {name!r}; known parameters: {list(self.names)}")

    @property
    def lower(self) -> np.ndarray:
        return self._lower.copy()

    @property
    def upper(self) -> np.ndarray:
        return self._upper.copy()

    def with_bounds(self, bounds: Mapping[str, tuple[float, float]]) -> ParameterSpace:
        """A copy with some bounds replaced, e.g. ``{"J_h": (1e-3, 1e-2)}``."""
        unknown = sorted(set(bounds) - set(self.names))
        if unknown:
            raise ValueError(f"bounds given for unknown parameter(s) {unknown}")
        return ParameterSpace(
            s.with_bounds(*bounds[s.name]) if s.name in bounds else s for s in self.specs
        )

    def reference(self) -> Params:
        """The reference values (for effects: their null values) as a parameter dict."""
        return {s.name: jnp.asarray(s.reference, dtype=jnp.float64) for s in self.specs}

    def nulls(self) -> Params:
        """Null values of the parameters that have one (where an effect vanishes)."""
        return {
            s.name: jnp.asarray(s.null, dtype=jnp.float64) for s in self.specs if s.null is not None
        }

    # --- physical <-> vector ------------------------------------------------------------------
    def to_vector(self, params: Mapping[str, ArrayLike]) -> Float[Array, "... d"]:
        """Stack named values into a vector (last axis follows ``names``); a NumPy array unless
        a value is traced."""
        missing = [n for n in self.names if n not in params]
        if missing:
            raise KeyError(f"parameter values missing for {missing}")
        xp = _namespace([params[n] for n in self.names])
        return xp.stack([xp.asarray(params[n], dtype=np.float64) for n in self.names], axis=-1)

    def from_vector(self, vector: Float[ArrayLike, "... d"]) -> Params:
        """Split a vector (last axis) into named values (copies, for a NumPy vector)."""
        xp = _namespace(vector)
        vector = xp.asarray(vector, dtype=np.float64)
        if vector.shape[-1] != len(self):
            raise ValueError(
                f"expected a last axis of length {len(self)} ({list(self.names)}), "
                f"got shape {vector.shape}"
            )
        if xp is np:
            return {n: vector[..., i].copy() for i, n in enumerate(self.names)}
        return {n: vector[..., i] for i, n in enumerate(self.names)}

    # --- physical <-> unit box ---------------------------------------------------------------
    def to_unit(self, params: Mapping[str, ArrayLike]) -> Float[Array, "... d"]:
        """Physical values → unit box coordinates (log scale where the spec says so)."""
        x = self.to_vector(params)
        xp = _namespace(x)
        lo, hi, log = xp.asarray(self._lower), xp.asarray(self._upper), xp.asarray(self._log)
        safe_x = xp.where(log, xp.maximum(x, lo * 1e-300), 1.0)
        # a linear parameter's bounds may be negative (a sensor mounted the other way): the
        # log side of the where sees 2/1 for it, never the log of its bounds
        u_log = (xp.log(safe_x) - xp.log(xp.where(log, lo, 1.0))) / xp.where(
            log, xp.log(xp.where(log, hi, 2.0) / xp.where(log, lo, 1.0)), 1.0
        )
        u_lin = (x - lo) / (hi - lo)
        return xp.where(log, u_log, u_lin)

    def from_unit(self, u: Float[ArrayLike, "... d"]) -> Params:
        """Unit box coordinates → physical values (values outside [0, 1] extrapolate); the
        box maps into the bounds, its faces onto them exactly (the log map's last ulp is not
        trusted)."""
        xp = _namespace(u)
        u = xp.asarray(u, dtype=np.float64)
        lo, hi, log = xp.asarray(self._lower), xp.asarray(self._upper), xp.asarray(self._log)
        safe_lo = xp.where(log, lo, 1.0)
        x_log = safe_lo * xp.exp(u * xp.log(xp.where(log, hi, 2.0) / safe_lo))
        x_lin = lo + u * (hi - lo)
        x = xp.where(log, x_log, x_lin)
        inside = (u >= 0.0) & (u <= 1.0)
        x = xp.where(inside, xp.clip(x, lo, hi), x)
        return self.from_vector(xp.where(u == 0.0, lo, xp.where(u == 1.0, hi, x)))

    def unit_seeds(self, params: Mapping[str, ArrayLike], what: str | None = None
                   ) -> Float[np.ndarray, "k d"]:
        """Physical starting points (a value or values per name) → unit-box rows, clipped into
        the box (:func:`into_unit_box`).

        ``what`` names given seeds (e.g. ``"init_population"``): a value beyond its bounds by more
        than round-off is an error naming it. Without ``what`` the points are estimates (e.g. a
        rigid-body fit): one beyond a bound starts on that bound.
        """
        missing = [n for n in self.names if n not in params]
        if missing:
            raise ValueError(f"{what or 'starting point'} lacks parameter(s) {missing}")
        values = {n: np.atleast_1d(np.asarray(params[n], dtype=np.float64)) for n in self.names}
        u = np.atleast_2d(np.asarray(self.to_unit(values)))
        if what is None:
            return np.clip(u, 0.0, 1.0)
        for i, spec in enumerate(self.specs):
            v = values[spec.name]
            bad = ~np.isfinite(v) | ~np.isfinite(u[:, i]) | (u[:, i] < -UNIT_SLACK) | (
                u[:, i] > 1.0 + UNIT_SLACK)
            if np.any(bad):
                raise ValueError(
                    f"{what}: {spec.name}={float(v[bad][0])!r} lies outside its search bounds "
                    f"[{spec.lower!r}, {spec.upper!r}] {spec.unit}"
                )
        return into_unit_box(u, what)

    # --- checks -----------------------------------------------------------------------------
    def validate(self, params: Mapping[str, ArrayLike], *, within_bounds: bool = False) -> None:
        """Raise a ValueError naming each missing, unknown, non-finite or non-positive value."""
        unknown = sorted(set(params) - set(self.names))
        if unknown:
            raise ValueError(
                f"unknown parameter(s) {unknown}; known parameters: {list(self.names)}"
            )
        missing = [n for n in self.names if n not in params]
        if missing:
            raise ValueError(f"parameter value(s) missing for {missing}")
        for spec in self.specs:
            value = np.asarray(params[spec.name], dtype=np.float64)
            if not np.all(np.isfinite(value)):
                raise ValueError(f"parameter {spec.name} must be finite, got {value}")
            floor = spec.null if spec.null is not None else 0.0
            two_sided = spec.null is not None and spec.lower < spec.null  # e.g. an offset
            if spec.null is not None and not two_sided and np.any(value < floor):
                raise ValueError(f"parameter {spec.name} must be >= {floor}, got {value}")
            if spec.null is None and np.any(value <= 0.0):
                raise ValueError(f"parameter {spec.name} must be positive, got {value}")
            if within_bounds and np.any((value < spec.lower) | (value > spec.upper)):
                raise ValueError(
                    f"parameter {spec.name}={value} lies outside its bounds "
                    f"[{spec.lower}, {spec.upper}] {spec.unit}"
                )


def base_space() -> ParameterSpace:
    """The six parameters of the reference testbed with the paper's bounds."""
    return ParameterSpace(BASE_PARAMETERS)


def reference_parameters() -> Params:
    """The paper's identified values (the testbed's reference parameter set)."""
    return base_space().reference()
