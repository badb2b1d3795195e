"""The fused GPU kernel (:mod:`jaxflex.fused`): the simulator's outputs to round-off, on a rig
other than the reference strip, through Pallas' interpreter on the CPU; and a program Triton can
compile (lowered for CUDA here, no GPU needed)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxflex import fused
from jaxflex.data import Dataset, Record
from jaxflex.effects import library
from jaxflex.effects.gravity import Gravity
from jaxflex.effects.payload import Payload
from jaxflex.effects.stribeck import Stribeck
from jaxflex.fused import simulate_fused, supports
from jaxflex.model import Model
from jaxflex.objective import build_objective
from jaxflex.signals import reference_input
from jaxflex.simulation import OUTPUT_NAMES, simulate_batch, simulate_core
from jaxflex.testbed import Testbed as Bench  # (a name pytest would try to collect)

RIG = Model(
    testbed=Bench(length=0.35, thickness=0.0015, width=0.02, n_elements=3, clamp_offset=0.02,
                    dt=0.002),
    effects=(Gravity(), Stribeck(), Payload()),
    stations=(0.1, 0.22, 0.3),  # three: padded to four in the kernel
)


@pytest.fixture(scope="module")
def population():
    _, torque = reference_input("pulse", duration=0.4, dt=RIG.testbed.dt)
    unit = np.random.default_rng(3).uniform(size=(5, len(RIG.space)))
    params = {k: jnp.asarray(v) for k, v in RIG.space.from_unit(unit).items()}
    return params, jnp.asarray(torque)


def test_the_kernel_gives_the_simulators_outputs_on_another_rig(population, monkeypatch):
    """simulate_batch as a GPU runs it, forced here (the kernel through Pallas' interpreter),
    against the XLA program."""
    params, torque = population
    scan = jax.jit(jax.vmap(lambda q: simulate_core(RIG, q, torque, RIG.testbed.dt)))(params)
    monkeypatch.setattr(fused, "preferred", lambda model: True)
    # five candidates in one block of 32 lanes: the population is padded, and the padding dropped
    kernel = simulate_batch(RIG, params, torque)
    names = OUTPUT_NAMES + ("station_deflection", "station_curvature", "station_acceleration")
    for name in names:
        got, want = np.asarray(getattr(kernel, name)), np.asarray(getattr(scan, name))
        assert got.shape == want.shape, name
        # six padded modes → eight lanes of modes; products summed in another order than XLA's
        np.testing.assert_allclose(got, want, rtol=0, atol=1e-11 * np.max(np.abs(want)),
                                   err_msg=name)
    # the stick-slip record does reach the friction solve's loop: the joint stops and restarts
    assert np.any(np.abs(np.asarray(scan.joint_velocity)) < 1e-6)


def _measured(name: str, duration: float):
    """A record of the rig as a logger would hand it over: any motion will do for the costs."""
    time, torque = reference_input(name, duration=duration, dt=RIG.testbed.dt)
    noise = np.random.default_rng(len(name)).standard_normal((2, time.size))
    return Record(time=time, torque=torque, joint_angle=0.2 * np.sin(9.0 * time) + 1e-3 * noise[0],
                  tip_acceleration=noise[1], name=name)


def test_where_the_kernel_is_preferred_a_generation_costs_what_it_costs_in_the_scan(monkeypatch):
    """Identification's fitness as a GPU runs it, forced here (through the interpreter), over
    records of two lengths: a group of two records and a group of one, a kernel each."""
    records = [_measured("pulse", 0.16), _measured("half_sine", 0.16), _measured("triangular", 0.1)]
    objective = build_objective(Dataset(records), RIG)
    assert [t.shape[0] for t in objective.torque] == [2, 1]
    population = jnp.asarray(np.random.default_rng(4).uniform(size=(3, objective.dim)))
    scan_costs = jax.jit(lambda u: objective.fitness(u))(population)
    monkeypatch.setattr(fused, "preferred", lambda model: True)
    kernel_costs = jax.jit(lambda u: objective.fitness(u))(population)
    assert np.all(np.asarray(scan_costs) > 0)
    np.testing.assert_allclose(kernel_costs, scan_costs, rtol=1e-10)


def test_models_the_kernel_cannot_run_are_named():
    assert supports(RIG)
    assert not supports(Model(n_modes=2))
    with pytest.raises(ValueError, match="advances only some modes.*simulate_batch runs it"):
        simulate_fused(Model(n_modes=2), {}, jnp.zeros(4), 1e-3)
    with pytest.raises(ValueError, match="block must be a power of two, got 24"):
        simulate_fused(RIG, {}, jnp.zeros(4), 1e-3, block=24)


def _eqns(jaxpr):
    """Every equation of a jaxpr and of the jaxprs inside its equations (loops, branches,
    custom rules, kernels)."""
    for eqn in jaxpr.eqns:
        yield eqn
        for value in eqn.params.values():
            for inner in value if isinstance(value, tuple) else (value,):
                inner = getattr(inner, "jaxpr", inner)
                if hasattr(inner, "eqns"):
                    yield from _eqns(inner)


@pytest.mark.parametrize("model", [RIG, Model(), Model().with_effects(*library())],
                         ids=["rig", "reference", "every effect"])
def test_the_kernel_is_one_triton_can_compile(model, population):
    """What Triton refused on the GPU: a loop condition per lane, and empty arrays (the
    reference model has no loads); and every effect of the library's laws lowers."""
    pytest.importorskip("jax._src.pallas.triton.pallas_call_registration")
    params = {k: jnp.zeros(64) + v for k, v in model.space.reference().items()}
    torque = population[1]

    def program(p, t):
        return simulate_fused(model, p, t, model.testbed.dt, interpret=False)

    closed = jax.make_jaxpr(program)(params, torque)
    [kernel] = [e.params["jaxpr"] for e in _eqns(closed.jaxpr) if e.primitive.name == "pallas_call"]
    for eqn in _eqns(kernel):
        for var in list(eqn.invars) + list(eqn.outvars):
            shape = getattr(var.aval, "shape", ())
            assert 0 not in shape, f"empty array in the kernel: {eqn.primitive} {shape}"
        if eqn.primitive.name == "while":
            assert eqn.params["cond_jaxpr"].out_avals[0].shape == ()
    exported = jax.export.export(
        jax.jit(program),
        platforms=["cuda"],
        disabled_checks=[jax.export.DisabledSafetyCheck.custom_call("__gpu$xla.gpu.triton")],
    )(params, torque)
    assert "__gpu$xla.gpu.triton" in exported.mlir_module()
