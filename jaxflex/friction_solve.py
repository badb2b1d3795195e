"""The joint-friction solve of each step: ``v + gain·f(v) = target`` for the end-of-step joint
velocity, converged to round-off in every step (stick phases included), with gradients by the
implicit-function theorem.

The end-of-step joint velocity is affine in the joint torque, so the stiff smooth-Coulomb law
near zero velocity stays stable at any step (:mod:`jaxflex.simulation`). The solve starts from a
Newton step off the previous step's velocity (:func:`warm_start`), takes :data:`NEWTON_STEPS`
plain Newton steps as straight-line code, and only where the round-off test then fails
(breakaway, stops: a small share of the steps) solves again with a safeguarded loop
(:func:`bracketed_newton`); it hands on the friction it evaluated at the root
(:func:`friction_at_root`).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jaxtyping import Array

from jaxflex.parameters import Params

MAX_FRICTION_ITERATIONS = 100
"""Upper bound on the friction solve's evaluations of the law (it stops at round-off, usually
after :data:`NEWTON_STEPS` + 1)."""
RESIDUAL_ULPS = 16.0
"""The friction residual counts as converged within this many ulps of its terms."""
NEWTON_STEPS = 2
"""Plain Newton steps of the friction solve before its round-off test; a lane that fails the
test (breakaway, stops) is solved again by the safeguarded loop. Straight-line steps cost
far less than turns of a loop (``benchmarks/profile_simulate.py`` times 0 to 3 of them)."""


def bracketed_newton(residual, lo: Array, hi: Array, guess: Array, *, fused: bool = False):
    """Root of the increasing scalar ``residual`` in ``[lo, hi]``, converged to round-off.

    ``residual(v)`` returns ``(r, slope, scale, extra)``, ``scale`` being the size of the terms
    that make up ``r`` (its round-off is a few ulps of it) and ``extra`` any values worth keeping
    from the evaluation (the friction there).

    First :data:`NEWTON_STEPS` plain Newton steps from ``guess``, straight-line code that XLA
    fuses; a lane whose result lies in the bracket with its residual at round-off is done. The
    others (breakaway, stops) restart from ``guess`` in a safeguarded
    loop: Newton steps that leave the bracket fall back to bisection, so every iteration shrinks
    it; it stops when the residual is at round-off, the Newton step is below an ulp of ``v``,
    the bracket has collapsed or an iteration left ``v`` unchanged, and after
    :data:`MAX_FRICTION_ITERATIONS` at the latest. Every lane ends on a point it evaluated.
    Returns the root, the evaluations taken and ``extra`` at the root.

    ``fused``: for the lanes of a GPU kernel, which computes each value once (no barrier) and
    loops on one condition for all its lanes (:func:`lane_loop`).
    """
    barrier = (lambda x: x) if fused else jax.lax.optimization_barrier
    eps = jnp.finfo(jnp.result_type(guess)).eps

    def at_round_off(r, scale):
        return jnp.abs(r) <= RESIDUAL_ULPS * eps * scale

    def step(carry):
        v, _, lo, hi, converged, count, _ = carry
        # one value of each quantity for every use below (XLA could otherwise recompute the
        # residual in several fused kernels that round differently and never agree)
        r, slope, scale, extra = barrier(residual(v))
        lo = jnp.where(r < 0.0, v, lo)
        hi = jnp.where(r > 0.0, v, hi)
        newton = v - r / jnp.where(slope > 0.0, slope, 1.0)
        ok = (slope > 0.0) & (newton > lo) & (newton < hi)
        new = jnp.where(ok, newton, 0.5 * (lo + hi))
        done = (
            converged  # a converged lane stays put: batched loops run until every lane is done
            | at_round_off(r, scale)
            | (jnp.abs(new - v) <= eps * jnp.abs(v))
            | (hi - lo <= eps * jnp.maximum(jnp.abs(lo), jnp.abs(hi)))
            | (count + 1 >= MAX_FRICTION_ITERATIONS)  # the last one keeps the point it evaluated
        )
        return jnp.where(done, v, new), v, lo, hi, done, count + 1, extra

    def running(carry):
        v, previous, _, _, done, count, _ = carry
        # an iteration that leaves v unchanged has nothing left to do, whatever the test said
        return ~done & (v != previous) & (count < MAX_FRICTION_ITERATIONS)

    v0 = jnp.clip(guess, lo, hi)
    v = v0
    for _ in range(NEWTON_STEPS):  # a slope <= 0 gives inf or NaN, which fails the test below
        r, slope, _, _ = residual(v)
        v = v - r / slope
    r, _, scale, extra = barrier(residual(v))
    fast = at_round_off(r, scale) & (v >= lo) & (v <= hi)
    start = (
        jnp.where(fast, v, v0),
        jnp.full_like(v0, jnp.nan),
        lo,
        hi,
        fast,
        jnp.full_like(v0, NEWTON_STEPS + 1, dtype=int),
        extra,  # where not fast, the loop's first turn replaces it (previous is NaN: it turns)
    )
    loop = lane_loop if fused else jax.lax.while_loop
    v, _, _, _, _, count, extra = loop(running, step, start)
    return v, count, extra


def lane_loop(running, step, start):
    """``jax.lax.while_loop(running, step, start)`` for the vmapped lanes of a GPU kernel:
    Triton's loops take one condition, not a condition per lane, so vmapped it turns while any
    lane runs and holds the lanes that have stopped, as a batched loop does."""
    # the closures' traced values as explicit arguments, so that the batching rule sees them
    step, step_consts = jax.closure_convert(step, start)
    running, running_consts = jax.closure_convert(running, start)

    @jax.custom_batching.custom_vmap
    def loop(start, step_consts, running_consts):
        return jax.lax.while_loop(
            lambda c: running(c, *running_consts), lambda c: step(c, *step_consts), start
        )

    @loop.def_vmap
    def loop_lanes(size, batched, start, step_consts, running_consts):
        start = jax.tree.map(
            lambda x, b: x if b else jnp.broadcast_to(x, (size, *jnp.shape(x))), start, batched[0]
        )

        def lanes(fn, consts_batched):
            axes = jax.tree.map(lambda b: 0 if b else None, consts_batched)
            return jax.vmap(fn, in_axes=(0, *axes))

        lane_step, lane_running = lanes(step, batched[1]), lanes(running, batched[2])

        def turn(c):
            turning = lane_running(c, *running_consts)
            new = lane_step(c, *step_consts)
            return jax.tree.map(
                lambda n, o: jnp.where(turning.reshape(-1, *(1,) * (n.ndim - 1)), n, o), new, c
            )

        def any_running(c):
            return jnp.max(lane_running(c, *running_consts).astype(jnp.int32)) > 0

        out = jax.lax.while_loop(any_running, turn, start)
        return out, jax.tree.map(lambda _: True, out)

    return loop(start, step_consts, running_consts)


def joint_velocity_solve(
    friction, target: Array, gain: Array, guess: Array, fused: bool = False
):
    """Solve ``v + gain·f(v) = target`` for the end-of-step joint velocity ``v``.

    ``f`` is any friction law with ``f(0) = 0`` and ``sign f(v) = sign v``, so the root lies
    between 0 and ``target``; a safeguarded Newton iteration converges it to round-off
    (:func:`bracketed_newton`), stick phases included. Gradients follow from the implicit-function
    theorem (:func:`jax.lax.custom_root`), so reverse mode stores no iterations. Returns the root
    and, from the solve's last evaluation, ``(f, f')`` there (without derivatives: see
    :func:`friction_at_root`).
    """

    def residual(v):
        return v + gain * friction(v) - target

    def solve(residual, guess):
        def with_slope(v):
            f, df = jax.jvp(friction, (v,), (jnp.ones_like(v),))
            scale = jnp.abs(v) + jnp.abs(gain * f) + jnp.abs(target)
            return v + gain * f - target, 1.0 + gain * df, scale, (f, df)

        lo, hi = jnp.minimum(0.0, target), jnp.maximum(0.0, target)
        root, _, friction_there = bracketed_newton(with_slope, lo, hi, guess, fused=fused)
        return root, friction_there

    return jax.lax.custom_root(residual, guess, solve, lambda g, y: y / g(1.0), has_aux=True)


def friction_at_root(friction_and_slope, params: Params, v: Array, evaluated):
    """``friction_and_slope(params, v)``, taken from ``evaluated`` (the solve's own evaluation
    at ``v``) when nothing differentiates it: a plain run evaluates the law once less per
    step. Differentiated (to any order), it is the law itself, values and derivatives."""

    @jax.custom_jvp
    def at_root(params, v, evaluated):
        return evaluated

    @at_root.defjvp
    def at_root_jvp(primals, tangents):
        params, v, _ = primals
        d_params, d_v, _ = tangents
        return jax.jvp(friction_and_slope, (params, v), (d_params, d_v))

    return at_root(params, v, evaluated)


def warm_start(v: Array, f: Array, slope: Array, target: Array, gain: Array) -> Array:
    """Start of the friction solve: one Newton step on ``v + gain·f(v) = target`` from the
    previous step's velocity ``v``, with the friction ``f`` and slope there (no new evaluation).

    Sliding, the friction law is nearly linear over a step and this lands within round-off of
    the root; a slope that is not positive (a falling Stribeck branch) takes a plain step.
    """
    denominator = 1.0 + gain * slope
    return v - (v + gain * f - target) / jnp.where(denominator > 0.0, denominator, 1.0)
