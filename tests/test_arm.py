"""Arm files describe a rig completely (one Model); errors name the file and key; reference =
today; every rig round-trips exactly through TOML and a fit file."""

import json
import tomllib
from typing import ClassVar

import equinox as eqx
import numpy as np
import pytest
from helpers import ARMS, REFERENCE_ARM, arm_text

from jaxflex import Model, identify, make_records, reference_parameters, simulate
from jaxflex.arm import ArmError, arm_from_dict, arm_to_dict, arm_to_toml, load_arm
from jaxflex.drives import VoltageDrive
from jaxflex.effects import AbstractEffect, SensorGain, register_effect
from jaxflex.parameters import ParameterSpec
from jaxflex.sensors import Accelerometer, DeflectionSensor, Encoder, StrainGauge, Tachometer
from jaxflex.signals import reference_input
from jaxflex.simulation import OUTPUT_NAMES

REFERENCE = REFERENCE_ARM
BED = Model().testbed  # the reference testbed


def test_reference_arm_file_is_exactly_the_reference_testbed():
    arm = load_arm(REFERENCE)
    assert arm == Model()
    assert arm.sensors == () and arm.stations == () and arm.fixed == ()
    ref = reference_parameters()
    assert {k: float(v) for k, v in arm.space.reference().items()} == {
        k: float(v) for k, v in ref.items()
    }
    torque = reference_input("pulse")[1]
    today, from_file = simulate(Model(), ref, torque), simulate(arm, ref, torque)
    for name in OUTPUT_NAMES:
        np.testing.assert_array_equal(getattr(from_file, name), getattr(today, name))


def test_reference_arm_file_reproduces_a_fit_bit_for_bit():
    records = make_records(inputs=("pulse",), noise=False)
    kwargs = dict(generations=2, population=12, refine=False, intervals=False, seed=3)
    today = identify(records, **kwargs)
    from_file = identify(records, load_arm(REFERENCE), **kwargs)
    assert from_file.params == today.params
    np.testing.assert_array_equal(from_file.history.best, today.history.best)


def test_rotflex_arm_file_holds_the_rig_constants():
    arm = load_arm(ARMS / "quanser_rotflex.toml")
    tb = arm.testbed
    assert (tb.length, tb.width, tb.thickness, tb.density) == (0.419, 0.02083, 0.0008128, 7850.0)
    assert isinstance(arm.drive, VoltageDrive)
    # the arm file's drive: tau = 0.1284 V - 0.0690 theta'
    assert arm.drive.gain == pytest.approx(0.1284, abs=5e-5)
    assert arm.drive.damping == pytest.approx(0.0690, abs=5e-5)
    space = arm.space
    assert space["E"].reference == 2.0e11 and space["J_h"].reference == 0.0021
    assert space["E"].lower <= 70e9 and space["E"].upper >= 210e9  # aluminium ... steel


@pytest.mark.parametrize(
    ("changes", "message"),
    [
        ({"width": "widht = 0.025"}, "link.width: missing value (is 'link.widht' a misspelling?)"),
        ({"extra": "[sensor]"}, "sensor: unknown key; did you mean 'sensors'?"),
        ({"extra": "[drives]"}, "drives: unknown key; did you mean 'drive'?"),
        ({"top": "colour = 'red'"}, "colour: unknown key; known keys: ['description', "),
        ({"clamp_offset": "clamp_offst = 0.0"}, "link.clamp_offst: unknown key; did you mean"),
        ({"length": 'length = "half a metre"'},
         "link.length: expected a number, got 'half a metre' (a string)"),
        ({"length": "length = -0.5"}, "link.length: expected a positive number, got -0.5"),
        ({"n_elements": "n_elements = 2.5"}, "simulation.n_elements: expected a whole number"),
        ({"E": "E = { reference = 2e11, lower = 20e9, upper = 100e9 }"},
         "parameters.E: bounds [20000000000.0, 100000000000.0] exclude the reference value "
         "200000000000.0"),
        ({"J_h": "J_h = { reference = 0.0053, lower = 1e-3 }"},
         "parameters.J_h.upper: missing value"),
        ({"beta": ""}, "parameters.beta: missing value"),
        ({"tau_c": "tau_c = { reference = 0.1, lower = 1e-3, upper = 0.2, fixd = true }"},
         "parameters.tau_c.fixd: unknown key; did you mean 'fixed'?"),
        ({"type": 'type = "hydraulic"'}, "drive.type: unknown drive 'hydraulic'; drives: "
         "['command', 'current', 'torque', 'voltage']"),
        ({"type": 'type = "current"'}, "drive.torque_per_amp: missing value"),
        ({"density": "density = 2700.0\nmass = 0.0675"},
         "link.density: give exactly one of density"),
        ({"name": "name = 3"}, "name: expected a string, got 3 (int)"),
        ({"name": 'name = "strip\\nB"'}, "name must be one line of text (the rig's name, "
         "written in fits and reports), got 'strip\\nB' (str)"),
        ({"type": 'type = "voltage"\nresistance = 2.6\ntorque_constant = 0.0077\n'
                  "back_emf_constant = 0.0077\ngear_ratio = 70\ngearbox_efficiency = 9\n"
                  "motor_efficiency = 0.69"},
         "drive.gearbox_efficiency: expected a number in (0, 1] (an efficiency: power out over "
         "power in), got 9 (int)"),
        ({"top": "effects = ['gravty']"}, "effects[0]: unknown effect 'gravty'"),
    ],
)
def test_arm_file_errors_are_one_line_naming_file_and_key(tmp_path, changes, message):
    path = tmp_path / "arm.toml"
    path.write_text(arm_text(**changes))
    with pytest.raises(ArmError) as info:
        load_arm(path)
    text = str(info.value)
    assert text.startswith(f"{path}: ") and "\n" not in text
    assert message in text


def test_a_rig_in_python_refuses_what_its_file_could_not_hold():
    """A model whose fit file would be refused on reading is refused when it is made."""
    with pytest.raises(TypeError, match=r"^name must be one line of text .*, got 5 \(int\)$"):
        Model(name=5)
    with pytest.raises(TypeError, match=r"^name must be one line .*, got 'a\\tb' \(str\)$"):
        Model(name="a\tb")
    with pytest.raises(TypeError, match=r"^description must be text, got None$"):
        Model(description=None)
    with pytest.raises(ValueError, match=r"^voltage drive: motor_efficiency=1.5 must be at most "
                                         r"1 \(an efficiency: power out over power in\)$"):
        VoltageDrive(motor_efficiency=1.5)
    assert Model(name="bench B, 0.4 m strip").name == "bench B, 0.4 m strip"


def test_broken_toml_and_missing_file(tmp_path):
    path = tmp_path / "arm.toml"
    path.write_text("[link\nlength = 1\n")
    with pytest.raises(ArmError, match=rf"^{path}: not valid TOML \("):
        load_arm(path)
    with pytest.raises(ArmError, match=r"nope.toml: arm file not found$"):
        load_arm(tmp_path / "nope.toml")


def test_mass_per_length_or_mass_instead_of_density(tmp_path):
    rho_a = 2700.0 * 0.025 * 0.002
    for line in (f"mass_per_length = {rho_a!r}", f"mass = {rho_a * 0.5!r}"):
        path = tmp_path / "arm.toml"
        path.write_text(arm_text(density=line))
        assert load_arm(path).testbed.mass_per_length == pytest.approx(rho_a, rel=1e-15)


def test_fixed_parameters_and_effects(tmp_path):
    path = tmp_path / "arm.toml"
    path.write_text(
        arm_text(
            b_v="b_v = { reference = 0.5, fixed = true }",  # outside the library's bounds
            top='effects = ["gravity"]',
        )
    )
    arm = load_arm(path)
    assert arm.fixed == ("b_v",) and arm.fixed_values == {"b_v": 0.5}
    assert arm.space["b_v"].lower <= 0.5 <= arm.space["b_v"].upper
    assert arm.effect_names == ("gravity",) and arm.space.names[-1] == "phi"


def test_arm_from_dict_without_a_file():
    data = {
        "name": "steel",
        "link": {"length": 1.0, "width": 0.05, "thickness": 0.005, "density": 7850.0},
        "parameters": {
            n: {"reference": s.reference, "lower": s.lower, "upper": s.upper}
            for n, s in ((s.name, s) for s in Model().base)
        },
        "drive": {"type": "current", "torque_per_amp": 8.925},
    }
    arm = arm_from_dict(data)
    assert arm.testbed == BED.replace(length=1.0, width=0.05, thickness=0.005, density=7850.0)
    assert arm.drive.gain == 8.925 and arm.name == "steel"
    data["parameters"]["E"]["lower"] = -1.0
    with pytest.raises(ArmError, match=r"^arm: parameters.E.lower: expected a positive number"):
        arm_from_dict(data)


def test_clamp_offset_moves_the_link_away_from_the_axis():
    """Offset r: rigid inertia ρA((r+L)³ − r³)/3 and θ–q coupling ∫ρA (r + x) w dx."""
    r, tb = 0.04, BED
    params = reference_parameters()
    near = Model(BED).structure(params)
    far = Model(BED.replace(clamp_offset=r)).structure(params)
    rho_a, length = tb.mass_per_length, tb.length
    expected = float(params["J_h"]) + rho_a * ((r + length) ** 3 - r**3) / 3
    assert float(far.mass[0, 0]) == pytest.approx(expected, rel=1e-14)
    assert BED.replace(clamp_offset=r).link_inertia == pytest.approx(expected - 0.0053, rel=1e-14)
    # the clamped deflection w = x² is represented exactly by the Hermite elements
    x = np.linspace(0.0, length, tb.n_elements + 1)[1:]
    q = np.zeros(1 + 2 * tb.n_elements)
    q[1::2], q[2::2] = x**2, 2 * x
    coupling = rho_a * (r * length**3 / 3 + length**4 / 4)
    assert float(far.mass[0, 1:] @ q[1:]) == pytest.approx(coupling, rel=1e-13)
    assert float(far.mass[1:, 0] @ q[1:]) == pytest.approx(coupling, rel=1e-13)
    np.testing.assert_array_equal(far.mass[1:, 1:], near.mass[1:, 1:])
    np.testing.assert_array_equal(far.stiffness, near.stiffness)
    assert float(far.first_moment[0]) == pytest.approx(rho_a * (r * length + length**2 / 2))
    with pytest.raises(ValueError, match="clamp_offset=-0.01 must be a number >= 0"):
        BED.replace(clamp_offset=-0.01)


def test_n_modes_travels_from_the_arm_file_through_a_fit_description(tmp_path):
    """``[simulation] n_modes`` truncates the arm's model, and a fit's model description
    rebuilds the same truncation (a saved fit must not silently revert to every mode)."""
    from jaxflex.identification import build_model, describe_model

    text = (ARMS / "reference.toml").read_text().replace(
        "[simulation]", "[simulation]\nn_modes = 8", 1
    )
    assert "n_modes = 8" in text
    path = tmp_path / "truncated.toml"
    path.write_text(text)
    model = load_arm(path)
    assert model.n_modes == 8
    assert build_model(describe_model(model)).n_modes == 8
    assert "n_modes" not in describe_model(load_arm(ARMS / "reference.toml"))["simulation"]


class _HubSpring(AbstractEffect):
    """A user's own effect: a torsional spring at the hub, ``k_s·θ`` opposing the angle."""

    name: ClassVar[str] = "hub_spring"
    parameters: ClassVar[tuple[ParameterSpec, ...]] = (
        ParameterSpec("k_s", "N m/rad", lower=0.0, upper=5.0, reference=0.5, null=0.0,
                      log_scale=False, description="hub spring stiffness"),
    )
    preload: float = eqx.field(static=True, default=0.0)

    def structure(self, structure, params):
        return eqx.tree_at(lambda s: s.stiffness, structure,
                           structure.stiffness.at[0, 0].add(params["k_s"]))


@pytest.fixture
def own_effect(monkeypatch):
    """The user's effect registered by name, for this test only (the registry is restored)."""
    import jaxflex.effects

    monkeypatch.setattr(jaxflex.effects, "EFFECTS", jaxflex.effects.EFFECTS.copy())
    assert register_effect(_HubSpring) is _HubSpring
    assert jaxflex.effects.get_effect("hub_spring") == _HubSpring()


def _odd_rig() -> Model:
    """A rig unlike the reference strip: other geometry, a voltage drive, sensors part-way
    along the link, an identified gain, a fixed parameter, a user's own effect, 8 modes."""
    text = (ARMS / "quanser_rotflex.toml").read_text()
    rig = arm_from_dict(tomllib.loads(text))
    sensors = (*rig.sensors, Accelerometer(channel="acc_mid", x=0.3, gain=0.102, noise=0.01,
                                           reading_unit="V"),
               DeflectionSensor(channel="laser", x=0.419), StrainGauge(channel="sg", x=0.2))
    return rig.replace(
        name="odd", sensors=sensors, fixed=("beta",), n_modes=8,
        effects=(_HubSpring(preload=0.25), SensorGain(channel="acc_mid", reference=0.102,
                                                      lower=0.05, upper=0.2,
                                                      gain_unit="V per m/s^2")),
    )


@pytest.mark.parametrize("name", ["reference", "quanser_rotflex", "daisy_robot_arm", "odd"])
def test_every_rig_round_trips_through_toml_and_a_fit_file_with_identical_simulations(
    tmp_path, name, own_effect
):
    from jaxflex.identification import build_model, describe_model

    rig = _odd_rig() if name == "odd" else load_arm(ARMS / f"{name}.toml")
    path = tmp_path / "rig.toml"
    path.write_text(arm_to_toml(rig))
    again = load_arm(path)
    from_fit = build_model(json.loads(json.dumps(describe_model(rig))))
    assert again == rig and from_fit == rig
    assert arm_to_dict(again) == arm_to_dict(rig)
    params = rig.space.reference()
    signal = reference_input("pulse", 0.5, 0.3, rig.testbed.dt)[1]
    first, second = simulate(rig, params, signal), simulate(from_fit, params, signal)
    for channel in (*OUTPUT_NAMES, *rig.channels):
        np.testing.assert_array_equal(second.channel(channel), first.channel(channel))


def test_a_rig_refuses_sensors_that_read_its_input_or_time_or_lie_beyond_the_link():
    rig = load_arm(ARMS / "quanser_rotflex.toml")
    with pytest.raises(ValueError, match="sensor channel 'voltage' is the voltage drive's input"):
        rig.replace(sensors=(Encoder(channel="voltage"),))
    with pytest.raises(ValueError, match="sensor channel 'time' is time, not a reading"):
        rig.replace(sensors=(Encoder(channel="time"),))
    with pytest.raises(ValueError, match=r"sensor tip at x = 0.5 m lies beyond the link "
                                         r"\(length 0.419 m\)"):
        rig.replace(sensors=(Accelerometer(channel="tip", x=0.5),))
    with pytest.raises(ValueError, match=r"two sensors log the channel\(s\) \['a'\]"):
        rig.replace(sensors=(Encoder(channel="a"), Tachometer(channel="a")))


def test_a_sensor_in_raw_units_reports_its_units(tmp_path):
    """An accelerometer logged in volts: its channel is in V, its identified gain in V per m/s^2
    (not '1', not m/s^2)."""
    from jaxflex.comparison import channel_units

    text = (ARMS / "reference.toml").read_text() + (
        '\n[[sensors]]\ntype = "accelerometer"\nchannel = "acc"\nx = 0.4\nreading_unit = "V"\n'
        'gain = { reference = 0.1, lower = 0.05, upper = 0.2 }\n')
    path = tmp_path / "volts.toml"
    path.write_text(text)
    rig = load_arm(path)
    assert channel_units(rig, ["acc"]) == {"acc": "V"}
    assert rig.space["gain_acc"].unit == "V per m/s^2"
    assert load_arm(path) == arm_from_dict(tomllib.loads(arm_to_toml(rig)))
