"""The torque_offset effect: a constant bias added to the drive's torque, of either sign."""

import numpy as np
import pytest

from jaxflex import Model, reference_parameters, simulate
from jaxflex.drives import VoltageDrive
from jaxflex.effects import TorqueOffset, get_effect
from jaxflex.signals import reference_input


@pytest.mark.parametrize("offset", [0.02, -0.015])
def test_an_offset_is_the_same_constant_added_to_the_input(offset):
    torque = reference_input("pulse")[1]
    model = Model().with_effects(TorqueOffset())
    params = reference_parameters() | {"tau_0": offset}
    model.space.validate(params, within_bounds=True)  # a negative bias is a valid value
    biased = simulate(model, params, torque)
    shifted = simulate(Model(), reference_parameters(), torque + offset)
    np.testing.assert_array_equal(biased.joint_angle, shifted.joint_angle)
    np.testing.assert_array_equal(biased.tip_acceleration, shifted.tip_acceleration)


def test_with_a_voltage_drive_the_offset_is_the_gain_times_a_voltage_bias():
    drive = VoltageDrive(2.6, 7.68e-3, 7.68e-3, 70.0, 0.9, 0.69)
    volts = reference_input("pulse")[1] * 10.0
    params = reference_parameters()
    model = Model(drive=drive)
    offset = model.with_effects(get_effect("torque_offset"))
    biased = simulate(offset, params | {"tau_0": drive.gain * 0.1}, volts)
    shifted = simulate(model, params, volts + 0.1)
    # the same physics rounded differently: where the joint sticks, the friction solve turns
    # rounding of gain·(V + V0) against gain·V + gain·V0 into ~1e-8 of full scale
    scale = float(np.max(np.abs(shifted.joint_angle)))
    np.testing.assert_allclose(biased.joint_angle, shifted.joint_angle, rtol=0, atol=1e-6 * scale)


def test_the_offset_drives_a_resting_arm_once_it_beats_coulomb_friction():
    """At rest under zero input, a bias above tau_c accelerates the arm at (τ0 − τc)/J_tot."""
    params = reference_parameters() | {"tau_0": 0.15, "b_v": 1e-5}
    model = Model().with_effects(TorqueOffset())
    out = simulate(model, params, np.zeros(201))
    tb = model.testbed
    j_tot = float(params["J_h"]) + tb.link_inertia
    expected = 0.5 * (0.15 - float(params["tau_c"])) / j_tot * 0.2**2
    assert out.joint_angle[-1] == pytest.approx(expected, rel=0.05)
    # below tau_c the smooth Coulomb law only lets it creep, at ω_s·atanh(tau_0/tau_c)
    creep = simulate(model, params | {"tau_0": 0.9 * float(params["tau_c"])}, np.zeros(2001))
    speed = tb.omega_s * np.arctanh(0.9)
    assert float(creep.joint_velocity[-1]) == pytest.approx(speed, rel=1e-3)


@pytest.mark.slow  # a base refit and the score tests of every candidate
def test_score_tests_name_the_offset_not_gravity():
    """A bias hidden in synthetic records is found by discover's score tests, ahead of the
    tilted plane (gravity) that used to absorb it, and its sign is estimated."""
    from jaxflex.diagnosis import NoiseLevel
    from jaxflex.discovery import refit, score_tests
    from jaxflex.synthetic import ACCELEROMETER_SIGMA, ENCODER_STEP, make_records

    truth = {"E": 5.2e10, "J_h": 0.0062, "b_v": 1.2e-3, "tau_c": 0.09, "alpha": 1.3,
             "beta": 9e-5}
    model = Model().with_effects(TorqueOffset())
    records = make_records(model, truth | {"tau_0": -0.008}, seed=5)
    noise = {"joint_angle": NoiseLevel.quantised(ENCODER_STEP),
             "tip_acceleration": NoiseLevel(ACCELEROMETER_SIGMA)}
    start = {k: v * (1.03 if i % 2 else 0.97) for i, (k, v) in enumerate(truth.items())}
    base = refit(records, Model(), start, noise=noise)
    ranking = score_tests(records, base.model, base.params, noise=noise)
    assert ranking[0].effect == "torque_offset", [(r.effect, r.statistic) for r in ranking]
    assert ranking[0].significant and ranking[0].estimate["tau_0"] < 0
    gravity = next(r for r in ranking if r.effect == "gravity")
    assert gravity.statistic < ranking[0].statistic
