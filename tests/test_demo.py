"""The demo: its steps chain, it writes what it announces, and it never overwrites by surprise."""

from __future__ import annotations

import json
import os
import shlex
import subprocess
import sysconfig
from dataclasses import replace
from pathlib import Path

import pytest

from jaxflex._io import OutputExistsError
from jaxflex.cli import main
from jaxflex.data import load_dataset
from jaxflex.demo import STEPS, planned_files, run_demo
from jaxflex.model import Model
from jaxflex.parameters import reference_parameters


class _TrueFit:
    """A fit at the true parameters, standing in for the identification step."""

    params = {k: float(v) for k, v in reference_parameters().items()}
    record_names = ("triangular",)
    model = Model()


def _known_fit(state):
    return replace(state, fit=_TrueFit())


def _skip(state):
    """Stands in for the discovery step (tests/test_discover.py covers discovery)."""
    return state


FAST_STEPS = tuple(
    (name, {"identify": _known_fit, "discover": _skip}.get(name, step)) for name, step in STEPS
)


def test_steps_chain_and_write_every_planned_file(tmp_path):
    lines = []
    out = tmp_path / "demo"
    state = run_demo(out, seed=3, steps=FAST_STEPS, echo=lines.append)
    assert [name for name, _ in STEPS] == ["records", "identify", "validate", "report",
                                           "discover"]
    discovered = {p for p in planned_files(out) if p.parent == out / "discover"}
    assert discovered  # the discovery report is planned (and checked) up front
    assert set(state.files) == set(planned_files(out)) - {out / "fit.json"} - discovered
    assert all(p.is_file() for p in state.files)
    assert [ln for ln in lines if ln.startswith("== ")][:4] == [
        "== records",
        "== identify",
        "== validate",
        "== report",
    ]
    assert state.comparison.names == ("triangular", "pulse", "half_sine")
    assert [r.role for r in state.comparison.rows] == ["fit", "held-out", "held-out"]
    assert any("held-out" in ln for ln in lines)  # the table was printed
    # the saved records are the ones compared, and reload as a data set
    reloaded = load_dataset(out / "records")
    assert sorted(reloaded.names) == sorted(state.records.names)
    data = json.loads((out / "comparison.json").read_text())
    assert data["settings"]["noise"] == {"encoder_counts": 4096, "accel_sigma": 0.05}


def test_refuses_to_overwrite_before_doing_any_work(tmp_path):
    out = tmp_path / "demo"
    (out / "records").mkdir(parents=True)
    (out / "records" / "pulse.csv").write_text("mine\n")
    ran = []
    steps = (("records", lambda s: ran.append("records") or s),)
    with pytest.raises(OutputExistsError, match="pulse.csv"):
        run_demo(out, steps=steps, echo=lambda _: None)
    assert ran == [] and (out / "records" / "pulse.csv").read_text() == "mine\n"
    run_demo(out, steps=steps, overwrite=True, echo=lambda _: None)
    assert ran == ["records"]


def _hint(out) -> list[str]:
    """The closing hint of a demo with no steps, split as a shell would."""
    lines = []
    run_demo(out, steps=(), echo=lines.append)
    assert lines[-1].startswith("   try: ")
    return shlex.split(lines[-1].removeprefix("   try: "))


def test_the_closing_hint_runs_without_an_activated_environment(tmp_path, monkeypatch):
    """After ``make demo`` the environment's scripts are not on the PATH: the hint names this
    interpreter's ``jaxflex`` by its path, and the shell runs it as printed."""
    script = Path(sysconfig.get_path("scripts")) / "jaxflex"
    if not script.is_file():
        pytest.skip(f"{script}: jaxflex is not installed as a script beside this interpreter")
    monkeypatch.setenv("PATH", os.pathsep.join(["/usr/bin", "/bin"]))
    monkeypatch.chdir(script.parent.parent.parent)  # the folder holding the environment
    argv = _hint(tmp_path / "demo")
    assert argv[0] == os.path.join(script.parent.parent.name, script.parent.name, "jaxflex")
    assert argv[1:] == ["validate", f"{tmp_path}/demo/records", "--fit",
                        f"{tmp_path}/demo/fit.json"]
    assert os.access(argv[0], os.X_OK)
    shown = subprocess.run([argv[0], "validate", "--help"], capture_output=True, text=True,
                           check=True)
    assert shown.stdout.startswith("usage: jaxflex validate")
    # once the PATH finds that very script (an activated environment), its name is enough
    monkeypatch.setenv("PATH", str(script.parent))
    assert _hint(tmp_path / "demo")[0] == "jaxflex"


def test_cli_errors(tmp_path, capsys):
    target = tmp_path / "file"
    target.write_text("")
    assert main(["demo", "--out", str(target)]) == 2
    assert "not a directory" in capsys.readouterr().err
    assert main(["demo", "--out", str(tmp_path / "d"), "--seed", "-1"]) == 2
    assert "argument --seed: -1 must lie in [0, 4294967295]" in capsys.readouterr().err


@pytest.mark.slow
def test_full_demo_identifies_and_validates(tmp_path, capsys):
    out = tmp_path / "demo-output"
    assert main(["demo", "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "== done" in text and f"jaxflex validate {out}/records --fit {out}/fit.json" in text
    data = json.loads((out / "comparison.json").read_text())
    for row in data["records"]:
        for name, floor in row["noise_floor_percent"].items():
            if name in row["nrmse_percent"]:
                assert row["nrmse_percent"][name] <= 1.3 * floor, (row["name"], name)
    # the example arm's hidden payload is found, and the error falls to the noise
    found = json.loads((out / "discover" / "discover.json").read_text())
    assert [s["added"] for s in found["steps"]][-1] == "payload"
    assert found["unexplained"] is None
    # the written fit validates the written records through the command line
    assert main(["validate", str(out / "records"), "--fit", str(out / "fit.json")]) == 0
