"""Parameter spaces: coordinate round trips and the one way seeds and warm starts enter the box."""

from __future__ import annotations

import jax
import numpy as np
import pytest

from jaxflex.evolve import DE, run
from jaxflex.identification import _unit_seeds
from jaxflex.model import Model
from jaxflex.objective import build_objective
from jaxflex.parameters import UNIT_SLACK, base_space, into_unit_box
from jaxflex.rigid import RigidEstimate, warm_start
from jaxflex.synthetic import make_records

SPACE = base_space()
ONE_ULP_PAST = float(np.nextafter(0.3, 1.0))  # b_v = 0.30000000000000004: a log round trip


def test_the_box_maps_onto_the_bounds_exactly():
    lower = SPACE.from_unit(np.zeros(len(SPACE)))
    upper = SPACE.from_unit(np.ones(len(SPACE)))
    for spec in SPACE.specs:
        assert float(lower[spec.name]) == spec.lower
        assert float(upper[spec.name]) == spec.upper
    # outside the box the map still extrapolates (it is not clipped)
    assert float(SPACE.from_unit(np.full(len(SPACE), 1.5))["b_v"]) > 0.3


def test_host_side_maps_compile_nothing_and_agree_with_the_traced_ones():
    """Given plain values the maps run in NumPy (a report or a start compiles no program) and
    give what the same maps give inside ``jit`` to round-off; the named values they return are
    copies, not views of the caller's vector."""
    rng = np.random.default_rng(3)
    u = rng.uniform(-0.1, 1.1, size=(5, len(SPACE)))
    host = SPACE.from_unit(u)
    back = SPACE.to_unit(host)
    assert all(type(v) is np.ndarray for v in host.values()) and type(back) is np.ndarray
    traced = jax.jit(SPACE.from_unit)(u)
    for name in SPACE.names:
        np.testing.assert_allclose(host[name], traced[name], rtol=1e-14, atol=0)
    np.testing.assert_allclose(back, jax.jit(SPACE.to_unit)(traced), rtol=0, atol=1e-14)
    np.testing.assert_allclose(back, u, rtol=0, atol=1e-14)
    vector = SPACE.to_vector({n: host[n][0] for n in SPACE.names})
    named = SPACE.from_vector(vector)
    vector[:] = -1.0
    assert all(float(named[n]) == float(host[n][0]) for n in SPACE.names)


def test_a_seed_one_ulp_past_a_log_scaled_bound_enters_the_box_on_it():
    row = {**{s.name: s.reference for s in SPACE.specs}, "b_v": ONE_ULP_PAST}
    u = SPACE.unit_seeds(row, "init_population")
    assert u.shape == (1, len(SPACE))
    assert u[0, SPACE.names.index("b_v")] == 1.0
    assert float(SPACE.from_unit(u[0])["b_v"]) == 0.3
    exact = SPACE.unit_seeds({**row, "b_v": 0.3}, "init_population")
    assert exact[0, SPACE.names.index("b_v")] == 1.0


def test_a_seed_beyond_a_bound_is_named():
    row = {**{s.name: s.reference for s in SPACE.specs}, "b_v": 0.31}
    with pytest.raises(ValueError, match=r"^init_population: b_v=0.31 lies outside its search "
                                         r"bounds \[1e-05, 0.3\] N m s/rad$"):
        SPACE.unit_seeds(row, "init_population")
    # an estimate (no name given) beyond a bound starts on it
    assert SPACE.unit_seeds(row)[0, SPACE.names.index("b_v")] == 1.0


def test_into_unit_box_clips_round_off_and_refuses_the_rest():
    assert into_unit_box([[1.0 + UNIT_SLACK / 2, -UNIT_SLACK / 2]]).tolist() == [[1.0, 0.0]]
    with pytest.raises(ValueError, match=r"^warm start must lie in the unit box"):
        into_unit_box([[1.01, 0.5]], "warm start")
    with pytest.raises(ValueError, match="init_population"):
        into_unit_box([[np.nan, 0.5]])


def test_identify_and_the_search_take_seeds_on_the_bound():
    records = make_records(inputs=("pulse",), noise=False, duration=0.2)
    objective = build_objective(records)
    row = {**{s.name: s.reference for s in SPACE.specs}, "b_v": ONE_ULP_PAST}
    seeds = _unit_seeds(objective, [row])
    assert seeds[0, objective.names.index("b_v")] == 1.0
    result = run(DE.paper(population=4), lambda x: np.sum(x**2, axis=1), 2, seed=0,
                 generations=1, init_population=[[1.0 + 1e-15, 0.5]])
    assert np.all((np.asarray(result.final_population) >= 0)
                  & (np.asarray(result.final_population) <= 1))


def test_a_rigid_warm_start_beyond_a_bound_starts_on_it():
    estimate = RigidEstimate(
        J_tot=0.01, J_h=0.006, b_v=0.5, tau_c=0.1, offset=0.0, residual_rms=0.0, active=(),
        condition_number=1.0, link_inertia=0.004, unconstrained={}, n_samples=100,
        cutoff_hz=20.0, deadband=0.0, guard=0.0,
    )
    units = warm_start(estimate, Model().space, population=16, seed=0)
    b_v = units[:, SPACE.names.index("b_v")]
    assert np.all((b_v >= 0.95) & (b_v <= 1.0))
    values = np.asarray(Model().space.from_unit(units)["b_v"])
    assert np.all(values <= 0.3)
