"""Inputs that move the hub: `simulate`'s default excitations are sized to the rig's breakaway
friction, in the drive's unit and within its saturation, and an input whose torque never
exceeds the breakaway is said, on the reference testbed and on a rig of one's own."""

import math

import numpy as np
import pytest

from jaxflex.cli import main
from jaxflex.data import load_record
from jaxflex.effects import get_effect
from jaxflex.model import Model
from jaxflex.signals import EXCITATION_AMPLITUDES, EXCITATION_BREAKAWAY_MULTIPLE
from jaxflex.synthetic import ENCODER_STEP

BENCH_COUNTS = 2048
BENCH = """\
name = "bench"
[link]
length = 0.35
width = 0.02
thickness = 0.003
density = 2700.0
[simulation]
n_elements = 4
[sampling]
duration = 1.0
[parameters]
E = { reference = 7e10, fixed = true }
J_h = { reference = 0.003, lower = 0.001, upper = 0.01 }
b_v = { reference = 0.004, lower = 1e-4, upper = 0.02 }
tau_c = { reference = 0.15, fixed = true }
alpha = { reference = 1.0, fixed = true }
beta = { reference = 5e-5, fixed = true }
[drive]
type = "command"
unit = "counts"
torque_per_unit = 0.0025
saturation = SATURATION
[[sensors]]
type = "encoder"
channel = "angle"
counts_per_revolution = 2048
[[sensors]]
type = "accelerometer"
channel = "acc_mid"
x = 0.2
"""
"""A 0.35 m strip with stiffer friction than the reference (0.15 N m), driven by a command in
counts of 0.0025 N m that saturates, an encoder and an accelerometer part-way along."""


def _bench(tmp_path, saturation: float = 400.0):
    path = tmp_path / "bench.toml"
    path.write_text(BENCH.replace("SATURATION", repr(saturation)))
    return path


@pytest.fixture
def warnings_shown(monkeypatch):
    """Warnings on stderr as a command shows them outside a test runner."""
    import sys
    import warnings

    def show(message, category, filename, lineno, file=None, line=None):
        sys.stderr.write(warnings.formatwarning(message, category, filename, lineno, line))

    monkeypatch.setattr(warnings, "showwarning", show)


def _simulate(tmp_path, name: str, *extra: str):
    out = tmp_path / f"{name}.csv"
    assert main(["simulate", "--input", name, "--out", str(out), "--overwrite", *extra]) == 0
    return load_record(out, channels=("command", "angle", "acc_mid"))


def test_the_breakaway_torque_is_the_static_friction():
    params = Model().space.reference()
    assert Model().breakaway_torque(params) == pytest.approx(float(params["tau_c"]), rel=1e-9)
    stribeck = Model(effects=(get_effect("stribeck"),))
    values = stribeck.space.reference() | {"delta_tau_s": 0.04}
    assert stribeck.breakaway_torque(values) == pytest.approx(0.1071 + 0.04, rel=1e-9)
    # the reference testbed's default excitation is the multiple of its breakaway
    for amplitude in EXCITATION_AMPLITUDES.values():
        assert amplitude == pytest.approx(EXCITATION_BREAKAWAY_MULTIPLE * float(params["tau_c"]),
                                          rel=1e-12)


@pytest.mark.parametrize("name", ["chirp", "multisine"])
def test_the_default_excitation_moves_the_reference_hub(tmp_path, capsys, warnings_shown,
                                                         name):
    record = _simulate(tmp_path, name)
    assert np.ptp(record.joint_angle) > 10 * ENCODER_STEP
    assert "warning" not in capsys.readouterr().err


def test_an_amplitude_below_the_breakaway_is_said_on_the_reference(tmp_path, capsys,
                                                                   warnings_shown):
    record = _simulate(tmp_path, "multisine", "--amplitude", "0.05")
    assert np.ptp(record.joint_angle) < ENCODER_STEP  # friction holds it: the warning is true
    err = capsys.readouterr().err
    assert err == ("jaxflex simulate: warning: input 'multisine' peaks at 0.05 N m at the hub, "
                   "which never exceeds the joint's breakaway friction torque 0.107 N m: "
                   "friction holds the hub still; raise the amplitude\n")


@pytest.mark.parametrize("name", ["chirp", "multisine"])
def test_the_default_excitation_moves_the_hub_of_a_rig_driven_in_counts(tmp_path, capsys,
                                                                        warnings_shown, name):
    """Three times 0.15 N m through 0.0025 N m per count: 180 counts, which the hub follows
    over many encoder counts."""
    record = _simulate(tmp_path, name, "--arm", str(_bench(tmp_path)))
    assert np.max(np.abs(record.channel("command"))) == pytest.approx(180.0, rel=1e-6)
    assert np.ptp(record.channel("angle")) > 10 * 2 * math.pi / BENCH_COUNTS
    assert "warning" not in capsys.readouterr().err


def test_a_small_command_or_a_low_saturation_is_said_on_a_rig_driven_in_counts(
        tmp_path, capsys, warnings_shown):
    bench = str(_bench(tmp_path))
    record = _simulate(tmp_path, "chirp", "--arm", bench, "--amplitude", "20")
    assert np.ptp(record.channel("angle")) < 2 * math.pi / BENCH_COUNTS
    assert ("warning: input 'chirp' peaks at 0.05 N m at the hub, which never exceeds the "
            "joint's breakaway friction torque 0.15 N m") in capsys.readouterr().err
    # the default stays within a saturation of 40 counts, 0.1 N m: too little, and said so
    low = str(_bench(tmp_path, saturation=40.0))
    record = _simulate(tmp_path, "chirp", "--arm", low)
    assert np.max(np.abs(record.channel("command"))) == pytest.approx(40.0, rel=1e-6)
    assert ("warning: input 'chirp' peaks at 0.1 N m at the hub, which never exceeds the "
            "joint's breakaway friction torque 0.15 N m") in capsys.readouterr().err


def test_a_design_whose_peak_torque_cannot_move_the_hub_is_refused_at_once(tmp_path, capsys):
    from jaxflex.design import design_input

    with pytest.raises(ValueError, match=r"^max_torque=0.1 never exceeds the joint's breakaway "
                                         r"friction torque 0.107 N m: no input within it moves"):
        design_input(max_torque=0.1, rms_torque=0.05, max_angle=1.0, max_speed=5.0)
    out = tmp_path / "designed.csv"
    assert main(["design", "--arm", str(_bench(tmp_path)), "--max-torque", "40", "--max-angle",
                 "1", "--max-speed", "5", "--out", str(out), "--quiet"]) == 2
    assert capsys.readouterr().err == (
        "jaxflex design: error: --max-torque 40 (0.1 N m at the hub) never exceeds the joint's "
        "breakaway friction torque 0.15 N m: no input within it moves the hub; raise it\n")
    assert not out.exists()
