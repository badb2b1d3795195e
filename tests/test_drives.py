"""Drives: torque, current and voltage inputs; the back-EMF is exactly a viscous friction."""

from typing import ClassVar

import numpy as np
import pytest

from jaxflex import Model, reference_parameters, simulate
from jaxflex.drives import CurrentDrive, TorqueDrive, VoltageDrive, get_drive
from jaxflex.effects import AbstractEffect
from jaxflex.signals import reference_input

ROTFLEX = dict(
    resistance=2.6,
    torque_constant=7.68e-3,
    back_emf_constant=7.68e-3,
    gear_ratio=70.0,
    gearbox_efficiency=0.9,
    motor_efficiency=0.69,
)


class _Viscous(AbstractEffect):
    """A viscous joint friction of fixed coefficient, written here for the comparison."""

    name: ClassVar[str] = "test_viscous"
    coefficient: float = 0.0

    def friction(self, params, velocity, omega_s):
        return self.coefficient * velocity


def test_voltage_drive_is_a_torque_drive_plus_back_emf_viscous_friction_exactly():
    drive = VoltageDrive(**ROTFLEX)
    volts = reference_input("pulse")[1] / 0.1071 * 1.5  # a 1.5 V pulse train
    params = reference_parameters()
    by_voltage = simulate(Model(drive=drive), params, volts)
    torque_model = Model().with_effects(_Viscous(coefficient=drive.gain * 70.0 * 7.68e-3))
    by_torque = simulate(torque_model, params, drive.gain * volts)
    for name in by_voltage.__dataclass_fields__:
        np.testing.assert_array_equal(getattr(by_voltage, name), getattr(by_torque, name))
    # and the back-EMF does act: without it the arm turns further
    free = simulate(Model(), params, drive.gain * volts)
    assert np.max(np.abs(free.joint_angle)) > 1.05 * np.max(np.abs(by_voltage.joint_angle))


def test_drive_constants():
    drive = VoltageDrive(**ROTFLEX)
    k = 70.0 * 0.9 * 0.69 * 7.68e-3 / 2.6
    assert drive.gain == pytest.approx(k, rel=1e-15)
    assert drive.damping == pytest.approx(k * 70.0 * 7.68e-3, rel=1e-15)
    assert CurrentDrive(torque_per_amp=8.925).gain == 8.925
    assert CurrentDrive(torque_per_amp=8.925).damping == 0.0
    assert TorqueDrive().gain == 1.0 and TorqueDrive().damping == 0.0
    assert get_drive("voltage", **ROTFLEX) == drive
    assert drive.settings() == ROTFLEX


def test_current_drive_scales_the_torque_exactly():
    amps = reference_input("pulse")[1] / 8.925
    params = reference_parameters()
    a = simulate(Model(drive=CurrentDrive(torque_per_amp=8.925)), params, amps)
    b = simulate(Model(), params, 8.925 * amps)
    np.testing.assert_array_equal(a.joint_angle, b.joint_angle)


def test_drive_errors_name_the_setting():
    with pytest.raises(ValueError, match=r"^voltage drive: resistance=0.0 must be a positive"):
        VoltageDrive(**(ROTFLEX | {"resistance": 0.0}))
    with pytest.raises(ValueError, match=r"unknown drive 'hydraulic'; drives: \['command', 'cur"):
        get_drive("hydraulic")
    with pytest.raises(ValueError, match=r"current drive: unknown setting\(s\) \['gain'\]"):
        get_drive("current", gain=2.0)
