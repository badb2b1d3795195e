"""Registries of extension points: a user's drive, sensor or strategy named like the library's."""

from __future__ import annotations

import tomllib
from typing import ClassVar

import pytest

import jaxflex.arm
from jaxflex.arm import arm_from_dict
from jaxflex.drives import DRIVES, AbstractDrive
from jaxflex.evolve import DE, STRATEGIES
from jaxflex.rigs import arm_path
from jaxflex.sensors import SENSORS, Encoder


class _Hydraulic(AbstractDrive):
    """A drive of one's own: valve current to torque."""

    name: ClassVar[str] = "valve"
    unit: ClassVar[str] = "mA"
    torque_per_milliamp: float = 0.02

    @property
    def gain(self) -> float:
        return self.torque_per_milliamp


def test_an_arm_file_names_a_registered_drive(monkeypatch):
    drives = DRIVES.copy()
    monkeypatch.setattr(jaxflex.arm, "DRIVES", drives)
    drives.register(_Hydraulic)
    data = tomllib.loads(arm_path("reference").read_text())
    rig = arm_from_dict(data | {"drive": {"type": "valve", "torque_per_milliamp": 0.05}})
    assert rig.drive == _Hydraulic(torque_per_milliamp=0.05)
    assert rig.drive.torque(2.0) == pytest.approx(0.1)
    assert "valve" not in DRIVES  # the library's registry is untouched


def test_registries_refuse_what_they_cannot_name():
    drives = DRIVES.copy()
    with pytest.raises(TypeError, match="a drive must subclass AbstractDrive, got <class 'int'>"):
        drives.register(int)

    class Other(_Hydraulic):
        name: ClassVar[str] = "torque"

    with pytest.raises(ValueError, match="drive name 'torque' is taken by TorqueDrive"):
        drives.register(Other)
    with pytest.raises(ValueError, match=r"unknown sensor 'laser'; sensors: \['accelerometer'"):
        SENSORS.create("laser")
    with pytest.raises(ValueError, match=r"encoder sensor: unknown setting\(s\) \['cpr'\]"):
        SENSORS.create("encoder", cpr=10)
    assert SENSORS.create("encoder", channel="theta") == Encoder(channel="theta")
    assert STRATEGIES["de"] is DE
    with pytest.raises(ValueError, match="unknown strategy 'cma'; strategies: "):
        STRATEGIES.lookup("cma")


def test_an_extension_point_without_its_method_cannot_be_made():
    class NoGain(AbstractDrive):
        name: ClassVar[str] = "nogain"

    with pytest.raises(TypeError, match="abstract"):
        NoGain()

    class NoQuantity(Encoder.__mro__[1]):  # the abstract sensor
        kind: ClassVar[str] = "nothing"

    with pytest.raises(TypeError, match="abstract"):
        NoQuantity()
