"""Populations split across CPU devices give the results of one plain vmap."""

import os
import subprocess
import sys
import textwrap

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxflex._host import host_devices_notice
from jaxflex.parallel import (
    BLOCK,
    MAX_HOST_DEVICES,
    default_host_devices,
    population_vmap,
    usable_cores,
)

SPLIT_CHECKS = textwrap.dedent(
    """
    import jax, jax.numpy as jnp, numpy as np
    import jaxflex
    from jaxflex import Model, make_records, simulate_batch
    from jaxflex.evolve import DE, PSO, run
    from jaxflex.objective import build_objective
    from jaxflex.parallel import population_vmap
    from jaxflex.signals import reference_input
    from jaxflex.simulation import simulate_core

    assert len(jax.devices()) == 3, jax.devices()
    # a population of 49 is padded to 51 and split three ways: the plain vmap's outputs
    model = Model()
    torque = reference_input("pulse", duration=0.3)[1]
    params = model.space.from_unit(np.random.default_rng(4).uniform(size=(49, 6)))
    plain = jax.jit(jax.vmap(lambda p: simulate_core(model, p, jnp.asarray(torque), 1e-3)))
    want, got = plain(params), simulate_batch(model, params, torque)
    for name in ("joint_angle", "tip_acceleration", "joint_torque"):
        a, b = np.asarray(getattr(got, name)), np.asarray(getattr(want, name))
        assert a.shape == b.shape == (49, torque.size)
        np.testing.assert_allclose(a, b, rtol=0, atol=1e-10 * np.abs(b).max())
    # inside jit
    x = jnp.linspace(0.0, 1.0, 50)
    y = jax.jit(lambda x: population_vmap(lambda v, k: jnp.sin(k * v), x, 2.0))(x)
    np.testing.assert_allclose(np.asarray(y), np.sin(2.0 * np.asarray(x)), rtol=1e-15)
    # eight split evenly, no whole vectors asked (a Jacobian block's tangents): padded to nine
    y = population_vmap(lambda v: jnp.sin(v), x[:8], lanes=1, min_per_device=1)
    assert y.shape == (8,) and len(y.sharding.device_set) == 3
    np.testing.assert_allclose(np.asarray(y), np.sin(np.asarray(x[:8])), rtol=1e-15)
    # generation steps whose fitness is split compile once, run and never get worse
    objective = build_objective(make_records(noise=False, duration=0.3))
    for strategy in (DE.paper(population=48), PSO.paper(population=48)):
        result = run(strategy, objective.fitness, len(objective.names), seed=0, generations=3)
        assert result.history_best[-1] <= result.history_best[0]
    print("ok", len(y.sharding.device_set))
    """
)


@pytest.mark.slow  # the fast suite runs three devices in the device-count hash test
def test_split_over_three_devices_in_a_fresh_process():
    """Device count from JAXFLEX_HOST_DEVICES; simulation, jit, DE and PSO runs all split."""
    env = {**os.environ, "JAXFLEX_HOST_DEVICES": "3", "JAX_PLATFORMS": "cpu"}
    result = subprocess.run(
        [sys.executable, "-c", SPLIT_CHECKS], env=env, capture_output=True, text=True, timeout=300
    )
    assert result.returncode == 0, result.stderr[-3000:]
    assert result.stdout.split()[-2:] == ["ok", "3"]


def test_pytrees_blocks_and_jit():
    def fn(candidate, shift):
        return {"sum": candidate["a"].sum() + candidate["b"] + shift, "a2": candidate["a"] ** 2}

    size = 2 * BLOCK + 3  # more than a block per device: runs block after block
    population = {"a": jnp.arange(3.0 * size).reshape(size, 3), "b": jnp.arange(size) * 1.0}
    want = jax.vmap(fn, in_axes=(0, None))(population, 0.5)
    for got in (
        population_vmap(fn, population, 0.5),
        jax.jit(lambda p: population_vmap(fn, p, 0.5))(population),
    ):
        np.testing.assert_array_equal(np.asarray(got["sum"]), np.asarray(want["sum"]))
        np.testing.assert_array_equal(np.asarray(got["a2"]), np.asarray(want["a2"]))
    one = population_vmap(fn, jax.tree.map(lambda x: x[:1], population), 0.0)
    assert one["sum"].shape == (1,)
    with pytest.raises(ValueError, match="leading population axis"):
        population_vmap(fn, {"a": jnp.ones(()), "b": jnp.ones(())}, 0.0)
    few = jax.tree.map(lambda x: x[:5], population)  # five, no padding asked
    got = population_vmap(fn, few, 0.5, lanes=1, min_per_device=1)
    np.testing.assert_array_equal(np.asarray(got["sum"]), np.asarray(want["sum"][:5]))
    for name, bad in (("lanes", 0), ("min_per_device", 1.5)):
        with pytest.raises(ValueError, match=f"population_vmap: {name} must be an int >= 1"):
            population_vmap(fn, few, 0.5, **{name: bad})


def test_device_count_setting_is_validated(monkeypatch):
    monkeypatch.setenv("JAXFLEX_HOST_DEVICES", "0")
    with pytest.raises(ValueError, match="JAXFLEX_HOST_DEVICES='0' must be an integer >= 1"):
        default_host_devices()
    monkeypatch.setenv("JAXFLEX_HOST_DEVICES", "two")
    with pytest.raises(ValueError, match="JAXFLEX_HOST_DEVICES='two'"):
        default_host_devices()
    monkeypatch.setenv("JAXFLEX_HOST_DEVICES", "5")
    assert default_host_devices() == 5
    monkeypatch.setenv("JAXFLEX_HOST_DEVICES", "100000")  # would take minutes to start
    assert default_host_devices() == max(usable_cores(), MAX_HOST_DEVICES)
    assert host_devices_notice().endswith(f"using {max(usable_cores(), MAX_HOST_DEVICES)} CPU "
                                          "devices")


def test_a_candidates_reductions_do_not_depend_on_how_many_share_its_device():
    """XLA would hand large batched reductions to a library kernel (chosen by size) that sums in
    another order than its own loops; importing jaxflex turns that off, so a candidate's sums
    are the same bits in a batch of 100 as in one of 40 or alone."""
    rows = np.random.default_rng(5).normal(size=(100, 3, 20))  # candidates, records, samples
    squares = jax.jit(jax.vmap(jax.vmap(lambda r: r @ r)))
    whole = np.asarray(squares(rows))
    for start, stop in ((0, 40), (40, 100), (7, 8)):
        part = np.asarray(squares(rows[start:stop]))
        assert part.tobytes() == whole[start:stop].tobytes(), (start, stop)


DEVICE_COUNT_CHECKS = textwrap.dedent(
    """
    import hashlib
    import equinox as eqx, jax, numpy as np
    from jaxflex import make_records
    from jaxflex.evolve import DE, run
    from jaxflex.objective import build_objective

    objective = build_objective(make_records(noise=False, duration=0.3))
    fitness = eqx.filter_jit(lambda o, x: o.fitness(x))
    digest = hashlib.sha256()
    population = np.random.default_rng(100).uniform(size=(100, len(objective.names)))
    digest.update(np.asarray(fitness(objective, population)).tobytes())  # padded on three
    result = run(DE.paper(population=40), objective.fitness, len(objective.names), seed=3,
                 generations=4)  # 40 candidates: padded on three devices, not on one or two
    for array in (result.final_population, result.final_fitness, result.best_x,
                  result.history_best):
        digest.update(np.asarray(array).tobytes())
    print(len(jax.devices()), digest.hexdigest())
    """
)


def test_fitness_and_de_are_bit_identical_on_one_two_and_three_devices():
    """Per-candidate costs do not depend on how the population is split (or whether it is):
    the fitness of 100 candidates and a whole DE run of 40 (its final population, their costs
    and the history) hash to the same bytes."""
    digests = []
    for devices in ("1", "2", "3"):
        env = {**os.environ, "JAXFLEX_HOST_DEVICES": devices, "JAX_PLATFORMS": "cpu"}
        result = subprocess.run(
            [sys.executable, "-c", DEVICE_COUNT_CHECKS],
            env=env, capture_output=True, text=True, timeout=300,
        )
        assert result.returncode == 0, result.stderr[-3000:]
        count, digest = result.stdout.split()[-2:]
        assert count == devices  # the process really has that many devices to split over
        digests.append(digest)
    assert digests[0] == digests[1] == digests[2], digests
