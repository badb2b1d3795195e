"""Packaged rigs: arm files inside the package, named wherever an arm file can be given."""

import argparse
import os
import subprocess
import sys
import tomllib
from pathlib import Path
from types import SimpleNamespace

import pytest

import jaxflex
from jaxflex.arm import ArmError, load_arm
from jaxflex.cli import UsageError, main
from jaxflex.cli._arm import rig_of, rig_settings
from jaxflex.rigs import arm_path, is_arm_name, locate, packaged_arms

PACKAGE = Path(jaxflex.__file__).parent
KNOWN = "packaged arms: daisy_robot_arm, quanser_rotflex, reference"


def test_the_arm_files_are_package_data():
    assert packaged_arms() == ("daisy_robot_arm", "quanser_rotflex", "reference")
    for name in packaged_arms():
        path = arm_path(name)
        assert path == PACKAGE / "rigs" / f"{name}.toml" and path.is_file()
        assert tomllib.loads(path.read_text())["name"] == name  # each file is named as it ships
    assert not (PACKAGE.parent / "arms").exists()  # no second copy outside the package


def test_a_name_loads_the_same_arm_as_its_file():
    by_name = load_arm("quanser_rotflex")
    assert by_name == load_arm(arm_path("quanser_rotflex"))
    assert by_name.name == "quanser_rotflex" and by_name.testbed.length == 0.419


def test_unknown_names_are_one_line_listing_the_packaged_ones():
    with pytest.raises(ArmError) as info:
        load_arm("quanser_rotflx")
    assert str(info.value) == (
        "quanser_rotflx: neither an arm file nor a packaged arm (did you mean 'quanser_rotflex'?)"
        f"; {KNOWN}; a file's path needs a '/' or the suffix .toml"
    )
    with pytest.raises(ArmError) as info:
        arm_path("xyz")
    assert str(info.value) == f"xyz: no packaged arm of that name; {KNOWN}"


def test_a_path_is_a_path_and_a_packaged_name_is_the_packaged_rig(tmp_path, monkeypatch):
    """A file in the working folder named like a packaged rig does not take its place (a
    warning says how to read it); written as a path, or under another name, the file is read."""
    monkeypatch.chdir(tmp_path)
    for value in ("rigs/reference", "reference.toml", "Reference.TOML"):
        assert not is_arm_name(value) and locate(value) == Path(value)
        with pytest.raises(ArmError, match=rf"^{value}: arm file not found$"):
            load_arm(value)
    own = arm_path("reference").read_text().replace('name = "reference"', 'name = "mine"')
    Path("reference").write_text(own)  # a file in the working folder named like a packaged rig
    Path("bench").write_text(own)
    with pytest.warns(UserWarning, match=r"^reference: the packaged rig of that name, not the "
                                         r"file reference in this folder; write \./reference "
                                         r"to read the file$"):
        assert is_arm_name("reference") and load_arm("reference").name == "reference"
    assert load_arm("./reference").name == "mine"
    assert not is_arm_name("bench") and load_arm("bench").name == "mine"
    assert is_arm_name("quanser_rotflex") and load_arm("quanser_rotflex").name == "quanser_rotflex"


def test_the_command_line_says_which_rig_a_name_beside_a_file_means(tmp_path):
    own = arm_path("reference").read_text().replace('name = "reference"', 'name = "mine"')
    (tmp_path / "quanser_rotflex").write_text(own)
    env = os.environ | {"PYTHONPATH": str(PACKAGE.parent)}
    done = subprocess.run(
        [sys.executable, "-m", "jaxflex", "simulate", "--arm", "quanser_rotflex", "--input",
         "pulse", "--duration", "0.2", "--out", "s.csv"],
        cwd=tmp_path, env=env, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    assert done.stderr.splitlines() == [
        "jaxflex simulate: warning: quanser_rotflex: the packaged rig of that name, not the file "
        "quanser_rotflex in this folder; write ./quanser_rotflex to read the file"]
    lines = (tmp_path / "s.csv").read_text().splitlines()
    header = next(ln for ln in lines if not ln.startswith("#")).split(",")
    assert "# rig: quanser_rotflex" in lines and "voltage" in header  # the packaged rig's drive


def test_results_record_a_name_as_the_name_and_a_file_as_its_absolute_path(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    rig = load_arm("quanser_rotflex")
    run = SimpleNamespace(name="run")
    assert rig_settings(rig, "quanser_rotflex", [run], [None]) == {
        "rig": "quanser_rotflex", "arm": "quanser_rotflex", "windows": {"run": None}}
    Path("rig.toml").touch()
    settings = rig_settings(rig, "rig.toml", [run], [(0.0, 1.0)])
    assert settings["arm"] == str(tmp_path / "rig.toml")
    assert settings["windows"] == {"run": (0.0, 1.0)}


def test_a_fits_rig_matches_the_same_rig_given_by_name_or_by_file():
    fit = SimpleNamespace(model=load_arm("quanser_rotflex"))
    for given in ("quanser_rotflex", str(arm_path("quanser_rotflex")), None):
        rig, source = rig_of(argparse.Namespace(arm=given, window=None), fit)
        assert rig == load_arm("quanser_rotflex") and source == given
    with pytest.raises(UsageError, match=r"^--arm reference: the fit was made with another rig "
                                         r"\('quanser_rotflex'\), which it carries; leave --arm "
                                         r"out$"):
        rig_of(argparse.Namespace(arm="reference", window=None), fit)


def test_arms_list_and_show(capsys):
    assert main(["arms", "list"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert [line.split(":")[0] for line in lines] == list(packaged_arms())
    assert lines[1] == f"quanser_rotflex: {load_arm('quanser_rotflex').description}"
    assert main(["arms", "show", "reference"]) == 0
    assert capsys.readouterr().out == arm_path("reference").read_text()  # byte for byte
    assert main(["arms", "show", "referenc"]) == 2
    assert capsys.readouterr().err == (
        "jaxflex arms: error: referenc: no packaged arm of that name (did you mean "
        f"'reference'?); {KNOWN}\n"
    )


def test_an_unknown_arm_name_stops_a_command_before_any_work(tmp_path, capsys):
    out = tmp_path / "fit.json"
    record = str(PACKAGE / "data" / "example_pulse.csv")
    assert main(["identify", record, "--arm", "quanser_rotflx", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("jaxflex identify: error: quanser_rotflx: neither an arm file nor a "
                          "packaged arm (did you mean 'quanser_rotflex'?)")
    assert KNOWN in err and err.count("\n") == 1 and not out.exists()


def test_a_command_given_the_name_writes_what_it_writes_given_the_file(tmp_path):
    by_name, by_file = tmp_path / "name.csv", tmp_path / "file.csv"
    common = ["simulate", "--input", "pulse", "--duration", "0.2", "--add-noise", "--seed", "1"]
    assert main([*common, "--arm", "quanser_rotflex", "--out", str(by_name)]) == 0
    assert main([*common, "--arm", str(arm_path("quanser_rotflex")), "--out", str(by_file)]) == 0
    text = by_name.read_text()
    assert "time,joint_angle,voltage,deflection_angle\n" in text  # the rig's drive and sensors
    assert text == by_file.read_text()
