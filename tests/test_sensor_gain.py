"""Effect strain_gauge_gain: a mis-calibrated root strain gauge, and only its reading, scaled."""

import equinox as eqx
import numpy as np
import pytest
from test_arm import ARMS

from jaxflex.arm import load_arm
from jaxflex.effects import StrainGaugeGain, get_effect
from jaxflex.measured import logged_record, model_record
from jaxflex.simulation import OUTPUT_NAMES, simulate

ROTFLEX = load_arm(ARMS / "quanser_rotflex.toml")
PARAMS = {**ROTFLEX.reference_parameters()}
DT = ROTFLEX.testbed.dt


@pytest.fixture(scope="module")
def volts():
    t = np.arange(0.0, 1.2, DT)
    return t, np.where(t < 0.1, 0.0, 2.0 * np.sin(2 * np.pi * 1.5 * (t - 0.1)))


@pytest.fixture(scope="module")
def base(volts):
    return simulate(ROTFLEX.model(), PARAMS, volts[1], DT)


def _with_gain(volts, ratio):
    """The arm with a gauge reading ``ratio`` times what its arm file says."""
    error = ratio - 1.0
    return simulate(ROTFLEX.model(StrainGaugeGain()), PARAMS | {"e_sg": error}, volts[1], DT)


def test_at_its_null_the_model_is_the_base_model(volts, base):
    assert get_effect("strain_gauge_gain").parameters[0].null == 0.0
    out = _with_gain(volts, 1.0)
    for name in OUTPUT_NAMES:
        np.testing.assert_array_equal(out.channel(name), base.channel(name), err_msg=name)


def test_it_scales_the_root_strain_and_leaves_the_motion(volts, base):
    out = _with_gain(volts, 1.25)
    strain = np.asarray(base.root_strain)
    assert np.ptp(strain) > 0
    np.testing.assert_allclose(out.root_strain, 1.25 * strain, rtol=0,
                               atol=1e-12 * np.abs(strain).max())
    for name in OUTPUT_NAMES:
        if name != "root_strain":
            np.testing.assert_array_equal(out.channel(name), base.channel(name), err_msg=name)


def test_it_explains_a_gauge_calibrated_wrong_in_the_arm_file(volts):
    """A log from a gauge of gain g, read with an arm file that says g/1.25: the record seen by
    the model is the strain times 1.25, which e_sg = 0.25 reproduces and the null does not."""
    time, signal = volts
    log = logged_record(ROTFLEX, PARAMS, time, signal)
    gauge = ROTFLEX.sensor("deflection_angle")
    told = ROTFLEX.replace(sensors=tuple(
        eqx.tree_at(lambda s: s.gain, s, s.gain / 1.25) if s is gauge else s
        for s in ROTFLEX.sensors
    ))
    seen = model_record(told, log)
    scale = np.abs(seen.channel("root_strain")).max()
    with_gain = _with_gain(volts, 1.25)
    np.testing.assert_allclose(seen.channel("root_strain"), with_gain.root_strain, rtol=0,
                               atol=1e-9 * scale)
    np.testing.assert_array_equal(seen.joint_angle, np.asarray(with_gain.joint_angle))
    error = np.abs(seen.channel("root_strain") - np.asarray(_with_gain(volts, 1.0).root_strain))
    assert error.max() > 0.19 * scale  # the assumed calibration is 20 % of the reading off
