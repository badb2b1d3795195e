"""The interface every physical effect implements, and the base joint-friction law.

An effect is a small :class:`equinox.Module` that declares its parameters (with bounds and a
*null value* at which it vanishes) and overrides one or more hooks of the model:

* :meth:`~AbstractEffect.structure` — change the mass or stiffness matrices (a payload, a
  compliant root);
* :meth:`~AbstractEffect.friction` — add a joint torque opposing the joint velocity (Stribeck
  friction);
* :meth:`~AbstractEffect.loads` — add position-dependent generalised forces
  ``Σ_i a_i(θ, θ') · f_i`` with constant shapes ``f_i`` (gravity in a tilted plane);
* :meth:`~AbstractEffect.input_torque` — transform the applied torque signal (a delay, a motor
  lag);
* :meth:`~AbstractEffect.signal_torque` — add a torque computed from the drive's input signal
  and time (a formula's terms in ``u`` and ``t``, :mod:`jaxflex.effects.formula`);
* :meth:`~AbstractEffect.readings` — act on the named output channels after the solve (a
  sensor's gain or offset): the motion is untouched, only what is read changes.

At the null values every hook must return its input unchanged (or add exactly zero), so the model
with the effect *is* the base model there and score tests can differentiate at that point.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator, Mapping
from typing import Any, ClassVar

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from jaxflex._arguments import raised
from jaxflex.parameters import ParameterSpec, Params
from jaxflex.testbed import Testbed


class Structure(eqx.Module):
    """Structural matrices over ``q = [theta, w_1, w'_1, …]`` for one parameter set.

    Damping is not stored: the simulator applies Rayleigh damping ``α·P M P + β·K`` on the
    elastic coordinates (``P`` removes the hub row and column), as the testbed specifies.
    """

    mass: Float[Array, "n n"]
    stiffness: Float[Array, "n n"]
    first_moment: Float[Array, " n"]  # generalised load of a unit uniform transverse field
    tip: Float[Array, " n"]  # row selecting the tip deflection w(L)
    root_curvature: Float[Array, " n"]  # row giving w''(0)
    length: float = eqx.field(static=True)


class AbstractEffect(eqx.Module):
    """Base class of a physical effect; subclasses override the hooks they need.

    Class attributes document the effect for people and for the discovery ranking:
    ``name`` (registry key), ``parameters`` (their specs, each with a ``null``),
    ``description`` (the physics, one paragraph) and ``signature`` (how it shows in the residuals).
    """

    name: ClassVar[str] = "effect"
    parameters: ClassVar[tuple[ParameterSpec, ...]] = ()
    description: ClassVar[str] = ""
    signature: ClassVar[str] = ""
    needs_declaration: ClassVar[bool] = False
    """True for an effect that exists only as declared (a formula): the library holds no
    default instance of it."""
    limits: ClassVar[Mapping[str, tuple[float, float]]] = {}
    """The widest range physics allows each parameter, by name (``{}``: its bounds are its
    limits). A discovery refit that ends on a bound is refitted once with the bound moved out
    to the limit (:func:`jaxflex.discovery.discover`)."""

    def physical_limits(self, testbed: Testbed, params: Mapping[str, float]
                        ) -> dict[str, tuple[float, float]]:
        """:attr:`limits` for the link ``testbed`` and the fitted base ``params`` (an effect
        whose limit scales with the link, its mass or its stiffness, overrides this)."""
        return dict(self.limits)

    def structure(self, structure: Structure, params: Params) -> Structure:
        """Modify mass or stiffness; the default leaves them unchanged."""
        return structure

    def friction(self, params: Params, velocity: Array, omega_s: float) -> Array:
        """Extra joint torque opposing ``velocity`` (rad/s); zero by default."""
        return jnp.zeros_like(velocity)

    def loads(self, structure: Structure, params: Params) -> Float[Array, "k n"]:
        """Shapes ``f_i`` of position-dependent generalised forces; none by default."""
        return jnp.zeros((0, structure.mass.shape[0]))

    def load_amplitudes(self, params: Params, angle: Array, velocity: Array) -> Float[Array, " k"]:
        """Amplitudes ``a_i(θ, θ')`` multiplying the shapes of :meth:`loads`; none by default (a
        NumPy array: nothing is computed, and a GPU kernel holds no empty arrays)."""
        return np.zeros((0,))

    def input_torque(self, params: Params, torque: Float[Array, " m"], h: float) -> Array:
        """Torque reaching the joint from the applied torque on a grid of step ``h``."""
        return torque

    def signal_torque(self, params: Params, signal: Float[Array, " m"], h: float) -> Array | None:
        """Torque added at the joint from the drive's input ``signal`` (in the drive's unit, on
        a grid of step ``h`` from the record's start); None (the default) adds nothing."""
        return None

    def readings(
        self, params: Params, readings: Mapping[str, Float[Array, "*batch n"]]
    ) -> dict[str, Float[Array, "*batch n"]]:
        """Output channels after the solve, by name (the simulator's output names, e.g.
        ``root_strain``); the default leaves them unchanged."""
        return dict(readings)


class EffectError(ValueError):
    """An effect's hook raised, or returned what the model cannot use; the one-line message
    names the effect's class, the hook and what it returned."""


def effect_label(effect: AbstractEffect) -> str:
    """``ClassName ('name')`` of an effect, or of the one a wrapper holds (``inner``)."""
    inner = getattr(effect, "inner", effect)
    return f"{type(inner).__name__} ({effect.name!r})"


@contextlib.contextmanager
def blamed(effect: AbstractEffect, hook: str) -> Iterator[None]:
    """Run one of ``effect``'s hooks: an exception it raises (often in JAX's words, from deep
    inside a trace) is an :class:`EffectError` that names the effect and the hook first."""
    try:
        yield
    except EffectError:
        raise
    except Exception as exc:
        raise EffectError(f"effect {effect_label(effect)}: {hook} raised {raised(exc)}") from exc


def returned(effect: AbstractEffect, hook: str, value: Any, shape: tuple[int, ...],
             what: str, *, broadcast: bool = True) -> Any:
    """``value`` when it is a real array whose shape is ``shape`` (or, with ``broadcast``,
    broadcasts to it); else an :class:`EffectError` naming the effect, the hook, the shape and
    dtype it returned and the one expected (``what`` says what that is)."""
    got = _shape_dtype(value)
    if got is not None and np.issubdtype(got[1], np.number) and not np.issubdtype(
            got[1], np.complexfloating):
        if got[0] == tuple(shape) or (broadcast and _broadcasts(got[0], shape)):
            return value
    said = f"an array of shape {got[0]}, {got[1]}" if got else type(value).__name__
    raise EffectError(f"effect {effect_label(effect)}: {hook} returned {said}; expected real "
                      f"values of shape {tuple(shape)} ({what})")


def _shape_dtype(value: Any) -> tuple[tuple[int, ...], np.dtype] | None:
    """The shape and dtype of an array (a tracer too) or a Python number; None otherwise."""
    if hasattr(value, "shape") and hasattr(value, "dtype"):
        return tuple(value.shape), np.dtype(value.dtype)
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        return (), np.dtype(type(value))
    return None


def _broadcasts(got: tuple[int, ...], shape: tuple[int, ...]) -> bool:
    try:
        return np.broadcast_shapes(got, shape) == tuple(shape)
    except ValueError:
        return False


def joint_friction(params: Params, velocity: Array, omega_s: float) -> Array:
    """Base friction law ``b_v·θ' + tau_c·tanh(θ'/omega_s)`` (a smooth Coulomb law)."""
    return params["b_v"] * velocity + params["tau_c"] * jnp.tanh(velocity / omega_s)
