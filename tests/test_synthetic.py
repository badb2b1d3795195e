"""Synthetic measured records: the model's response plus the testbed's sensor noise."""

import numpy as np
import pytest

import jaxflex  # noqa: F401  (float64)
from jaxflex.data import Dataset
from jaxflex.model import Model
from jaxflex.signals import reference_input
from jaxflex.simulation import simulate
from jaxflex.synthetic import (
    ACCELEROMETER_SIGMA,
    ENCODER_STEP,
    add_noise,
    make_records,
    true_parameters,
)


@pytest.fixture(scope="module")
def clean():
    return make_records(noise=False, extras=("tip_deflection",))


def test_noise_free_records_are_the_simulation(clean):
    assert isinstance(clean, Dataset)
    assert clean.names == ("triangular", "pulse", "half_sine")
    model = Model()
    for record in clean:
        t, torque = reference_input(record.name)
        out = simulate(model, model.space.reference(), torque)
        np.testing.assert_array_equal(record.time, t)
        np.testing.assert_array_equal(record.torque, torque)
        np.testing.assert_allclose(record.joint_angle, out.joint_angle, rtol=0, atol=1e-14)
        np.testing.assert_allclose(record.tip_acceleration, out.tip_acceleration, atol=1e-12)
        np.testing.assert_allclose(record.extras["tip_deflection"], out.tip_deflection)
        assert record.n_samples == 2001 and record.dt == pytest.approx(1e-3)
        # the spec's test condition: each reference input moves the joint to about 80 degrees
        assert 60 < np.degrees(record.joint_angle[-1]) < 100


def test_noise_follows_the_spec(clean):
    noisy = make_records(noise=True, seed=7)
    for a, b in zip(clean, noisy, strict=True):
        counts = b.joint_angle / ENCODER_STEP
        np.testing.assert_allclose(counts, np.round(counts), atol=1e-9)  # whole counts
        assert np.max(np.abs(b.joint_angle - a.joint_angle)) <= ENCODER_STEP / 2 + 1e-12
        noise = b.tip_acceleration - a.tip_acceleration
        # 2001 Gaussian samples: the sample std is within ~3.2 % of sigma (2 standard errors)
        assert np.std(noise) == pytest.approx(ACCELEROMETER_SIGMA, rel=0.1)
        assert abs(np.mean(noise)) < 4 * ACCELEROMETER_SIGMA / np.sqrt(noise.size)
        np.testing.assert_array_equal(b.torque, a.torque)
        assert b.metadata["noise_seed"]


def test_seeds_reproduce_and_differ():
    a = make_records(inputs=("pulse", "half_sine"), seed=3)
    b = make_records(inputs=("pulse", "half_sine"), seed=3)
    c = make_records(inputs=("pulse", "half_sine"), seed=4)
    for x, y, z in zip(a, b, c, strict=True):
        np.testing.assert_array_equal(x.tip_acceleration, y.tip_acceleration)
        assert not np.array_equal(x.tip_acceleration, z.tip_acceleration)
    # the records of one data set carry independent noise
    truth = make_records(inputs=("pulse", "half_sine"), noise=False)
    na = a[0].tip_acceleration - truth[0].tip_acceleration
    nb = a[1].tip_acceleration - truth[1].tip_acceleration
    assert abs(np.corrcoef(na, nb)[0, 1]) < 0.1


def test_add_noise_reads_a_record_through_the_testbed_sensors_or_given_ones(clean):
    record = clean["pulse"]
    once = add_noise(record, seed=1)
    again = add_noise(record, seed=1)
    np.testing.assert_array_equal(once.tip_acceleration, again.tip_acceleration)
    counts = once.joint_angle / ENCODER_STEP
    np.testing.assert_allclose(counts, np.round(counts), rtol=0, atol=1e-9)
    assert np.std(once.tip_acceleration - record.tip_acceleration) == pytest.approx(
        ACCELEROMETER_SIGMA, rel=0.1)
    accelerometer_only = add_noise(record, seed=1, noise={"tip_acceleration": ACCELEROMETER_SIGMA})
    np.testing.assert_array_equal(accelerometer_only.joint_angle, record.joint_angle)
    np.testing.assert_array_equal(accelerometer_only.tip_acceleration, once.tip_acceleration)
    silent = add_noise(record, seed=1, noise={})
    np.testing.assert_array_equal(silent.tip_acceleration, record.tip_acceleration)
    with pytest.raises(ValueError, match="seed"):
        add_noise(record, seed=-1)
    with pytest.raises(ValueError, match="noise level of tip_acceleration must be positive"):
        add_noise(record, seed=1, noise={"tip_acceleration": -0.1})


def test_parameters_amplitudes_and_errors():
    stiff = make_records(params={"E": 9e10}, inputs="pulse", noise=False, duration=0.5)
    soft = make_records(params={"E": 3e10}, inputs="pulse", noise=False, duration=0.5)
    assert stiff[0].n_samples == 501
    assert not np.allclose(stiff[0].tip_acceleration, soft[0].tip_acceleration)
    assert "E=90000000000.0" in stiff[0].metadata["parameters"]
    assert true_parameters(params={"E": 9e10})["J_h"] == pytest.approx(0.0053)
    small = make_records(inputs="pulse", amplitudes={"pulse": 0.125}, noise=False, duration=0.5)
    assert np.max(small[0].torque) == pytest.approx(0.125)
    with pytest.raises(ValueError, match="unknown parameter"):
        make_records(params={"E_mod": 1.0})
    with pytest.raises(ValueError, match="J_h must be positive"):
        make_records(params={"J_h": -1.0})
    with pytest.raises(ValueError, match="unknown input"):
        make_records(inputs=("square",))
    with pytest.raises(ValueError, match="not in inputs"):
        make_records(inputs=("pulse",), amplitudes={"chirp": 0.1})
    with pytest.raises(ValueError, match="extra outputs"):
        make_records(extras=("joint_angle",))


def test_noise_given_as_levels_is_the_testbed_noise_when_the_levels_are_the_testbed_s():
    """``noise`` is one type everywhere (:data:`jaxflex.noise.Noise`): the spec's encoder step and
    accelerometer σ given as levels write the very records ``noise=True`` writes."""
    from jaxflex.noise import NoiseLevel
    from jaxflex.synthetic import ACCELEROMETER_SIGMA, ENCODER_STEP

    spec = make_records(inputs=["pulse", "half_sine"], seed=5)
    given = make_records(inputs=["pulse", "half_sine"], seed=5, noise={
        "joint_angle": NoiseLevel.quantised(ENCODER_STEP), "tip_acceleration": ACCELEROMETER_SIGMA})
    for a, b in zip(spec, given, strict=True):
        assert np.array_equal(a.joint_angle, b.joint_angle)
        assert np.array_equal(a.tip_acceleration, b.tip_acceleration)
    with pytest.raises(ValueError, match="noise given for unknown channel 'strain'"):
        make_records(inputs=["pulse"], noise={"strain": 1e-6})
