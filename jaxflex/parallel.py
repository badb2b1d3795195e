"""Populations spread over the host's CPU cores.

XLA runs one program on one CPU device single-threaded for programs as small as a time step of
the simulator, so a vmapped population uses one core. Importing jaxflex therefore exposes one
JAX CPU device per usable core (:func:`configure_host_devices`), and :func:`population_vmap`
splits the leading population axis across them: each device runs its share of the candidates in
its own thread, inside the same compiled program (the evaluation of a DE/GA/PSO generation
stays one call).

The number of devices comes from ``JAXFLEX_HOST_DEVICES`` if set, else the cores this process
may use (at most :data:`MAX_HOST_DEVICES`). Nothing changes if JAX was already started, if the
user set ``jax_num_cpu_devices`` or ``--xla_force_host_platform_device_count`` themselves, or on
a machine whose default backend is an accelerator (one device there: no split).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TypeVar

import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec

from jaxflex._host import (
    MAX_HOST_DEVICES,
    configure_host_devices,
    default_host_devices,
    usable_cores,
)

LANES = 8
"""Each device's share is padded to a multiple of this many candidates: XLA's CPU code runs the
candidates in SIMD vectors of up to 8 doubles (AVX-512) and computes a partial vector at the end
of a share with other instructions, which may round a last candidate differently; with whole
vectors every candidate rounds alike whatever the share's size."""
BLOCK = 104
"""Candidates one CPU device simulates at once; larger shares run block after block
(``lax.map``), which keeps the working set in cache: about 100 at a time run faster per candidate
than 500 at once. An accelerator runs its whole share at once (its threads need the width)."""
MIN_PER_DEVICE = 16
"""Smaller populations are not split: below it, waiting for the other devices costs more than
their help."""
_AXIS = "population"

_T = TypeVar("_T")


def population_devices() -> list[jax.Device]:
    """The devices a population is split across: all of the default backend's."""
    return jax.devices()


def _mesh() -> Mesh:
    return Mesh(np.asarray(population_devices()), (_AXIS,))


def gathered_sharding() -> NamedSharding | None:
    """The layout of :func:`gathered` arrays: on every device (None with a single device)."""
    if len(population_devices()) == 1:
        return None
    return NamedSharding(_mesh(), PartitionSpec())


def gathered(tree: _T) -> _T:
    """``tree`` with every array on every device (inside ``jit``: a sharding constraint).

    Programs that pass their outputs back in as inputs (a generation step) use it so that the
    layout of what they return matches the layout they were compiled for.
    """
    sharding = gathered_sharding()
    if sharding is None:
        return tree
    return jax.tree.map(lambda x: jax.lax.with_sharding_constraint(x, sharding), tree)


def _population_size(population) -> int:
    leaves = jax.tree.leaves(population)
    if not leaves or any(jnp.ndim(x) == 0 for x in leaves):
        raise ValueError("a population needs at least one array with a leading population axis")
    return leaves[0].shape[0]


def _on_cpu() -> bool:
    """Whether :func:`population_devices` are CPU devices (not an accelerator)."""
    return population_devices()[0].platform == "cpu"


def _blockwise(fn: Callable[..., _T], population, *args) -> _T:
    """vmap of ``fn`` over the population, :data:`BLOCK` candidates at a time on the CPU."""
    if _on_cpu() and _population_size(population) > BLOCK:
        return jax.lax.map(lambda x: fn(x, *args), population, batch_size=BLOCK)
    return jax.vmap(fn, in_axes=(0,) + (None,) * len(args))(population, *args)


def population_vmap(fn: Callable[..., _T], population, *args, lanes: int = LANES,
                    min_per_device: int = MIN_PER_DEVICE) -> _T:
    """``jax.vmap(fn, (0, None, ...))(population, *args)``, split across :func:`population_devices`.

    ``population`` is an array (or a pytree of arrays) with the population on its leading axis;
    the other ``args`` are shared by every candidate. The population is padded (with copies of
    its first candidate) to a multiple of ``lanes`` per device, each device computes its share,
    :data:`BLOCK` candidates at a time, and the results (those of the plain vmap) are gathered
    onto every device; a population of fewer than ``min_per_device`` per device is not split.
    Works inside ``jit`` and outside it.

    With the default ``lanes`` (:data:`LANES`) every candidate's result is the same bits on any
    number of devices from two up: the work always runs as the body of a ``shard_map``,
    candidates never interact (no reduction crosses them), and a population too small to split
    is computed whole on every device rather than in a program of another kind. A one-device
    process compiles the body as part of one ordinary program, which XLA may round differently
    in the last ulp.
    """
    for name, value in (("lanes", lanes), ("min_per_device", min_per_device)):
        if not (isinstance(value, int) and value >= 1):
            raise ValueError(f"population_vmap: {name} must be an int >= 1, got {value!r}")
    devices = population_devices()
    size = _population_size(population)
    split = len(devices) > 1 and size >= min_per_device * len(devices)
    shares = len(devices) if split else 1
    pad = -size % (shares * lanes)
    if pad:
        population = jax.tree.map(
            lambda x: jnp.concatenate([x, jnp.broadcast_to(x[:1], (pad, *x.shape[1:]))]),
            population,
        )
    spec = PartitionSpec(_AXIS) if split else PartitionSpec()

    def share(population, *args):
        # the barriers keep each device's work a program of its own on one device as on several
        population, args = jax.lax.optimization_barrier((population, args))
        return jax.lax.optimization_barrier(_blockwise(fn, population, *args))

    body = jax.shard_map(
        share,
        mesh=_mesh(),
        in_specs=(spec,) + (PartitionSpec(),) * len(args),
        out_specs=spec,
        check_vma=False,
    )
    return gathered(jax.tree.map(lambda y: y[:size], jax.jit(body)(population, *args)))


__all__ = [
    "BLOCK",
    "LANES",
    "MAX_HOST_DEVICES",
    "MIN_PER_DEVICE",
    "configure_host_devices",
    "default_host_devices",
    "gathered",
    "gathered_sharding",
    "population_devices",
    "population_vmap",
    "usable_cores",
]
