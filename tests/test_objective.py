"""The identification objective: normalised residuals, scalar cost and population fitness."""

import equinox as eqx
import jax.numpy as jnp
import numpy as np
import pytest

import jaxflex  # noqa: F401  (float64)
from jaxflex.data import Record, RecordError
from jaxflex.metrics import nrmse
from jaxflex.model import Model
from jaxflex.objective import build_objective
from jaxflex.simulation import simulate
from jaxflex.synthetic import make_records

DURATION = 0.6  # short records keep these tests fast; the arm is still moving at 0.6 s
TRUTH = {k: float(v) for k, v in Model().space.reference().items()}
OTHER = {**TRUTH, "E": 6.5e10, "J_h": 0.006, "tau_c": 0.09}


@pytest.fixture(scope="module")
def records():
    return make_records(noise=True, seed=2, duration=DURATION)


@pytest.fixture(scope="module")
def clean():
    return make_records(noise=False, duration=DURATION)


cost_jit = eqx.filter_jit(lambda objective, params: objective.cost(params))
residuals_jit = eqx.filter_jit(lambda objective, params: objective.residuals(params))
fitness_jit = eqx.filter_jit(lambda objective, population: objective.fitness(population))


def nrmse_cost(records, params, weights):
    """The cost recomputed independently: weighted mean over records of squared NRMSE."""
    total = sum(weights.values())
    values = []
    for record in records:
        out = simulate(Model(), params, record.torque)
        values.append(
            sum(
                w / total * (nrmse(record.channel(c), out.channel(c)) / 100) ** 2
                for c, w in weights.items()
            )
        )
    return float(np.mean(values))


def test_zero_at_the_truth_of_noise_free_records(clean):
    objective = build_objective(clean)
    r = residuals_jit(objective, TRUTH)
    assert r.shape == (3 * 2 * clean[0].n_samples,) == (objective.size,)
    # round-off only: stick phases amplify it to ~1e-10 of the channel scale on some CPUs,
    # still six orders below the sensor noise and the effect of a wrong parameter
    assert float(jnp.max(jnp.abs(r))) < 1e-8
    assert float(cost_jit(objective, OTHER)) > 1e-4


def test_cost_is_weighted_mean_squared_nrmse(records):
    weights = {"joint_angle": 1.0, "tip_acceleration": 3.0}
    objective = build_objective(records, weights=weights)
    cost = float(cost_jit(objective, OTHER))
    assert cost == pytest.approx(nrmse_cost(records, OTHER, weights), rel=1e-9)
    r = residuals_jit(objective, OTHER)
    assert cost == pytest.approx(float(jnp.sum(r**2)), rel=1e-12)  # one code path
    # a channel of weight 0 is left out of the objective altogether
    angle_only = build_objective(records, weights={"tip_acceleration": 0.0})
    assert angle_only.channels == ("joint_angle",)
    assert angle_only.size == objective.size // 2


def test_noise_levels_weigh_the_residual_in_units_of_the_noise(records):
    """One record: with weights from the noise, ``e = (ŷ − y)/σ_c`` up to one common factor."""
    sigma = {"joint_angle": 2e-3, "tip_acceleration": 0.05}
    objective = build_objective(records[0], noise=sigma)
    # e = s_c (ŷ − y) with s_c ∝ 1/σ_c
    scale = dict(zip(objective.channels, np.asarray(objective.scale[0])[0], strict=True))
    assert scale["joint_angle"] / scale["tip_acceleration"] == pytest.approx(
        sigma["tip_acceleration"] / sigma["joint_angle"], rel=1e-12)
    with pytest.raises(ValueError, match="^give channel weights or noise levels, not both$"):
        build_objective(records, noise=sigma, weights={"joint_angle": 1.0})
    with pytest.raises(ValueError, match=r"^noise level missing for channel\(s\) "
                                         r"\['tip_acceleration'\]"):
        build_objective(records, noise={"joint_angle": 2e-3})


def test_population_fitness_is_the_cost_per_candidate_and_never_nan(records):
    objective = build_objective(records)
    space = objective.space
    population = np.stack(
        [
            np.asarray(space.to_unit(TRUTH)),
            np.asarray(space.to_unit(OTHER)),
            np.full(6, np.nan),  # a candidate whose simulation is not finite
            np.full(6, 0.5),
        ]
    )
    fitness = np.asarray(fitness_jit(objective, jnp.asarray(population)))
    assert fitness[0] == pytest.approx(float(cost_jit(objective, TRUTH)), rel=1e-8)
    assert fitness[1] == pytest.approx(float(cost_jit(objective, OTHER)), rel=1e-8)
    assert fitness[2] == np.inf
    assert np.all(np.isfinite(fitness[[0, 1, 3]]))
    assert fitness[0] < fitness[1]
    # the noisy records' cost at the truth is the sensor-noise floor (a fraction, ~1e-4)
    assert 1e-6 < fitness[0] < 1e-3


def test_unit_coordinates_round_trip(records):
    objective = build_objective(records)
    from_u = objective.from_unit(objective.space.to_unit(OTHER))
    for name, value in OTHER.items():
        assert float(from_u[name]) == pytest.approx(value, rel=1e-12)


def test_records_of_different_length_each_count_once(clean):
    pulse = clean["pulse"]
    short = clean["half_sine"].trim(0.0, 0.4)
    both = build_objective([pulse, short])
    assert both.groups == ((0,), (1,))
    weights = {"joint_angle": 1.0, "tip_acceleration": 1.0}
    single = [nrmse_cost([r], OTHER, weights) for r in (pulse, short)]
    assert float(cost_jit(both, OTHER)) == pytest.approx(np.mean(single), rel=1e-9)


def test_a_record_alone_is_simulated_as_in_a_batch_beside_another(clean):
    """A group of one record runs unbatched (``per_record``), a group of several as one vmap:
    the record's channels agree to round-off (stick phases amplify it, as above)."""
    alone = build_objective([clean["pulse"]])
    beside = build_objective([clean["pulse"], clean["triangular"]])
    assert alone.groups == ((0,),) and beside.groups == ((0, 1),)
    simulated = eqx.filter_jit(lambda objective, params: objective.simulate(params))
    [one], [two] = simulated(alone, OTHER), simulated(beside, OTHER)
    assert one.shape == (1, *two.shape[1:])
    scale = np.max(np.abs(np.asarray(two[0])), axis=-1, keepdims=True)
    assert np.all(np.abs(np.asarray(one[0]) - np.asarray(two[0])) <= 1e-9 * scale)
    assert np.max(np.abs(np.asarray(one[0]) - np.asarray(two[1]))) > 1e-3 * np.max(scale)


def test_fixed_parameters_and_bounds(clean):
    objective = build_objective(
        clean, fixed={"beta": TRUTH["beta"]}, bounds={"J_h": (1e-3, 1e-2)}
    )
    assert objective.names == ("E", "J_h", "b_v", "tau_c", "alpha")
    assert objective.space["J_h"].upper == 1e-2
    free = {k: v for k, v in TRUTH.items() if k != "beta"}
    assert float(cost_jit(objective, free)) < 1e-16  # round-off (see above)
    wrong_beta = build_objective(clean, fixed={"beta": 2 * TRUTH["beta"]})
    assert float(cost_jit(wrong_beta, free)) > 1e-8


def test_bad_input_is_named(clean):
    with pytest.raises(ValueError, match="bounds for E: lower bound 5.0 must be below upper"):
        build_objective(clean, bounds={"E": (5.0, 5.0)})
    with pytest.raises(ValueError, match="unknown parameter"):
        build_objective(clean, bounds={"E_mod": (1.0, 2.0)})
    with pytest.raises(ValueError, match="every parameter is fixed"):
        build_objective(clean, fixed=TRUTH)
    with pytest.raises(ValueError, match="fixed value of beta"):
        build_objective(clean, fixed={"beta": np.nan})
    with pytest.raises(ValueError, match=r"\[.joint_velocity.\] not fitted"):
        build_objective(clean, weights={"joint_velocity": 1.0})
    with pytest.raises(ValueError, match="weight of channel 'joint_angle'"):
        build_objective(clean, weights={"joint_angle": -1.0})
    with pytest.raises(ValueError, match="at least one channel weight"):
        build_objective(clean, weights={"joint_angle": 0.0, "tip_acceleration": 0.0})
    with pytest.raises(ValueError, match="not a simulated output"):
        build_objective(clean, channels=("joint_angel",))
    with pytest.raises(ValueError, match="at least one record"):
        build_objective([])
    pulse = clean["pulse"]
    with pytest.raises(RecordError, match="different sampling intervals"):
        build_objective([pulse, pulse.replace(time=2 * pulse.time, name="slow")])
    still = Record(pulse.time, pulse.torque, np.zeros(pulse.n_samples),
                   pulse.tip_acceleration, name="still")
    with pytest.raises(ValueError, match="record 'still': channel 'joint_angle' is identically"):
        build_objective([still])
