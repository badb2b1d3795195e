"""A whole population's time loop in one GPU kernel (Pallas, Triton).

On a GPU, :func:`jaxflex.simulation.simulate_batch`'s XLA program runs each sub-step as a chain
of small kernels, each a pass through the population's state in memory. Here one kernel runs the
whole record: each program of its grid takes a block of candidates (its lanes), holds their state
and steps it through every sample, writing the outputs as it goes.
The step is the simulator's own (:func:`jaxflex.simulation.model_dynamics` with ``fused=True``,
vmapped over the lanes: its products written as sums, since Triton has no float64 matrix units,
and the friction solve's loop shared by the lanes); only the per-candidate coefficients (the
modal decomposition) are formed outside, by XLA (:func:`jaxflex.simulation.step_coefficients`).
Measured on an H200 (``benchmarks/results/gpu_h200.json``): 88,000 simulations/s at population
10,000, 5.4× the XLA program on the same GPU.

Triton's arrays have power-of-two sizes and none is empty: the modes and the stations are padded
with zeros up to a power of two (a padded mode has no coefficients and stays at rest, a padded
station reads nothing and is dropped), the population up to whole blocks, and empty inputs (no
loads) stay out of the kernel. A model that advances only some modes, or whose position-dependent
loads do not come in a power of two, runs through the XLA program instead (:func:`supports`).
"""

from __future__ import annotations

import os

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from jaxflex.model import Model
from jaxflex.parameters import Params
from jaxflex.simulation import (
    Outputs,
    StepCoefficients,
    model_dynamics,
    step_coefficients,
    with_readings,
)

BLOCK = 32
"""Candidates one program of the kernel steps together (one warp's lanes)."""


def _power_of_two(n: int) -> bool:
    return n > 0 and n & (n - 1) == 0


def _power_above(n: int) -> int:
    """The least power of two not below ``n`` (n ≥ 1)."""
    return 1 << (n - 1).bit_length()


def supports(model: Model) -> bool:
    """Whether :func:`simulate_fused` runs ``model``: every mode advanced, and position-dependent
    loads none or a power of two in number."""
    loads = jax.eval_shape(
        lambda: model.load_amplitudes(model.space.reference(), jnp.zeros(()), jnp.zeros(()))
    ).shape[0]
    return model.n_modes is None and (loads == 0 or _power_of_two(loads))


def preferred(model: Model) -> bool:
    """Whether populations of ``model`` run through the fused kernel: on a GPU where
    :func:`supports` allows it, unless ``JAXFLEX_FUSED=0``."""
    enabled = os.environ.get("JAXFLEX_FUSED", "1") != "0"
    return enabled and jax.default_backend() == "gpu" and supports(model)


def _lane_coefficients(c: StepCoefficients, modes: int, stations: int) -> StepCoefficients:
    """``c`` with its mode axis padded with zeros to ``modes`` and its stations to ``stations``
    (a padded station reads nothing), without what the time loop never reads (the mode shapes
    and the rest state)."""
    m, k = c.system.hub.shape[-1], c.system.station_radius.shape[0]

    def pad(a: Array, rows: int = 0) -> Array:  # the mode axis last, rows (stations) first
        leading = [(0, rows)] + [(0, 0)] * (a.ndim - 2) if a.ndim > 1 else []
        return jnp.pad(a, [*leading, (0, modes - m)])

    system = c.system
    system = eqx.tree_at(
        lambda s: (s.maps, s.damping, s.omega2, s.hub, s.load_modal, s.tip, s.root_curvature,
                   s.stations, s.station_radius, s.shapes, s.initial),
        system,
        (
            jax.tree_util.tree_map(pad, system.maps),
            pad(system.damping),
            pad(system.omega2),
            pad(system.hub),
            pad(system.load_modal),
            pad(system.tip),
            pad(system.root_curvature),
            tuple(pad(rows, stations - k) for rows in system.stations),
            jnp.pad(system.station_radius, (0, stations - k)),
            jnp.zeros((modes,)),
            (system.initial[0], jnp.zeros((modes,))),
        ),
    )
    vectors = (c.gx_p, c.gv_p, c.p2, c.a12, c.a22, c.bx, c.bv)
    return eqx.tree_at(
        lambda c: (c.system, c.gx_p, c.gv_p, c.p2, c.a12, c.a22, c.bx, c.bv),
        c,
        (system, *(pad(v) for v in vectors)),
    )


def simulate_fused(
    model: Model,
    params: Params,
    torque: Float[Array, " n"] | Float[Array, "P n"],
    dt: float,
    *,
    block: int = BLOCK,
    num_warps: int = 1,
    interpret: bool | None = None,
) -> Outputs:
    """Simulate a population (each parameter ``(P,)``) in one kernel, under one torque record
    or, ``(P, n)``, each candidate under its own; pure and traceable. Gives
    :func:`jaxflex.simulation.simulate_core`'s outputs, vmapped, to round-off (the products are
    summed in another order).

    ``interpret`` runs the kernel through Pallas' interpreter (default: where the default backend
    is not a GPU; slow, for tests)."""
    from jax.experimental import pallas as pl

    if not supports(model):
        raise ValueError(
            "simulate_fused: the model advances only some modes, or has position-dependent "
            "loads not in a power of two; simulate_batch runs it"
        )
    if not _power_of_two(block):
        raise ValueError(f"simulate_fused: block must be a power of two, got {block}")
    if interpret is None:
        interpret = jax.default_backend() != "gpu"
    population = next(iter(params.values())).shape[0]
    torque = jnp.broadcast_to(torque, (population, torque.shape[-1]))
    lanes = -(-population // block) * block
    params, torque = jax.tree.map(
        lambda v: jnp.pad(v, [(0, lanes - population)] + [(0, 0)] * (v.ndim - 1), mode="edge"),
        (params, torque),
    )
    n, n_sub = torque.shape[1], model.n_substeps

    def prepare(q, torque):
        c = step_coefficients(model, q, dt)
        dynamics = model_dynamics(model, q, dt, c)
        return c, dynamics.start(None), dynamics.fine_torque(torque)

    coefficients, state, fine = jax.vmap(prepare)(params, torque)
    modes = _power_above(coefficients.system.hub.shape[-1])
    stations = _power_above(len(model.stations)) if model.stations else 0
    coefficients = jax.vmap(lambda c: _lane_coefficients(c, modes, stations))(coefficients)
    theta_r, vel_r, eta, deta, *friction = state
    eta, deta = (jnp.pad(a, ((0, 0), (0, modes - a.shape[1]))) for a in (eta, deta))
    state = (theta_r, vel_r, eta, deta, *friction)
    fine = jnp.moveaxis(fine, 0, -1)  # (n, n_sub, lanes): a sample's torques side by side

    leaves, treedef = jax.tree_util.tree_flatten((params, coefficients, state))
    carried = [a for a in leaves if a.size]  # an empty one (no loads) stays a constant
    lane_axes = jax.tree_util.tree_unflatten(treedef, [0 if a.size else None for a in leaves])

    def lane_inputs(values):
        """``(params, coefficients, state)`` from the carried leaves' ``values``."""
        values = iter(values)
        return jax.tree_util.tree_unflatten(
            treedef, [next(values) if a.size else np.zeros(a.shape[1:], a.dtype) for a in leaves]
        )

    def observe(q, c, s, tau):
        return model_dynamics(model, q, dt, c, fused=True).observe(s, tau)

    def advance(q, c, s, taus):
        return model_dynamics(model, q, dt, c, fused=True).advance(s, taus)

    observe_lanes = jax.vmap(observe, in_axes=(*lane_axes, 0))
    advance_lanes = jax.vmap(advance, in_axes=(*lane_axes, 0))
    signals = jax.eval_shape(observe_lanes, *lane_inputs(carried), fine[0, 0])
    signal_leaves, signal_def = jax.tree_util.tree_flatten(signals)

    def kernel(*refs):
        k = len(carried)
        in_refs, fine_ref, out_refs = refs[:k], refs[k], refs[k + 1 :]
        q, c, s = lane_inputs(ref[...] for ref in in_refs)

        def sample(t, s):
            taus = tuple(fine_ref[t, j] for j in range(n_sub))
            outputs = observe_lanes(q, c, s, taus[0])
            for ref, value in zip(out_refs, jax.tree_util.tree_leaves(outputs), strict=True):
                ref[t] = value.T  # (…, lanes): the lanes side by side in memory
            return advance_lanes(q, c, s, taus)

        jax.lax.fori_loop(0, n, sample, s)

    def lanes_of(a):
        trailing = (0,) * (a.ndim - 1)
        return pl.BlockSpec((block, *a.shape[1:]), lambda i: (i, *trailing))

    def samples_of(shape):  # (n, …, lanes)
        leading = (0,) * (len(shape) - 1)
        return pl.BlockSpec((*shape[:-1], block), lambda i: (*leading, i))

    out_shapes = [(n, *o.shape[1:][::-1], lanes) for o in signal_leaves]
    outs = pl.pallas_call(
        kernel,
        out_shape=[
            jax.ShapeDtypeStruct(s, o.dtype)
            for s, o in zip(out_shapes, signal_leaves, strict=True)
        ],
        grid=(lanes // block,),
        in_specs=[lanes_of(a) for a in carried] + [samples_of(fine.shape)],
        out_specs=[samples_of(s) for s in out_shapes],
        interpret=interpret,
        **({} if interpret else _triton_parameters(num_warps)),
    )(*carried, fine)
    outs = [jnp.moveaxis(o, -1, 0)[:population] for o in outs]  # (population, n, …)
    outs = [o[..., : len(model.stations)] if o.ndim == 3 else o for o in outs]  # real stations
    outputs = Outputs(*jax.tree_util.tree_unflatten(signal_def, outs))
    return jax.vmap(lambda o: with_readings(model, o))(outputs)


def _triton_parameters(num_warps: int) -> dict:
    from jax.experimental.pallas import triton as pltriton

    return {"compiler_params": pltriton.CompilerParams(num_warps=num_warps, num_stages=1)}
