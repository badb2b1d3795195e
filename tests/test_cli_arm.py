"""``identify --arm`` and ``validate`` on a rig's records as logged (the CLI contract)."""

import json

from helpers import ARMS

from jaxflex.cli import main


def test_identify_with_an_arm_then_validate_every_record(rotflex_csv, tmp_path, capsys):
    fit, arm = tmp_path / "fit.json", tmp_path / "my_rig.toml"
    arm.write_text((ARMS / "quanser_rotflex.toml").read_text())
    args = ["identify", str(rotflex_csv / "square_wave.csv"), "--arm", str(arm),
            "--generations", "2", "--population", "8", "--no-refine", "--quiet",
            "--out", str(fit), "--plot", str(tmp_path / "fit.png")]
    assert main(args) == 0
    assert (tmp_path / "fit.png").is_file()  # convergence and intervals
    assert (tmp_path / "fit_square_wave.png").is_file()  # the record against the fit
    saved = json.loads(fit.read_text())
    assert saved["settings"]["arm"] == str(arm.resolve())
    assert saved["model_description"]["drive"]["type"] == "voltage"  # the rig, whole
    arm.write_text(arm.read_text().replace("7850.0", "2700.0"))  # edited, then gone:
    arm.unlink()  # the fit validates on the rig it carries, with figures
    table, report = tmp_path / "table.json", tmp_path / "report"
    data = [str(rotflex_csv / "square_wave.csv"), str(rotflex_csv / "random_985.csv")]
    assert main(["validate", *data, "--fit", str(fit), "--json", str(table),
                 "--report", str(report)]) == 0
    rows = json.loads(table.read_text())["records"]
    assert [(r["name"], r["role"]) for r in rows] == [
        ("square_wave", "fit"), ("random_985", "held-out")
    ]
    for row in rows:
        assert set(row["nrmse"]) == {"joint_angle", "deflection_angle"}
        assert all(value > 0 for value in row["nrmse"].values())
    figures = sorted(p.name for p in report.iterdir())
    assert figures == ["comparison.json", "frf.png", "random_985_time.png", "square_wave_time.png",
                       "table.txt"]
    compared = json.loads((report / "comparison.json").read_text())
    assert compared["channels"] == {"joint_angle": "rad", "deflection_angle": "rad"}
    capsys.readouterr()
    window = ["validate", data[1], "--fit", str(fit), "--window", "10:20"]
    assert main(window) == 2
    err = capsys.readouterr().err
    assert "does not start at rest at t = 10 s" in err and "(--window T0:T1)" in err
    assert err.rstrip().endswith("or fit where the record starts (--initial-state estimate, "
                                 "slower)")
    assert "rest tolerance" in err and err.count("\n") == 1
    assert main([*window[:-1], "20"]) == 2
    assert "--window 20: expected T0:T1, T0:, :T1 or auto" in capsys.readouterr().err
    # each record its own window: the square wave from its last rest, the random run's first 20 s
    table = tmp_path / "windows.json"
    assert main(["validate", *data, "--fit", str(fit), "--window", "square_wave=auto",
                 "--window", "random_985=0:20", "--json", str(table)]) == 0
    windows = json.loads(table.read_text())["windows"]
    assert windows["random_985"] == [0.0, 20.0]
    start, end = windows["square_wave"]
    assert 0.0 < start < 0.1 and end == 5.0  # rests until the first step at about 0.1 s


def test_arm_options_are_checked(rotflex_csv, tmp_path, capsys):
    data = str(rotflex_csv / "square_wave.csv")
    out = str(tmp_path / "fit.json")
    bad = tmp_path / "arm.toml"
    bad.write_text((ARMS / "quanser_rotflex.toml").read_text().replace("width =", "widht ="))
    assert main(["identify", data, "--arm", str(bad), "--out", out]) == 2
    assert f"{bad}: link.width: missing value" in capsys.readouterr().err
    reference = str(ARMS / "reference.toml")
    assert main(["identify", data, "--arm", reference, "--out", out]) == 2
    assert "logs 'voltage' but rig 'reference' has a torque drive" in capsys.readouterr().err
