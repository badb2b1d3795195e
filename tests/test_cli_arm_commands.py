"""``--arm`` on simulate, study, discover and design; a fit's rig carries to later commands."""

import json
import math

import numpy as np
import pytest
from helpers import ARMS

from jaxflex.arm import load_arm
from jaxflex.cli import main
from jaxflex.data import Record, load_record, save_record
from jaxflex.effects import get_effect
from jaxflex.measured import logged_record, model_record

REFERENCE = str(ARMS / "reference.toml")
ROTFLEX_FILE = str(ARMS / "quanser_rotflex.toml")
ROTFLEX = load_arm(ROTFLEX_FILE)
TINY = ["--generations", "2", "--population", "8", "--no-refine", "--quiet"]


@pytest.fixture(scope="module")
def rotflex_log(tmp_path_factory):
    """A ROTFLEX-like log written by ``simulate --arm`` (0.1 s at rest, then 1.5 s of a
    triangular voltage; encoder and strain gauge with their noise and quantisation)."""
    path = tmp_path_factory.mktemp("rotflex") / "log.csv"
    assert main(["simulate", "--arm", ROTFLEX_FILE, "--input", "triangular", "--duration", "1.5",
                 "--rest", "0.1", "--add-noise", "--seed", "3", "--out", str(path)]) == 0
    return path


@pytest.fixture(scope="module")
def reference_log(tmp_path_factory):
    path = tmp_path_factory.mktemp("reference") / "pulse.csv"
    assert main(["simulate", "--arm", REFERENCE, "--input", "pulse", "--duration", "1",
                 "--out", str(path)]) == 0
    return path


def test_simulate_with_the_reference_arm_is_todays_simulate(tmp_path, reference_log):
    plain = tmp_path / "plain.csv"
    assert main(["simulate", "--input", "pulse", "--duration", "1", "--out", str(plain)]) == 0
    today, with_arm = load_record(plain), load_record(reference_log)
    for column in ("time", "torque", "joint_angle", "tip_acceleration"):
        np.testing.assert_array_equal(with_arm.channel(column), today.channel(column))


def test_simulate_with_an_arm_logs_its_drive_and_sensors(rotflex_log):
    record = load_record(rotflex_log)
    assert set(record.columns) == {"time", "voltage", "joint_angle", "deflection_angle"}
    assert record.dt == pytest.approx(ROTFLEX.testbed.dt)  # the arm's sampling
    assert record.duration == pytest.approx(1.6)
    assert not np.any(record.channel("voltage")[record.time < 0.1])  # at rest first
    # the default amplitude is the input's own torque (0.49 N m) in volts through the gain
    assert np.max(record.channel("voltage")) == pytest.approx(0.49 / ROTFLEX.drive.gain)
    step = 2 * math.pi / 4096  # the encoder's quantum, with noise on
    counts = record.joint_angle / step
    np.testing.assert_allclose(counts, np.round(counts), atol=1e-6)
    assert np.ptp(record.joint_angle) > 100 * step  # the arm moved
    ready = model_record(ROTFLEX, record)  # and the log is what the model reads
    assert set(ready.columns) == {"time", "voltage", "joint_angle", "deflection_angle"}


def test_simulate_with_an_arm_refuses_link_settings(tmp_path, capsys):
    out = str(tmp_path / "x.csv")
    assert main(["simulate", "--arm", ROTFLEX_FILE, "--input", "pulse", "--set", "length=1",
                 "--out", out]) == 2
    assert "--set length: with --arm the arm file sets the link; edit it" in capsys.readouterr().err
    assert main(["simulate", "--arm", ROTFLEX_FILE, "--input", "pulse", "--set", "E=-1",
                 "--out", out]) == 2
    assert "--set: " in capsys.readouterr().err
    assert not (tmp_path / "x.csv").exists()


def test_outputs_are_checked_before_the_arm_is_used(tmp_path, rotflex_log, capsys):
    taken, record = tmp_path / "taken.json", tmp_path / "taken.csv"
    taken.write_text("{}")
    record.write_text("")
    for option, command in (
        ("--out", ["study", str(rotflex_log), "--arm", ROTFLEX_FILE, "--methods", "de",
                   "--seeds", "0", "--out", str(taken)]),
        ("--json", ["discover", str(rotflex_log), "--arm", ROTFLEX_FILE, "--json", str(taken)]),
        ("--out", ["design", "--arm", ROTFLEX_FILE, "--max-torque", "5", "--max-angle", "1",
                   "--max-speed", "5", "--out", str(record)]),
        ("--out", ["simulate", "--arm", ROTFLEX_FILE, "--input", "pulse", "--out", str(record)]),
    ):
        assert main(command) == 2
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1
        assert f"{option} {command[-1]}: file exists; pass --overwrite" in err
    assert taken.read_text() == "{}" and record.read_text() == ""


@pytest.mark.slow  # compiles the search
def test_study_with_an_arm_fits_the_sensor_channels(tmp_path, rotflex_log):
    out = tmp_path / "study.json"
    assert main(["study", str(rotflex_log), "--arm", ROTFLEX_FILE, "--methods", "de",
                 "--seeds", "0", "--window", "0:1.4", *TINY[:4], "--quiet", "--out",
                 str(out)]) == 0
    saved = json.loads(out.read_text())["settings"]
    assert saved["arm"] == str((ARMS / "quanser_rotflex.toml").resolve())
    assert saved["windows"] == {"log": [0.0, 1.4]}


def _offset_log(folder, tau_0: float):
    """A ROTFLEX-like log with a torque bias ``tau_0``: voltage pulses of alternating sign
    after 0.3 s at rest (the angle stays within ±20°), encoder and strain gauge with their
    quantisation, no accelerometer; written as a logger does, 7 significant digits, its clock
    starting at 12.5 s."""
    params = {"E": 1.6e11, "J_h": 0.0024, "b_v": 0.004, "tau_c": 0.02, "alpha": 0.05,
              "beta": 3e-4}
    t = np.arange(0.0, 2.0, ROTFLEX.testbed.dt)
    pulse = (t - 0.3) % 0.5 < 0.1
    sign = np.where((t - 0.3) // 0.5 % 2 == 0, 1.0, -1.0)
    volts = np.where(t < 0.3, 0.0, 2.0 * pulse * sign)
    record = logged_record(ROTFLEX.with_effects(get_effect("torque_offset")),
                           params | {"tau_0": tau_0}, t, volts, seed=4)
    assert np.max(np.abs(record.joint_angle)) < np.radians(20.0)
    columns = ["voltage", "joint_angle", "deflection_angle"]
    path = folder / "offset.csv"
    np.savetxt(path, np.column_stack([12.5 + t, *(record.channel(c) for c in columns)]),
               fmt="%.7g", delimiter=",", header=",".join(["time", *columns]), comments="")
    start = folder / "start.json"
    start.write_text(json.dumps({k: v * (1.03 if i % 2 else 0.97)
                                 for i, (k, v) in enumerate(params.items())}))
    return path, start


@pytest.mark.slow  # a discovery run; the fast set keeps one of its kind
def test_discover_names_a_torque_offset_on_encoder_and_strain_gauge(tmp_path, capsys):
    """Voltage drive, encoder and root strain gauge (no accelerometer): discover fits the two
    channels the arm's sensors give, with their quantisation as noise model, and names the
    bias as a torque offset of the right size, not as a tilted plane (the angle stays small,
    where gravity's cos θ is a constant torque too)."""
    log, start = _offset_log(tmp_path, -0.006)  # a larger bias bends the link at t0 already
    out = tmp_path / "discover.json"
    assert main(["discover", str(log), "--arm", ROTFLEX_FILE, "--initial", str(start),
                 "--candidates", "torque_offset,gravity", "--max-steps", "1",
                 "--json", str(out)]) == 0
    assert "deflection_angle NRMSE %" in capsys.readouterr().out
    result = json.loads(out.read_text())
    assert result["settings"]["channels"] == ["joint_angle", "deflection_angle"]
    noise = result["settings"]["noise"]
    assert noise["joint_angle"]["step"] == pytest.approx(2 * math.pi / 4096)
    assert noise["deflection_angle"]["kind"] == "quantised"
    assert noise["deflection_angle"]["step"] == 6.4e-5
    base, added = result["steps"]
    assert added["added"] == "torque_offset"
    assert added["params"]["tau_0"] == pytest.approx(-0.006, rel=0.05)
    assert "phi" not in added["params"]
    ranking = {r["effect"]: r["statistic"] for r in result["ranking"][0]}
    assert ranking["torque_offset"] > 3 * ranking["gravity"]
    for channel in ("joint_angle", "deflection_angle"):
        assert added["nrmse"][channel] < 0.1 * base["nrmse"][channel]


@pytest.mark.slow  # compiles the search
def test_a_fit_carries_its_rig_to_discover(tmp_path, capsys):
    log, fit = tmp_path / "log.csv", tmp_path / "fit.json"
    assert main(["simulate", "--arm", ROTFLEX_FILE, "--input", "pulse", "--duration", "0.4",
                 "--rest", "0.1", "--out", str(log)]) == 0
    assert main(["identify", str(log), "--arm", ROTFLEX_FILE, *TINY, "--out", str(fit)]) == 0
    capsys.readouterr()
    assert main(["discover", str(log), "--initial", str(fit), "--arm", REFERENCE]) == 2
    assert "the fit was made with another rig ('quanser_rotflex')" in capsys.readouterr().err
    # the fit's rig (a voltage drive) meets a torque log: the rig was used without --arm
    torque = tmp_path / "t.csv"
    assert main(["simulate", "--input", "pulse", "--duration", "0.5", "--out", str(torque)]) == 0
    assert main(["discover", str(torque), "--initial", str(fit), "--window", "0:0.4"]) == 2
    err = capsys.readouterr().err
    assert "logs 'torque' but rig 'quanser_rotflex' has a voltage drive" in err


@pytest.mark.slow  # compiles the Fisher information
def test_design_with_an_arm_writes_the_drive_and_sensor_columns(tmp_path, capsys):
    out = tmp_path / "designed.csv"
    assert main(["design", "--arm", ROTFLEX_FILE, "--duration", "1", "--max-torque", "4",
                 "--max-angle", "1.5", "--max-speed", "20", "--harmonics", "3",
                 "--iterations", "1", "--out", str(out)]) == 0
    record = load_record(out)
    assert set(record.columns) == {"time", "voltage", "joint_angle", "deflection_angle"}
    assert np.max(np.abs(record.channel("voltage"))) <= 4.0 * (1 + 1e-9)
    assert record.dt == pytest.approx(ROTFLEX.testbed.dt)
    assert "predicted" in record.metadata["note"]
    assert out.read_text().splitlines()[0] == (
        "# units = time s, joint_angle rad, voltage V, deflection_angle rad")


def test_two_link_records_are_refused(tmp_path, reference_log, capsys):
    logged = load_record(reference_log)
    source = "github.com/basta/quanser-2-dof-serial-flexible-link @ 48ab0ce (MIT)"
    path = tmp_path / "two_link.csv"
    save_record(Record(time=logged.time, torque=logged.torque, joint_angle=logged.joint_angle,
                       name="two_link", metadata={"source": source}), path)
    for command in (["identify", str(path), "--out", str(tmp_path / "f.json")],
                    ["discover", str(path)]):
        assert main(command) == 2
        err = capsys.readouterr().err
        assert "Quanser 2-DOF serial flexible link, a two-link arm" in err
        assert len(err.strip().splitlines()) == 1


@pytest.mark.slow  # compiles the search and the refinement
def test_identify_names_a_strain_gauge_calibrated_wrong(tmp_path):
    """The rig's gauge reads 1.25 times what the arm file says: identify with the arm and
    --effect sensor_gain:deflection_angle gives gain_deflection_angle = 1.25 (motion parameters
    held at their truth)."""
    true_arm = tmp_path / "true.toml"
    true_arm.write_text(ARMS.joinpath("quanser_rotflex.toml").read_text().replace(
        'calibration = "deflection_angle"', 'calibration = "deflection_angle"\ngain = 1.25'))
    log, fit = tmp_path / "log.csv", tmp_path / "fit.json"
    assert main(["simulate", "--arm", str(true_arm), "--input", "triangular", "--duration", "1",
                 "--rest", "0.1", "--out", str(log)]) == 0
    fixed = [f"--fix={k}={float(v)!r}" for k, v in ROTFLEX.space.reference().items()]
    assert main(["identify", str(log), "--arm", ROTFLEX_FILE, "--effect",
                 "sensor_gain:deflection_angle", *fixed, "--generations", "2", "--population",
                 "8", "--quiet", "--out", str(fit)]) == 0
    gain = json.loads(fit.read_text())["params"]["gain_deflection_angle"]
    assert gain == pytest.approx(1.25, rel=1e-6)
