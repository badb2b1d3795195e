"""Command drives: a raw command (counts) through a saturating amplifier of a torque per unit
that the fit can identify (the drive_gain effect)."""

import math

import numpy as np
import pytest

from jaxflex import Model, identify, reference_parameters, simulate
from jaxflex.arm import ArmError, arm_from_dict
from jaxflex.data import Record, load_record, save_record
from jaxflex.discovery import candidate_set
from jaxflex.drives import CommandDrive, TorqueDrive, get_drive
from jaxflex.effects import DriveGain, get_effect
from jaxflex.measured import logged_record, model_record
from jaxflex.signals import reference_input
from jaxflex.simulation import OUTPUT_NAMES

K = 0.0025  # N m per count
TRUE = {"E": 70e9, "J_h": 0.004, "b_v": 0.002, "tau_c": 0.02, "alpha": 1.0, "beta": 5e-5}
FREE = {"J_h": (0.001, 0.02), "b_v": (1e-4, 0.02)}  # the others fixed at their true values


def _rig(torque_per_unit, /, **drive) -> dict:
    """A 0.4 m × 30 mm × 3 mm aluminium strip driven by a PWM command in counts that saturates
    at ±100, with an encoder and a tip accelerometer (quantised, slightly noisy)."""
    params = {n: {"reference": v, "lower": FREE[n][0], "upper": FREE[n][1]} if n in FREE
              else {"reference": v, "fixed": True} for n, v in TRUE.items()}
    return {
        "name": "bench",
        "link": {"length": 0.4, "width": 0.03, "thickness": 0.003, "density": 2700.0},
        "simulation": {"n_elements": 4},
        "parameters": params,
        "drive": {"type": "command", "unit": "counts", "torque_per_unit": torque_per_unit,
                  "saturation": 100.0} | drive,
        "sensors": [{"type": "encoder", "counts_per_revolution": 4096},
                    {"type": "accelerometer", "x": 0.4, "channel": "acc", "noise": 0.01,
                     "resolution": 0.05}],
    }


def _command() -> tuple[np.ndarray, np.ndarray]:
    """0.7 s at 1 kHz: 0.1 s at rest, one 3 Hz sine period of 150 counts (clipped at 100),
    whole counts as a PWM register holds them."""
    t = 1e-3 * np.arange(700)
    u = np.where((t >= 0.1) & (t < 0.1 + 1 / 3), 150.0 * np.sin(2 * np.pi * 3.0 * (t - 0.1)), 0)
    return t, np.round(u)


def test_a_saturating_command_drive_is_a_torque_drive_fed_the_clipped_command_exactly():
    drive = CommandDrive(torque_per_unit=K, saturation=60.0, unit="counts")
    counts = reference_input("pulse")[1] / 0.25 * 100.0  # ±100-count pulses
    params = reference_parameters()
    by_command = simulate(Model(drive=drive), params, counts)
    by_torque = simulate(Model(drive=TorqueDrive()), params, np.clip(counts, -60.0, 60.0) * K)
    for name in OUTPUT_NAMES:
        np.testing.assert_array_equal(by_command.channel(name), by_torque.channel(name))
    # and the clip does act: the unclipped command turns the arm further
    free = simulate(Model(drive=CommandDrive(torque_per_unit=K, unit="counts")), params, counts)
    assert np.max(np.abs(free.joint_angle)) > 1.3 * np.max(np.abs(by_command.joint_angle))


def test_the_drive_gain_rescales_the_drive_torque_and_vanishes_at_its_reference():
    counts = reference_input("pulse")[1] / 0.25 * 100.0
    params = reference_parameters()
    drive = CommandDrive(torque_per_unit=0.002, saturation=80.0, unit="counts")
    gain = DriveGain(reference=0.002, lower=0.001, upper=0.004, unit="counts")
    (spec,) = gain.parameters
    assert (spec.name, spec.unit, spec.null, spec.log_scale) == (
        "torque_per_unit", "N m/counts", 0.002, True)
    model = Model(drive=drive).with_effects(gain)
    base = simulate(Model(drive=drive), params, counts)
    at_null = simulate(model, params | {"torque_per_unit": 0.002}, counts)
    np.testing.assert_array_equal(at_null.joint_angle, base.joint_angle)
    scaled = simulate(model, params | {"torque_per_unit": K}, counts)
    truth = simulate(Model(drive=CommandDrive(torque_per_unit=K, saturation=80.0)), params,
                     counts)
    scale = np.abs(truth.joint_angle).max()
    np.testing.assert_allclose(scaled.joint_angle, truth.joint_angle, rtol=0, atol=1e-12 * scale)
    assert np.abs(base.joint_angle - truth.joint_angle).max() > 0.1 * scale


def test_the_torque_per_count_is_identified_with_the_hub_inertia_and_friction():
    """A rig's log at 0.0025 N m per count, read with an arm file that says 'between 0.001 and
    0.004, reference 0.002': DE 20 × 12 + LM gives the gain back within its interval and 1 %,
    with J_h and b_v free."""
    t, counts = _command()
    assert np.abs(counts).max() == 150.0  # the amplifier clips a third of the sine's peak
    log = logged_record(arm_from_dict(_rig(K)), TRUE, t, counts, seed=0)
    assert log.input_name == "command" and log.units["command"] == "1"
    arm = arm_from_dict(_rig({"reference": 0.002, "lower": 0.001, "upper": 0.004}))
    assert arm.effect_names == ("drive_gain",) and arm.space["torque_per_unit"].null == 0.002
    fit = identify(model_record(arm, log), arm, generations=12, population=20, seed=0)
    assert fit.names == ("J_h", "b_v", "torque_per_unit")
    lower, upper = fit.intervals["torque_per_unit"]
    assert lower <= K <= upper and upper - lower < 0.02 * K, fit.summary()
    assert fit.params["torque_per_unit"] == pytest.approx(K, rel=0.01)
    for name in ("J_h", "b_v"):
        assert fit.params[name] == pytest.approx(TRUE[name], rel=0.03), (name, fit.summary())


def test_an_arm_file_command_drive():
    arm = arm_from_dict(_rig({"reference": 0.002, "lower": 0.001, "upper": 0.004}))
    assert arm.drive == CommandDrive(torque_per_unit=0.002, saturation=100.0, unit="counts")
    assert arm.effects == (DriveGain(reference=0.002, lower=0.001, upper=0.004, unit="counts"),)
    assert arm.drive.unit == "counts" and arm.drive.gain == 0.002 and arm.drive.damping == 0.0
    assert arm.drive.settings() == {"unit": "counts", "torque_per_unit": 0.002,
                                    "saturation": 100.0}
    assert arm_from_dict(_rig(K)).effect_names == ()  # a number: fixed
    plain = _rig(K)
    del plain["drive"]["saturation"]
    assert arm_from_dict(plain).drive == get_drive("command", torque_per_unit=K, unit="counts")


@pytest.mark.parametrize(
    ("drive", "message"),
    [
        ({"saturation": 0.0}, "drive.saturation: expected a positive number, got 0.0 (float)"),
        ({"saturation": -5.0}, "drive.saturation: expected a positive number, got -5.0"),
        ({"saturation": math.nan}, "drive.saturation: expected a positive number, got nan"),
        ({"saturation": "max"}, "drive.saturation: expected a number, got 'max' (a string)"),
        ({"saturaton": 50.0}, "drive.saturaton: unknown key; did you mean 'saturation'?"),
        ({"gain": 2.0}, "drive.gain: unknown key; known keys: ['saturation', 'torque_per_unit', "
                        "'type', 'unit']"),
        ({"torque_per_unit": {"reference": 0.002, "lower": 0.004, "upper": 0.001}},
         "drive.torque_per_unit.lower: lower bound 0.004 must be below the upper bound 0.001"),
        ({"torque_per_unit": {"reference": 0.005, "lower": 0.001, "upper": 0.004}},
         "drive.torque_per_unit: bounds [0.001, 0.004] exclude the reference value 0.005"),
        ({"torque_per_unit": {"reference": 0.002, "lower": -0.001, "upper": 0.004}},
         "drive.torque_per_unit.lower: expected a positive number, got -0.001"),
        ({"torque_per_unit": {"reference": 0.002, "upper": 0.004}},
         "drive.torque_per_unit.lower: missing value"),
        ({"torque_per_unit": {"reference": 0.002, "lower": 0.001, "upper": 0.004,
                              "fixed": True}}, "drive.torque_per_unit.fixed: unknown key"),
        ({"torque_per_unit": 0.0}, "drive.torque_per_unit: expected a positive number, got 0.0"),
        ({"unit": 7}, "drive.unit: expected a string, got 7 (int)"),
        ({"unit": " "}, "drive: command drive: unit=' ' must name the command's unit, e.g. "
                        "'counts'"),
    ],
)
def test_command_drive_errors_are_one_line_naming_the_file_and_key(drive, message):
    with pytest.raises(ArmError) as info:
        arm_from_dict(_rig(K, **drive), "bench.toml")
    assert str(info.value).startswith(f"bench.toml: {message}"), str(info.value)
    assert "\n" not in str(info.value)


def test_a_missing_unit_is_named():
    data = _rig(K)
    del data["drive"]["unit"]
    with pytest.raises(ArmError, match=r"^bench.toml: drive.unit: missing value$"):
        arm_from_dict(data, "bench.toml")


def test_drive_and_effect_errors_name_the_setting():
    with pytest.raises(ValueError, match=r"^command drive: torque_per_unit=-1.0 must be a pos"):
        CommandDrive(torque_per_unit=-1.0)
    with pytest.raises(ValueError, match=r"^command drive: saturation=inf must be a positive"):
        CommandDrive(saturation=math.inf)
    with pytest.raises(ValueError, match=r"^drive_gain: bounds \[0.001, 0.004\] must be "
                                         r"increasing and hold the reference torque per unit 0.01"):
        DriveGain(reference=0.01, lower=0.001, upper=0.004)
    with pytest.raises(ValueError, match=r"^drive_gain: lower=0.0 must be a positive number"):
        get_effect("drive_gain", lower=0.0)


def test_a_log_in_counts_loads_and_drives_only_a_command_drive(tmp_path):
    """Counts in the thousands are no unit error (no unit check reads a command column); a
    command log read through a torque-driven arm is refused naming both columns."""
    t, counts = _command()
    log = logged_record(arm_from_dict(_rig(K)), TRUE, t, 20.0 * counts, seed=1)
    path = save_record(log, tmp_path / "log.csv")
    back = load_record(path)
    np.testing.assert_array_equal(back.channel("command"), 20.0 * counts)
    assert back.input_name == "command" and np.abs(back.channel("command")).max() == 3000.0
    torque_arm = arm_from_dict(_rig(K) | {"drive": {"type": "torque"}})
    with pytest.raises(ValueError, match="logs 'command' but rig 'bench' has a torque drive"):
        model_record(torque_arm, back)
    with pytest.raises(ValueError, match=r"exactly one input column of \['torque', 'current', "
                                         r"'voltage', 'command'\]; found \['torque', 'command'\]"):
        Record(time=t, torque=counts, extras={"command": counts, "acc": counts})


def test_discover_does_not_propose_a_drive_gain_unless_named():
    assert "drive_gain" not in {c.name for c in candidate_set()}
    (named,) = candidate_set(["drive_gain"])
    assert named.effects == (DriveGain(),) and named.parameters[0].null == 1.0
