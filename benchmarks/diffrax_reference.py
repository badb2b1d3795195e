"""The alternative a JAX user would write: the model's ODE handed to diffrax, vmapped.

Same model as :mod:`jaxflex.simulation` — the FEM mass and stiffness of
:meth:`jaxflex.model.Model.structure`, Rayleigh damping ``α·P M P + β·K`` on the elastic
coordinates, the joint friction of :meth:`jaxflex.model.Model.friction` — written as the
first-order system ``x = [q, q']``, ``M q'' + D q' + K q = e_θ (τ − τ_f(θ'))`` in physical
coordinates (no modal basis, no stepping scheme of jaxflex's), and integrated by diffrax's
implicit Kvaerno5 with an adaptive step (PID controller). The torque is held over each sample
(zero-order hold); the controller is told where it jumps (``jump_ts``) so that it restarts
there instead of stepping across the discontinuity. One compiled program serves every tolerance:
``rtol`` and ``atol`` are arguments, not constants.
"""

from __future__ import annotations

import diffrax
import jax
import jax.numpy as jnp
import numpy as np

from jaxflex.model import Model
from jaxflex.parameters import Params

MAX_STEPS = 200_000
"""Steps allowed per record before diffrax gives up (far above what the tolerances need)."""


def equations_of_motion(model: Model, params: Params):
    """``(f, tip_acceleration, n)``: the right-hand side ``f(t, x, τ)``, the tip acceleration
    of a state's derivative and the number of coordinates, for one parameter set."""
    structure = model.structure(params)
    mass, stiffness = structure.mass, structure.stiffness
    n = mass.shape[0]
    elastic = jnp.ones(n).at[0].set(0.0)
    damping = params["alpha"] * mass * jnp.outer(elastic, elastic) + params["beta"] * stiffness
    inv_mass = jnp.linalg.inv(mass)
    mk, md, me = inv_mass @ stiffness, inv_mass @ damping, inv_mass[:, 0]

    def field(t, x, torque):
        q, v = x[:n], x[n:]
        acceleration = me * (torque - model.friction(params, v[0])) - md @ v - mk @ q
        return jnp.concatenate([v, acceleration])

    def tip_acceleration(dx):
        acc = dx[n:]
        return structure.length * acc[0] + acc @ structure.tip

    return field, tip_acceleration, n


def simulate(model: Model, params: Params, torque, dt: float, rtol, atol):
    """Joint angle and tip acceleration at the samples of ``torque`` (a NumPy array, held)."""
    torque = np.asarray(torque, dtype=float)
    jumps = jump_times(torque, dt)
    count = torque.shape[0]
    field, tip_acceleration, n = equations_of_motion(model, params)
    times = dt * jnp.arange(count)

    levels = jnp.asarray(np.concatenate([torque[:1], torque[1:][np.diff(torque) != 0.0]]))

    def held(t):  # the value after the last jump at or before t (right-hand limit)
        return levels[jnp.searchsorted(jumps, t, side="right")]

    term = diffrax.ODETerm(lambda t, x, args: field(t, x, held(t)))
    solution = diffrax.diffeqsolve(
        term,
        diffrax.Kvaerno5(),
        t0=0.0,
        t1=float(dt * (count - 1)),
        dt0=dt / 4,
        y0=jnp.zeros(2 * n),
        saveat=diffrax.SaveAt(ts=times),
        stepsize_controller=diffrax.PIDController(rtol=rtol, atol=atol, jump_ts=jumps),
        max_steps=MAX_STEPS,
    )
    states = solution.ys
    rates = jax.vmap(field)(times, states, torque)
    return states[:, 0], jax.vmap(tip_acceleration)(rates)


def jump_times(torque: np.ndarray, dt: float) -> np.ndarray:
    """The instants where the held torque changes value."""
    return dt * (np.flatnonzero(np.diff(torque) != 0.0) + 1.0)


def batch(model: Model, torque: np.ndarray, dt: float):
    """A compiled ``(params, rtol, atol) → (joint_angle, tip_acceleration)``, vmapped over a
    population of parameter sets (the tolerances shared)."""

    def one(params, rtol, atol):
        return simulate(model, params, torque, dt, rtol, atol)

    return jax.jit(jax.vmap(one, in_axes=(0, None, None)))
