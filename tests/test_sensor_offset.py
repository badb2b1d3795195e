"""Effect sensor_offset: a constant added to one channel's reading, and only to it."""

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
