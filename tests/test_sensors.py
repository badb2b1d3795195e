"""Sensors: output maps at any position on the link, calibration, noise model, arm files."""

import math

import numpy as np
import pytest
from helpers import ARMS, arm_text

from jaxflex import Model, reference_parameters, simulate
from jaxflex.arm import ArmError, load_arm
from jaxflex.fem import BeamPatterns
from jaxflex.sensors import (
    Accelerometer,
    DeflectionSensor,
    Encoder,
    StrainGauge,
    Tachometer,
    readings,
)
from jaxflex.signals import reference_input
from jaxflex.stations import beam_rows

BED = Model().testbed


@pytest.fixture(scope="module")
def pulse_run():
    """One simulation of the reference arm with stations at the clamp, mid-element and tip."""
    sensors = (
        Encoder(counts_per_revolution=4096),
        Tachometer(),
        StrainGauge(channel="root_strain", x=0.0),
        StrainGauge(channel="mid_strain", x=0.1234),
        Accelerometer(channel="tip_acceleration", x=0.5),
        Accelerometer(channel="mid_acceleration", x=0.1234),
        DeflectionSensor(channel="tip_deflection", x=0.5),
    )
    model = Model(sensors=sensors)
    torque = reference_input("pulse")[1]
    params = reference_parameters()
    return sensors, model, simulate(model, params, torque), simulate(Model(), params, torque)


def test_sensors_at_tip_and_clamp_equal_todays_outputs_exactly(pulse_run):
    sensors, model, outputs, today = pulse_run
    read = readings(model, outputs)
    np.testing.assert_array_equal(read["tip_acceleration"], today.tip_acceleration)
    np.testing.assert_array_equal(read["tip_deflection"], today.tip_deflection)
    np.testing.assert_array_equal(read["root_strain"], today.root_strain)
    np.testing.assert_array_equal(read["joint_angle"], today.joint_angle)
    np.testing.assert_array_equal(read["joint_velocity"], today.joint_velocity)
    for name in ("joint_angle", "tip_acceleration", "tip_deflection", "root_strain"):
        np.testing.assert_array_equal(getattr(outputs, name), getattr(today, name))
    assert today.station_curvature is None  # no stations, no extra outputs


def test_a_record_may_hold_any_subset_of_the_sensors(pulse_run):
    sensors, model, outputs, _ = pulse_run
    read = readings(model, outputs, channels=("time", "torque", "mid_strain"))
    assert list(read) == ["mid_strain"]


def test_mid_link_accelerometer_is_the_second_derivative_of_the_point_motion():
    """a(x) = x·θ'' + ẅ(x): the simulated point motion x·θ + w(x), differenced twice, agrees.

    A smooth torque (sin², 1 s) sampled at 10 kHz keeps the O(dt²) error of the central
    difference far below the signal; the deflection is a large part of the motion there.
    """
    x, dt = 0.1234, 1e-4
    sensors = (Accelerometer(x=x), DeflectionSensor(x=x))
    model = Model(sensors=sensors)
    time = np.arange(0.0, 1.0 + dt / 2, dt)
    outputs = simulate(model, reference_parameters(), 0.3 * np.sin(np.pi * time) ** 2, dt)
    read = readings(model, outputs)
    motion = x * np.asarray(outputs.joint_angle) + np.asarray(read["tip_deflection"])
    second_difference = np.diff(motion, 2) / dt**2
    measured = np.asarray(read["acceleration"])[1:-1]
    assert np.max(np.abs(read["tip_deflection"])) > 1e-4 * np.max(np.abs(motion))
    assert np.max(np.abs(second_difference - measured)) < 1e-4 * np.max(np.abs(measured))


def test_strain_gauge_matches_the_static_cantilever_under_a_tip_load():
    """Tip load P on the clamped link: w''(x) = P(L − x)/EI, w(L) = PL³/(3EI) (exact in FEM)."""
    params = reference_parameters()
    structure = Model().structure(params)
    ei = float(params["E"]) * BED.second_moment
    load = np.zeros(structure.mass.shape[0])
    load[-2] = 0.8  # N at the tip
    q = np.zeros_like(load)
    q[1:] = np.linalg.solve(np.asarray(structure.stiffness)[1:, 1:], load[1:])
    positions = [0.0, 0.03, 0.1234, 0.25, 0.4999]
    deflection, curvature = beam_rows(BED.length, BED.n_elements, positions)
    length = BED.length
    for k, x in enumerate(positions):
        exact = 0.8 * (length - x) / ei
        assert curvature[k] @ q == pytest.approx(exact, rel=1e-9)
        exact_w = 0.8 * x**2 * (3 * length - x) / (6 * ei)
        assert deflection[k] @ q == pytest.approx(exact_w, rel=1e-9, abs=1e-15)
        # Quanser's calibration reports the tip deflection angle w(L)/L of this static shape
        angle = StrainGauge(x=x, calibration="deflection_angle").scale(Model()) * curvature[k] @ q
        assert angle == pytest.approx(0.8 * length**2 / (3 * ei), rel=1e-9)
        strain = StrainGauge(x=x).scale(Model()) * curvature[k] @ q
        assert strain == pytest.approx(BED.thickness / 2 * exact, rel=1e-9)
    assert np.array_equal(beam_rows(BED.length, 10, [BED.length])[0][0], BeamPatterns(0.5, 10).tip)


def test_calibration_gain_offset_and_noise_model(pulse_run):
    sensors, model, outputs, today = pulse_run
    gauge = StrainGauge(channel="s", x=0.0, gain=-2.0, offset=1e-4)
    reading = np.asarray(gauge.measure(model, outputs))
    np.testing.assert_allclose(reading, -2.0 * np.asarray(today.root_strain) + 1e-4, rtol=1e-15)
    encoder = Encoder(counts_per_revolution=4096, noise=0.0)
    assert encoder.resolution == 2 * math.pi / 4096
    logged = encoder.observe(np.asarray(today.joint_angle), np.random.default_rng(0))
    counts = logged / encoder.resolution
    np.testing.assert_allclose(counts, np.round(counts), rtol=0, atol=1e-9)
    error = logged - np.asarray(today.joint_angle)
    assert np.max(np.abs(error)) <= encoder.resolution / 2 * (1 + 1e-12)
    assert encoder.noise_std == pytest.approx(encoder.resolution / 12**0.5)
    noisy = Tachometer(noise=0.01).observe(np.zeros(20000), np.random.default_rng(1))
    assert np.std(noisy) == pytest.approx(0.01, rel=0.03)
    assert Encoder(resolution=0.0).observe(np.array([0.1]), np.random.default_rng(0))[0] == 0.1


def test_sensor_errors_name_the_sensor():
    with pytest.raises(ValueError, match="strain_gauge s: calibration='volts' must be"):
        StrainGauge(channel="s", calibration="volts")
    with pytest.raises(ValueError, match="encoder joint_angle: counts_per_revolution=0 must"):
        Encoder(counts_per_revolution=0)
    with pytest.raises(ValueError, match=r"accelerometer a: the model has no station at x = 0.3"):
        Accelerometer(channel="a", x=0.3).measure(Model(), None)
    with pytest.raises(ValueError, match="must be a float position on the link"):
        Model(stations=(0.7,))


def test_rotflex_arm_sensors(tmp_path):
    arm = load_arm(ARMS / "quanser_rotflex.toml")
    assert arm.sensor("joint_angle").resolution == 2 * math.pi / 4096
    gauge = arm.sensor("deflection_angle")
    assert isinstance(gauge, StrainGauge) and gauge.calibration == "deflection_angle"
    assert arm.stations == (0.0,)
    with pytest.raises(KeyError, match="no sensor logging 'tip_acceleration'"):
        arm.sensor("tip_acceleration")


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        ('[[sensors]]\ntype = "laser"', "sensors[0].type: unknown sensor 'laser'; sensors: ["),
        ('[[sensors]]\ntype = "accelerometer"\nx = 0.6', "sensors[0].x: 0.6 m lies beyond the"),
        ('[[sensors]]\ntype = "accelerometer"\npositon = 0.2', "sensors[0].positon: unknown key"),
        ('[[sensors]]\ntype = "encoder"\ncounts_per_revolution = 40.5',
         "sensors[0].counts_per_revolution: expected a whole number"),
        ('[[sensors]]\ntype = "accelerometer"\nchannel = "tip_acceleration"\nx = 0.5\n'
         '[[sensors]]\ntype = "accelerometer"\nchannel = "tip_acceleration"\nx = 0.5',
         "sensors[1].channel: sensors[0] logs the channel 'tip_acceleration' too"),
        ('[[sensors]]\ntype = "accelerometer"\nchannel = "acc_mid"',
         "sensors[0].x: missing value; the accelerometer 'acc_mid' sits on the link: give its "
         "distance from the clamp in m"),
        ('[[sensors]]\ntype = "deflection"\nchannel = "laser"\nx = 0',
         "sensors[0].x: the deflection 'laser' at x = 0 sits at the clamp, where it reads zero"),
        ('[[sensors]]\ntype = "accelerometer"\nchannel = "acc"\nx = 0.0',
         "sensors[0].x: the accelerometer 'acc' at x = 0 sits at the clamp, where it reads zero"),
        ('[[sensors]]\ntype = "strain_gauge"\nchannel = "sg"',
         "sensors[0].x: missing value; the strain_gauge 'sg' sits on the link"),
    ],
)
def test_sensor_table_errors_name_file_and_key(tmp_path, extra, message):
    path = tmp_path / "arm.toml"
    path.write_text(arm_text(extra=extra))
    with pytest.raises(ArmError, match=None) as info:
        load_arm(path)
    assert message in str(info.value) and "\n" not in str(info.value)


def test_a_link_sensor_that_reads_zero_at_the_clamp_is_refused_in_python_too():
    """On the joint axis an accelerometer at the clamp does not move and a deflection there is
    zero; with the clamp off the axis the accelerometer reads (r·θ''), and a gauge always
    reads the root strain."""
    for sensor in (Accelerometer(channel="acc"), DeflectionSensor(channel="laser", x=0.0)):
        with pytest.raises(ValueError, match=rf"sensor {sensor.channel} at x = 0 sits at the "
                                             "clamp, where it reads zero"):
            Model(sensors=(Encoder(), sensor))
    offset = Model().testbed.replace(clamp_offset=0.05)
    assert Model(offset, sensors=(Accelerometer(channel="acc"),)).stations == (0.0,)
    assert Model(sensors=(StrainGauge(channel="sg"),)).stations == (0.0,)
