"""The rig: one description of a flexible-link arm that every command, fit and figure uses.

A :class:`Model` holds the link and simulation settings (a :class:`~jaxflex.testbed.Testbed`),
the base parameters' specs (reference values, bounds) and which of them are fixed, the drive that
turns the logged input into hub torque, the sensors that log the record's channels, and the
physical effects added to the base model. It is what an arm file describes
(:mod:`jaxflex.arm` reads and writes one) and what a fit file stores whole, so a fit
re-simulates identically whatever became of the file it was made with. ``Model()`` is the
reference testbed (``jaxflex arms show reference``).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterable, Mapping

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array

from jaxflex._arguments import shown
from jaxflex.drives import AbstractDrive, TorqueDrive
from jaxflex.effects._base import (
    AbstractEffect,
    EffectError,
    Structure,
    blamed,
    effect_label,
    joint_friction,
    returned,
)
from jaxflex.fem import BeamPatterns
from jaxflex.parameters import BASE_PARAMETERS, ParameterSpace, ParameterSpec, Params
from jaxflex.sensors import AbstractSensor
from jaxflex.stations import beam_rows
from jaxflex.testbed import Testbed

REFERENCE_DESCRIPTION = (
    "reference testbed: 0.5 m aluminium strip, torque drive, joint angle and tip acceleration"
)
"""The reference testbed's description (``Model().description``)."""
BREAKAWAY_SPEED = 1e-9
"""Joint speed (rad/s) at which :meth:`Model.breakaway_torque` reads the friction: far below
any motion an encoder sees, so viscous friction adds nothing and a static excess is whole."""


class Model(eqx.Module):
    """A flexible-link rig: link, parameter specs, drive, sensors and physical effects.

    ``n_substeps`` integrator steps are taken per sample interval; see :mod:`jaxflex.simulation`.
    ``base`` holds the specs (bounds, reference values) of the six base parameters and ``fixed``
    names those held at their reference value when identifying; ``drive`` turns the logged input
    into hub torque (:mod:`jaxflex.drives`). ``sensors`` read the record's channels
    (:mod:`jaxflex.sensors`): a simulation then also gives each sensor's reading by its channel
    name, and a station is added at each link sensor. A model without sensors (the reference
    testbed) is fitted on the simulator's own outputs, named as record columns. ``n_modes``
    advances only that many of the lowest flexible modes and adds the others' quasi-static
    response (default: all modes; see :mod:`jaxflex.simulation`).
    """

    testbed: Testbed = Testbed()
    effects: tuple[AbstractEffect, ...] = ()
    n_substeps: int = eqx.field(static=True, default=2)
    base: tuple[ParameterSpec, ...] = eqx.field(static=True, default=BASE_PARAMETERS)
    drive: AbstractDrive = TorqueDrive()
    stations: tuple[float, ...] = eqx.field(static=True, default=())
    n_modes: int | None = eqx.field(static=True, default=None)
    sensors: tuple[AbstractSensor, ...] = eqx.field(static=True, default=())
    fixed: tuple[str, ...] = eqx.field(static=True, default=())
    name: str = eqx.field(static=True, default="reference")
    description: str = eqx.field(static=True, default=REFERENCE_DESCRIPTION)

    def __post_init__(self) -> None:
        if not (isinstance(self.name, str) and self.name.strip() and self.name.isprintable()):
            raise TypeError(f"name must be one line of text (the rig's name, written in fits "
                            f"and reports), got {shown(self.name)}")
        if not isinstance(self.description, str):
            raise TypeError(f"description must be text, got {shown(self.description)}")
        if isinstance(self.fixed, str):
            raise TypeError(f"fixed must be a tuple of parameter names, got {self.fixed!r}")
        if not isinstance(self.testbed, Testbed):
            raise TypeError(f"testbed must be a Testbed (e.g. Testbed(length=0.4)), got "
                            f"{shown(self.testbed)}")
        if not isinstance(self.drive, AbstractDrive):
            raise TypeError(f"drive must be a drive (e.g. VoltageDrive(...)), got "
                            f"{shown(self.drive)}")
        for field, example in (("sensors", "(Encoder(),)"), ("effects", "(Payload(),)")):
            value = getattr(self, field)
            if isinstance(value, (str, Mapping)) or not isinstance(value, Iterable):
                raise TypeError(f"{field} must be a tuple of {field[:-1].capitalize()}s (e.g. "
                                f"{example}), got {shown(value)}")
        self.effects = tuple(self.effects)
        self.sensors = tuple(self.sensors)
        self.fixed = tuple(self.fixed)
        for sensor in self.sensors:  # checked here: a station needs a position
            if not isinstance(sensor, AbstractSensor):
                raise TypeError(f"sensors must be sensors (e.g. Encoder()), got {shown(sensor)}")
        positions = {s.position for s in self.sensors if s.position is not None}
        self.stations = tuple(sorted(set(self.stations) | positions))

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
        self._check_sensors()
        names = [e.name for e in self.effects]
        for effect in self.effects:
            if not isinstance(effect, AbstractEffect):
                raise TypeError(f"effects must be effects (e.g. Payload()), got "
                                f"{type(effect).__name__}")
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
        unknown = sorted(set(self.fixed) - set(base_names))
        if unknown:
            raise ValueError(f"fixed parameter(s) {unknown} are not base parameters "
                             f"{list(base_names)}")

    def _check_sensors(self) -> None:
        """Distinct channels, none that is the drive's input or time, each effect on a channel
        acting on an output or a sensor's channel."""
        from jaxflex.simulation import OUTPUT_NAMES

        channels = [s.channel for s in self.sensors]
        twice = sorted({c for c in channels if channels.count(c) > 1})
        if twice:
            raise ValueError(f"rig {self.name!r}: two sensors log the channel(s) {twice}")
        for s in self.sensors:
            if s.position is not None and s.position > self.testbed.length:
                raise ValueError(
                    f"rig {self.name!r}: sensor {s.channel} at x = {s.position!r} m lies beyond "
                    f"the link (length {self.testbed.length!r} m)"
                )
            if s.position == 0.0 and s.silent_at_clamp(self.testbed.clamp_offset):
                raise ValueError(
                    f"rig {self.name!r}: sensor {s.channel} at x = 0 sits at the clamp, where "
                    "it reads zero; give its distance from the clamp, x (m)"
                )
        for c in channels:
            if c == "time" or c == self.drive.name:
                what = "time" if c == "time" else f"the {self.drive.name} drive's input"
                raise ValueError(f"rig {self.name!r}: sensor channel {c!r} is {what}, not a "
                                 "reading; name the sensor's own column")
        for effect in self.effects:
            channel = getattr(effect, "channel", None)
            if channel is not None and channel not in OUTPUT_NAMES and channel not in channels:
                raise ValueError(
                    f"rig {self.name!r}: effect {effect.name} acts on {channel!r}, neither a "
                    f"simulator output nor a sensor's channel ({channels})"
                )

    @property
    def channels(self) -> tuple[str, ...]:
        """The channels the rig's sensors log (empty for a rig fitted on the outputs)."""
        return tuple(s.channel for s in self.sensors)

    def sensor(self, channel: str) -> AbstractSensor:
        """The sensor that logs ``channel``."""
        for s in self.sensors:
            if s.channel == channel:
                return s
        raise KeyError(f"rig {self.name!r} has no sensor logging {channel!r}; channels: "
                       f"{list(self.channels)}")

    @property
    def fixed_values(self) -> dict[str, float]:
        """The fixed base parameters and their reference values."""
        return {s.name: s.reference for s in self.base if s.name in self.fixed}

    def replace(self, **changes) -> Model:
        """A copy with some fields changed (checked again)."""
        return dataclasses.replace(self, **changes)

    @property
    def space(self) -> ParameterSpace:
        """The base parameters followed by each effect's parameters."""
        return ParameterSpace(self.base + tuple(p for e in self.effects for p in e.parameters))

    @property
    def effect_names(self) -> tuple[str, ...]:
        return tuple(e.name for e in self.effects)

    def with_effects(self, *effects: AbstractEffect) -> Model:
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
            with blamed(effect, "structure"):
                changed = effect.structure(structure, params)
            if not isinstance(changed, Structure):
                raise EffectError(f"effect {effect_label(effect)}: structure returned "
                                  f"{shown(changed)}; expected a Structure")
            square = structure.mass.shape
            returned(effect, "structure", changed.mass, square, "its mass matrix",
                     broadcast=False)
            returned(effect, "structure", changed.stiffness, square, "its stiffness matrix",
                     broadcast=False)
            structure = changed
        return structure

    def friction(self, params: Params, velocity: Array) -> Array:
        """Total joint friction torque at joint velocity ``velocity``."""
        omega_s = self.testbed.omega_s
        torque = joint_friction(params, velocity, omega_s)
        for effect in self.effects:
            with blamed(effect, "friction"):
                extra = effect.friction(params, velocity, omega_s)
            torque = torque + returned(effect, "friction", extra, jnp.shape(velocity),
                                       "a torque per velocity")
        if self.drive.damping:
            torque = torque + self.drive.damping * velocity
        return torque

    def breakaway_torque(self, params: Params) -> float:
        """The hub torque (N m) that the joint's friction holds at rest: the friction just above
        zero speed without its smoothing (``tau_c``, plus any static excess such as a Stribeck
        ``delta_tau_s``). An input whose torque never exceeds it leaves the hub still."""
        velocity, omega_s = jnp.asarray(BREAKAWAY_SPEED), BREAKAWAY_SPEED * 1e-3
        torque = joint_friction(params, velocity, omega_s)
        for effect in self.effects:
            torque = torque + effect.friction(params, velocity, omega_s)
        return float(torque)

    def loads(self, structure: Structure, params: Params) -> Array:
        """Stacked shapes of all position-dependent loads, ``(k, n)``."""
        n = structure.mass.shape[0]
        shapes = []
        for e in self.effects:
            with blamed(e, "loads"):
                shape = e.loads(structure, params)
            k = np.shape(shape)[0] if np.ndim(shape) == 2 else 0
            shapes.append(returned(e, "loads", shape, (k, n), "k load shapes over the "
                                   f"{n} coordinates", broadcast=False))
        return jnp.concatenate([jnp.zeros((0, structure.mass.shape[0]))] + shapes, axis=0)

    def load_amplitudes(self, params: Params, angle: Array, velocity: Array) -> Array:
        """Stacked amplitudes of all position-dependent loads, ``(k,)``."""
        parts = []
        for e in self.effects:
            with blamed(e, "load_amplitudes"):
                amplitude = e.load_amplitudes(params, angle, velocity)
            k = np.shape(amplitude)[0] if np.ndim(amplitude) == 1 else 0
            parts.append(returned(e, "load_amplitudes", amplitude, (k,),
                                  "one amplitude per load shape", broadcast=False))
        parts = [a for a in parts if np.shape(a)[0]]  # no empty arrays (a GPU kernel has none)
        return jnp.concatenate(parts) if parts else jnp.zeros((0,))

    def input_torque(self, params: Params, torque: Array, h: float) -> Array:
        """The drive's torque from the logged input after every input effect (delay, lag), plus
        each effect's torque from the input signal itself (a formula in ``u`` and ``t``).

        ``torque`` is the input signal on a grid of step ``h`` (N m for a torque drive).
        """
        signal, torque = torque, self.drive.torque(torque)
        for effect in self.effects:
            with blamed(effect, "input_torque"):
                changed = effect.input_torque(params, torque, h)
            torque = returned(effect, "input_torque", changed, jnp.shape(torque),
                              "the torque at each instant", broadcast=False)
        for effect in self.effects:
            with blamed(effect, "signal_torque"):
                extra = effect.signal_torque(params, signal, h)
            if extra is not None:
                torque = torque + returned(effect, "signal_torque", extra, jnp.shape(torque),
                                           "the torque at each instant", broadcast=False)
        return torque

    def readings(self, params: Params, readings: Mapping[str, Array]) -> dict[str, Array]:
        """Output channels (by name) after every effect's calibration (a sensor gain, offset)."""
        readings = dict(readings)
        for effect in self.effects:
            with blamed(effect, "readings"):
                changed = effect.readings(params, readings)
            if not isinstance(changed, Mapping) or set(readings) - set(changed):
                said = (f"without {sorted(set(readings) - set(changed))}"
                        if isinstance(changed, Mapping) else shown(changed))
                raise EffectError(f"effect {effect_label(effect)}: readings returned {said}; "
                                  f"expected every channel it was given: {sorted(readings)}")
            readings = {c: returned(effect, "readings", changed[c], jnp.shape(readings[c]),
                                    f"channel {c}") if c in readings else changed[c]
                        for c in changed}
        return readings
