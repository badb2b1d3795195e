"""The effect sensor_offset: a constant added to one channel's reading, and only to it."""

import numpy as np
import pytest

from jaxflex import Model, reference_parameters, simulate
from jaxflex.effects import SensorOffset, get_effect
from jaxflex.effects.sensor_offset import DEFAULT_BOUNDS
from jaxflex.sensors import calibrated
from jaxflex.signals import reference_input
from jaxflex.simulation import OUTPUT_NAMES


@pytest.fixture(scope="module")
def pulse_outputs():
    return simulate(Model(), reference_parameters(), reference_input("pulse", duration=0.5)[1])


def test_every_output_has_a_default_bound_and_the_name_carries_the_channel():
    assert set(DEFAULT_BOUNDS) == set(OUTPUT_NAMES)
    effect = get_effect("sensor_offset:joint_angle")
    (spec,) = effect.parameters
    assert effect.name == "sensor_offset:joint_angle"
    assert (spec.name, spec.unit, spec.lower, spec.upper, spec.null, spec.log_scale) == (
        "offset_joint_angle", "rad", -0.05, 0.05, 0.0, False)
    assert SensorOffset(channel="root_strain", bound=1e-3).parameters[0].upper == 1e-3
    with pytest.raises(ValueError, match="bound=-1.0 must be a number >= 0"):
        SensorOffset(bound=-1.0)


@pytest.mark.parametrize("channel", OUTPUT_NAMES)
def test_it_adds_exactly_to_its_channel_and_leaves_every_other_bit_identical(
    channel, pulse_outputs
):
    model = Model().with_effects(SensorOffset(channel=channel))
    base, offset = {**reference_parameters()}, 0.75 * DEFAULT_BOUNDS[channel]
    at_null = calibrated(model, base | {f"offset_{channel}": 0.0}, pulse_outputs)
    shifted = calibrated(model, base | {f"offset_{channel}": offset}, pulse_outputs)
    for name in OUTPUT_NAMES:
        y = np.asarray(pulse_outputs.channel(name))
        np.testing.assert_array_equal(at_null.channel(name), y, err_msg=name)
        expected = y + offset if name == channel else y
        np.testing.assert_array_equal(shifted.channel(name), expected, err_msg=name)


TRUTH = {**reference_parameters()}
BIASED = TRUTH | {"offset_joint_angle": 0.01}
ENCODER_OFF = Model().with_effects(SensorOffset(channel="joint_angle"))


def test_synthetic_records_carry_the_offset_in_that_column_alone():
    """Records of a model whose encoder reads 0.01 rad too much: make_records writes exactly the
    offset into the joint-angle column and leaves the acceleration as it was."""
    from jaxflex.synthetic import make_records

    exact = make_records(ENCODER_OFF, BIASED, noise=False, duration=0.5)
    for r, c in zip(exact, make_records(Model(), TRUTH, noise=False, duration=0.5), strict=True):
        np.testing.assert_array_equal(r.joint_angle, c.joint_angle + 0.01)
        np.testing.assert_array_equal(r.tip_acceleration, c.tip_acceleration)


@pytest.mark.slow  # the discovery engine compiles its Jacobian
def test_discover_scores_the_encoder_offset_first():
    """The score test of sensor_offset:joint_angle at the true motion parameters is the
    largest, ahead of a torque offset and gravity, with the right sign."""
    from jaxflex.diagnosis import NoiseLevel
    from jaxflex.discovery import score_tests
    from jaxflex.synthetic import ACCELEROMETER_SIGMA, ENCODER_STEP, make_records

    records = make_records(ENCODER_OFF, BIASED, seed=3, duration=0.5)  # quantised, noisy
    noise = {"joint_angle": NoiseLevel.quantised(ENCODER_STEP),
             "tip_acceleration": NoiseLevel(ACCELEROMETER_SIGMA)}
    ranking = score_tests(records, Model(), TRUTH, noise=noise,
                          candidates=["sensor_offset:joint_angle", "torque_offset", "gravity"])
    assert ranking[0].effect == "sensor_offset:joint_angle", [(r.effect, r.statistic)
                                                              for r in ranking]
    assert ranking[0].significant and ranking[0].estimate["offset_joint_angle"] > 0
