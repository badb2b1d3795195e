"""The effect sensor_gain: one channel's reading, and only it, scaled by a calibration factor."""

import equinox as eqx
import numpy as np
import pytest
from helpers import ARMS

from jaxflex import Model, reference_parameters, simulate
from jaxflex.arm import ArmError, arm_from_dict, load_arm
from jaxflex.effects import SensorGain, get_effect
from jaxflex.measured import logged_record, model_record
from jaxflex.objective import build_objective
from jaxflex.sensors import calibrated, readings
from jaxflex.signals import reference_input
from jaxflex.simulation import OUTPUT_NAMES

ROTFLEX = load_arm(ARMS / "quanser_rotflex.toml")
PARAMS = {**ROTFLEX.space.reference()}
DT = ROTFLEX.testbed.dt


@pytest.fixture(scope="module")
def volts():
    t = np.arange(0.0, 1.2, DT)
    return t, np.where(t < 0.1, 0.0, 2.0 * np.sin(2 * np.pi * 1.5 * (t - 0.1)))


@pytest.fixture(scope="module")
def pulse_outputs():
    return simulate(Model(), reference_parameters(), reference_input("pulse", duration=0.5)[1])


def test_names_carry_the_channel_and_bad_channels_are_named():
    gain = get_effect("sensor_gain:tip_acceleration")
    assert gain == SensorGain(channel="tip_acceleration")
    assert gain.name == "sensor_gain:tip_acceleration" and SensorGain.name == "sensor_gain"
    (spec,) = gain.parameters
    assert (spec.name, spec.null, spec.lower, spec.upper) == (
        "gain_tip_acceleration", 1.0, 0.5, 2.0)
    stray = get_effect("sensor_gain:deflection_angle")  # a rig's sensor may log it
    with pytest.raises(ValueError, match="effect sensor_gain:deflection_angle acts on "
                                         "'deflection_angle', neither a simulator output nor a "
                                         "sensor's channel"):
        Model(effects=(stray,))
    with pytest.raises(ValueError, match="effect 'payload' acts on no channel"):
        get_effect("payload:joint_angle")
    with pytest.raises(ValueError, match="reference gain 3.0 must be non-zero and lie in"):
        SensorGain(reference=3.0)


@pytest.mark.parametrize("channel", OUTPUT_NAMES)
def test_it_scales_exactly_its_channel_and_leaves_every_other_bit_identical(
    channel, pulse_outputs
):
    model = Model().with_effects(SensorGain(channel=channel))
    base = {**reference_parameters()}
    at_null = calibrated(model, base | {f"gain_{channel}": 1.0}, pulse_outputs)
    scaled = calibrated(model, base | {f"gain_{channel}": 1.25}, pulse_outputs)
    for name in OUTPUT_NAMES:
        y = np.asarray(pulse_outputs.channel(name))
        np.testing.assert_array_equal(at_null.channel(name), y, err_msg=name)
        expected = 1.25 * y if name == channel else y  # one rounding: the product itself
        np.testing.assert_array_equal(scaled.channel(name), expected, err_msg=name)
    assert np.ptp(np.asarray(pulse_outputs.channel(channel))) > 0


def test_a_gauge_calibrated_wrong_in_the_arm_file_is_explained_by_its_gain(volts):
    """A log from a gauge of gain g, read with an arm file that says g/1.25: the record seen by
    model reads 1.25 times less than the log, which gain_deflection_angle = 1.25 reproduces."""
    time, signal = volts
    log = logged_record(ROTFLEX, PARAMS, time, signal)
    gauge = ROTFLEX.sensor("deflection_angle")
    told = ROTFLEX.replace(sensors=tuple(
        eqx.tree_at(lambda s: s.gain, s, s.gain / 1.25) if s is gauge else s
        for s in ROTFLEX.sensors
    ))
    seen = model_record(told, log)
    model = told.with_effects(get_effect("sensor_gain:deflection_angle"))
    at = PARAMS | {"gain_deflection_angle": 1.25}
    out = simulate(model, at, seen.input, DT)
    with_gain = calibrated(model, at, out)
    scale = np.abs(seen.channel("deflection_angle")).max()
    np.testing.assert_allclose(seen.channel("deflection_angle"),
                               with_gain.channel("deflection_angle"), rtol=0, atol=1e-9 * scale)
    np.testing.assert_array_equal(seen.joint_angle, np.asarray(with_gain.channel("joint_angle")))
    error = np.abs(seen.channel("deflection_angle") - np.asarray(out.channel("deflection_angle")))
    assert error.max() > 0.19 * scale  # the assumed calibration is 20 % of the reading off


def _rig(gain) -> dict:
    """A small steel strip with an encoder and a tip accelerometer of ``gain``."""
    reference = {n: {"reference": s.reference, "lower": s.lower, "upper": s.upper}
                 for n, s in ((s.name, s) for s in Model().base)}
    return {
        "name": "rig",
        "link": {"length": 0.5, "width": 0.025, "thickness": 0.002, "density": 2700.0},
        "parameters": reference,
        "drive": {"type": "torque"},
        "sensors": [{"type": "encoder"},
                    {"type": "accelerometer", "x": 0.5, "channel": "acc", "gain": gain}],
    }


def test_an_arm_file_gain_table_identifies_the_gain_through_the_fit():
    """A rig logs its accelerometer with gain 1.6 V/(m/s²); the arm file says 'gain between
    0.5 and 2, reference 1': the objective's residuals vanish at gain_acc = 1.6 (to round-off
    of the batched solve) and not at the reference."""
    true = arm_from_dict(_rig(1.6))
    torque = np.concatenate([np.zeros(100), reference_input("pulse", duration=0.5)[1]])
    time = 1e-3 * np.arange(torque.size)  # at rest for 0.1 s first
    log = logged_record(true, reference_parameters(), time, torque)
    arm = arm_from_dict(_rig({"reference": 1.0, "lower": 0.5, "upper": 2.0}))
    assert arm.sensor("acc").gain == 1.0 and arm.effect_names == ("sensor_gain:acc",)
    assert arm.space["gain_acc"].null == 1.0
    objective = build_objective([model_record(arm, log)], arm)
    assert objective.channels == ("joint_angle", "acc")
    right = objective.residuals(reference_parameters() | {"gain_acc": 1.6})
    wrong = objective.residuals(reference_parameters() | {"gain_acc": 1.0})
    assert np.abs(right).max() < 1e-7 * np.abs(wrong).max()  # round-off: vmap, stops
    # readings through the arm at gain 1.6 are the 1.6-gain rig's log (one rounding each)
    at_true = reference_parameters() | {"gain_acc": 1.6}
    at = readings(arm, simulate(arm, at_true, torque), params=at_true)
    np.testing.assert_allclose(at["acc"], log.channel("acc"), rtol=0,
                               atol=1e-14 * np.abs(log.channel("acc")).max())


@pytest.mark.parametrize(
    ("gain", "message"),
    [
        ({"reference": 1.0, "lower": 2.0, "upper": 0.5},
         "sensors[1].gain.lower: lower bound 2.0 must be below the upper bound 0.5"),
        ({"reference": 3.0, "lower": 0.5, "upper": 2.0},
         "sensors[1].gain: bounds [0.5, 2.0] exclude the reference value 3.0"),
        ({"reference": 1.0, "lower": 0.5}, "sensors[1].gain.upper: missing value"),
        ({"reference": 1.0, "lower": 0.5, "upper": 2.0, "fixed": True},
         "sensors[1].gain.fixed: unknown key"),
        ({"reference": 0.0, "lower": -1.0, "upper": 1.0}, "gain must be non-zero"),
    ],
)
def test_gain_table_errors_are_one_line_naming_the_key(gain, message):
    with pytest.raises(ArmError) as info:
        arm_from_dict(_rig(gain), "rig.toml")
    assert str(info.value).startswith("rig.toml: ") and message in str(info.value)
    assert "\n" not in str(info.value)


def test_an_offset_table_is_refused_with_the_reason_on_records_re_zeroed_at_rest():
    data = _rig(1.0)
    data["sensors"][1]["offset"] = {"reference": 0.0, "lower": -1.0, "upper": 1.0}
    with pytest.raises(ArmError, match=r"^rig.toml: sensors\[1\].offset: an offset cannot be "
                                       r"identified from records re-zeroed at rest, which "
                                       r"removes it; give a number, or set rezero = false"):
        arm_from_dict(data, "rig.toml")


def test_a_record_that_keeps_its_zero_identifies_the_sensors_offset():
    """An accelerometer biased by 0.3 m/s², logged without re-zeroing; the arm file says
    'offset 0.1 within ±1, rezero = false': the residuals vanish at offset_acc = 0.2 (the bias
    beyond the stated offset), not at 0."""
    true = arm_from_dict(_rig(1.0) | {"sensors": [
        {"type": "encoder"}, {"type": "accelerometer", "x": 0.5, "channel": "acc",
                              "offset": 0.3}]})
    torque = np.concatenate([np.zeros(100), reference_input("pulse", duration=0.5)[1]])
    time = 1e-3 * np.arange(torque.size)
    log = logged_record(true, reference_parameters(), time, torque)
    data = _rig(1.0)
    data["sensors"][1] |= {"rezero": False, "offset": {"reference": 0.1, "lower": -0.9,
                                                       "upper": 1.1}}
    arm = arm_from_dict(data)
    assert arm.effect_names == ("sensor_offset:acc",) and arm.sensor("acc").offset == 0.1
    ready = model_record(arm, log)
    np.testing.assert_allclose(ready.channel("acc")[:100], 0.2, rtol=0, atol=1e-12)
    objective = build_objective([ready], arm)
    right = objective.residuals(reference_parameters() | {"offset_acc": 0.2})
    wrong = objective.residuals(reference_parameters() | {"offset_acc": 0.0})
    assert np.abs(right).max() < 1e-7 * np.abs(wrong).max()


def test_offset_bounds_on_one_side_of_the_stated_offset_are_kept_as_written():
    """'offset 1 within [0.8, 10]': the offset beyond the stated one is searched in
    [-0.2, 9], not made symmetric ([-8, 10]), and the rig's file gives the same back."""
    import tomllib

    from jaxflex.arm import arm_to_toml

    data = _rig(1.0)
    data["sensors"][1] |= {"rezero": False, "offset": {"reference": 1.0, "lower": 0.8,
                                                       "upper": 10.0}}
    arm = arm_from_dict(data)
    (spec,) = arm.effects[0].parameters
    assert (spec.lower, spec.upper) == pytest.approx((-0.2, 9.0), abs=1e-12)
    assert spec.lower <= spec.reference <= spec.upper
    again = arm_from_dict(tomllib.loads(arm_to_toml(arm)))
    assert again == arm
    symmetric = _rig(1.0)
    symmetric["sensors"][1] |= {"rezero": False, "offset": {"reference": 0.1, "lower": -0.9,
                                                            "upper": 1.1}}
    assert arm_from_dict(symmetric).effects[0].below is None  # as before: ±1
