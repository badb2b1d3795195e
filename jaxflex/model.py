"""The model: testbed + drive + effects → parameter space and structural matrices."""

from __future__ import annotations

import dataclasses
from collections.abc import Iterable, Mapping

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array

from jaxflex.drives import Drive, TorqueDrive
from jaxflex.effects._base import Effect, Structure, joint_friction
from jaxflex.fem import BeamPatterns
from jaxflex.parameters import BASE_PARAMETERS, ParameterSpace, ParameterSpec, Params
from jaxflex.stations import beam_rows
from jaxflex.testbed import Testbed


class Model(eqx.Module):
    """A flexible-link arm: the reference testbed plus any number of physical effects.

    ``n_substeps`` integrator steps are taken per sample interval; see :mod:`jaxflex.simulation`.
    ``base`` holds the specs (bounds, reference values) of the six base parameters, ``drive``
    turns the logged input into hub torque (:mod:`jaxflex.drives`); a :class:`~jaxflex.arm.Arm`
    sets both for a real rig. ``n_modes`` advances only that many of the lowest flexible modes
    and adds the others' quasi-static response (default: all modes; see
    :mod:`jaxflex.simulation`).
    """

    testbed: Testbed = Testbed()
    effects: tuple[Effect, ...] = ()
    n_substeps: int = eqx.field(static=True, default=2)
    base: tuple[ParameterSpec, ...] = eqx.field(static=True, default=BASE_PARAMETERS)
    drive: Drive = TorqueDrive()
    stations: tuple[float, ...] = eqx.field(static=True, default=())
    n_modes: int | None = eqx.field(static=True, default=None)

    def __check_init__(self) -> None:
        if not isinstance(self.n_substeps, int) or self.n_substeps < 1:
            raise ValueError(f"n_substeps must be an int >= 1, got {self.n_substeps!r}")
        flexible = 2 * self.testbed.n_elements
        if self.n_modes is not None and not (
            isinstance(self.n_modes, int) and 1 <= self.n_modes <= flexible
        ):
            raise ValueError(
                f"n_modes must be None or an int from 1 to {flexible} (the flexible modes of "
                f"{self.testbed.n_elements} elements), got {self.n_modes!r}"
            )
        names = [e.name for e in self.effects]
        for effect in self.effects:
            if not isinstance(effect, Effect):
                raise TypeError(f"effects must be Effect instances, got {type(effect).__name__}")
        if len(set(names)) != len(names):
            raise ValueError(f"an effect appears twice: {names}")
        for x in self.stations:
            if not (isinstance(x, float) and 0.0 <= x <= self.testbed.length):
                raise ValueError(
                    f"station {x!r} must be a float position on the link, 0 <= x <= "
                    f"{self.testbed.length} m from the clamp"
                )
        base_names = tuple(p.name for p in self.base)
        if base_names != tuple(p.name for p in BASE_PARAMETERS):
            raise ValueError(
                f"base parameters must be {[p.name for p in BASE_PARAMETERS]}, got "
                f"{list(base_names)}"
            )

    @property
    def space(self) -> ParameterSpace:
        """The base parameters followed by each effect's parameters."""
        return ParameterSpace(self.base + tuple(p for e in self.effects for p in e.parameters))

    @property
    def effect_names(self) -> tuple[str, ...]:
        return tuple(e.name for e in self.effects)

    def with_effects(self, *effects: Effect) -> Model:
        """A copy with more effects appended."""
        return dataclasses.replace(self, effects=self.effects + tuple(effects))

    def without_effects(self, names: Iterable[str]) -> Model:
        """A copy without the named effects."""
        drop = set(names)
        return dataclasses.replace(
            self, effects=tuple(e for e in self.effects if e.name not in drop)
        )

    @property
    def advanced_modes(self) -> int:
        """How many flexible modes the simulator advances in time (the rest quasi-statically)."""
        return 2 * self.testbed.n_elements if self.n_modes is None else self.n_modes

    def station_rows(self) -> tuple[np.ndarray, np.ndarray]:
        """Rows giving ``w(x_k)`` and ``w''(x_k)`` at the stations, ``(k, n)`` each (NumPy)."""
        tb = self.testbed
        return beam_rows(tb.length, tb.n_elements, self.stations)

    def patterns(self) -> BeamPatterns:
        """Mesh patterns (NumPy, per unit rhoA and EI) for this testbed."""
        return BeamPatterns(self.testbed.length, self.testbed.n_elements)

    def structure(self, params: Params) -> Structure:
        """Mass and stiffness for one parameter set, after every effect has acted."""
        tb = self.testbed
        pat = self.patterns()
        rho_a = tb.mass_per_length
        mass = rho_a * jnp.asarray(pat.mass)
        first_moment = rho_a * jnp.asarray(pat.first_moment)
        r = tb.clamp_offset
        if r:  # the link's root sits at r from the axis: x → r + x in the rotation terms
            rows = jnp.asarray(pat.first_moment).at[0].set(r * tb.length + tb.length**2)
            shift = rho_a * r * rows  # [ρA(r²L + rL²), ρA r ∫N dx]
            mass = mass.at[0, :].add(shift).at[1:, 0].add(shift[1:])
            first_moment = first_moment.at[0].add(rho_a * r * tb.length)
        mass = mass.at[0, 0].add(params["J_h"])
        structure = Structure(
            mass=mass,
            stiffness=params["E"] * tb.second_moment * jnp.asarray(pat.stiffness),
            first_moment=first_moment,
            tip=jnp.asarray(pat.tip),
            root_curvature=jnp.asarray(pat.root_curvature),
            length=tb.length,
        )
        for effect in self.effects:
            structure = effect.structure(structure, params)
        return structure

    def friction(self, params: Params, velocity: Array) -> Array:
        """Total joint friction torque at joint velocity ``velocity``."""
        omega_s = self.testbed.omega_s
        torque = joint_friction(params, velocity, omega_s)
        for effect in self.effects:
            torque = torque + effect.friction(params, velocity, omega_s)
        if self.drive.damping:
            torque = torque + self.drive.damping * velocity
        return torque

    def loads(self, structure: Structure, params: Params) -> Array:
        """Stacked shapes of all position-dependent loads, ``(k, n)``."""
        shapes = [e.loads(structure, params) for e in self.effects]
        return jnp.concatenate([jnp.zeros((0, structure.mass.shape[0]))] + shapes, axis=0)

    def load_amplitudes(self, params: Params, angle: Array, velocity: Array) -> Array:
        """Stacked amplitudes of all position-dependent loads, ``(k,)``."""
        parts = [e.load_amplitudes(params, angle, velocity) for e in self.effects]
        return jnp.concatenate([jnp.zeros((0,))] + parts)

    def input_torque(self, params: Params, torque: Array, h: float) -> Array:
        """The drive's torque from the logged input after every input effect (delay, lag).

        ``torque`` is the input signal on a grid of step ``h`` (N m for a torque drive).
        """
        torque = self.drive.torque(torque)
        for effect in self.effects:
            torque = effect.input_torque(params, torque, h)
        return torque

    def readings(self, params: Params, readings: Mapping[str, Array]) -> dict[str, Array]:
        """Output channels (by name) after every effect's calibration (a sensor gain, offset)."""
        readings = dict(readings)
        for effect in self.effects:
            readings = effect.readings(params, readings)
        return readings
