"""The installed package, not the checkout: a wheel built from the repository, installed into a
fresh virtual environment, runs the README's real-data commands from a folder outside the
checkout, with the rig named by ``--arm quanser_rotflex`` (its arm file ships in the wheel).

The fresh environment sees this environment's dependencies (jax, ...) through a ``.pth`` line
naming their site-packages, written after the wheel is installed (so that pip never weighs the
development install); a ``.pth`` line adds the folder only, so the development install's own
``.pth`` finder, which would import the checkout, is not run there. The wheel is built by pip
from a copy of what a source distribution holds (the checkout's ``build/`` is never touched);
pip fetches the build backend that ``pyproject.toml`` names from its configured index, as
``make`` does for the development install.
"""

import json
import math
import os
import shutil
import site
import subprocess
import sys
import sysconfig
from pathlib import Path

import pytest
from helpers import REAL_DATA_DIR

ROOT = Path(__file__).resolve().parents[1]
SHARED_REAL_DATA = ROOT.parent / "shared" / "realdata"  # the Makefile's REALDATA
DISTRIBUTED = ("pyproject.toml", "README.md", "LICENSE", "jaxflex")  # what pip builds from
TINY = ["--generations", "2", "--population", "8", "--no-refine", "--quiet"]


def _real_data() -> Path:
    """The local copy of the public records: ``JAXFLEX_DATA_DIR``, else the Makefile's folder
    beside the project; the test skips without one (it never downloads)."""
    folder = Path(REAL_DATA_DIR) if REAL_DATA_DIR else SHARED_REAL_DATA
    if not (folder / "quanser_rotflex").is_dir():
        pytest.skip(f"real-rig data: no local copy in {folder} (set JAXFLEX_DATA_DIR, or put "
                    "it in ../shared/realdata as the Makefile does)")
    return folder


def _run(command: list, cwd: Path, env: dict) -> str:
    """Run ``command``; its stdout, or a failure showing what it printed."""
    done = subprocess.run(command, cwd=cwd, env=env, capture_output=True, text=True,
                          timeout=300)
    assert done.returncode == 0, f"{command}: exit {done.returncode}\n{done.stdout}{done.stderr}"
    return done.stdout


def _fresh_venv(tmp: Path) -> tuple[Path, Path]:
    """A new virtual environment with only the wheel built from this checkout in it, then this
    environment's site-packages after it; its (python, site-packages)."""
    source = tmp / "source"
    for name in DISTRIBUTED:
        original = ROOT / name
        if original.is_dir():
            shutil.copytree(original, source / name,
                            ignore=shutil.ignore_patterns("__pycache__", "*.pyc"))
        else:
            source.mkdir(exist_ok=True)
            shutil.copy2(original, source / name)
    pip = [sys.executable, "-m", "pip", "--disable-pip-version-check", "--quiet"]
    _run([*pip, "wheel", "--no-deps", "--wheel-dir", str(tmp / "dist"), str(source)], tmp,
         os.environ)
    (wheel,) = (tmp / "dist").glob("jaxflex-*.whl")
    venv = tmp / "venv"
    _run([sys.executable, "-m", "venv", "--without-pip", str(venv)], tmp, os.environ)
    python = venv / "bin" / "python"
    _run([*pip, "--python", str(python), "install", "--no-deps", "--no-index", str(wheel)],
         tmp, os.environ)
    packages = Path(_run([str(python), "-c", "import sysconfig; print(sysconfig.get_path("
                                             "'purelib'))"], tmp, os.environ).strip())
    ours = [sysconfig.get_path("purelib"), *site.getsitepackages()]
    (packages / "dependencies.pth").write_text("\n".join(dict.fromkeys(ours)) + "\n")
    return python, packages


def test_the_wheel_installs_and_runs_the_real_data_commands_outside_the_checkout(tmp_path):
    data = _real_data()
    python, packages = _fresh_venv(tmp_path)
    work = tmp_path / "elsewhere"
    work.mkdir()
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "PYTHONHOME")}
    env |= {"JAXFLEX_DATA_DIR": str(data), "JAXFLEX_PROGRESS": "0", "JAXFLEX_HOST_DEVICES": "1"}
    where = _run([str(python), "-c", "import jaxflex, jaxflex.rigs as r; "
                  "print(jaxflex.__file__); print(r.arm_path('reference'))"], work, env)
    module, rig = (Path(line) for line in where.splitlines())
    assert module == packages / "jaxflex" / "__init__.py"  # the wheel's, not the checkout's
    assert rig == packages / "jaxflex" / "rigs" / "reference.toml"
    jaxflex = [str(python.parent / "jaxflex")]  # the wheel's console script
    listed = _run([*jaxflex, "arms", "list"], work, env).splitlines()
    assert [line.split(":")[0] for line in listed] == [
        "daisy_robot_arm", "quanser_rotflex", "reference"
    ]
    shown = _run([*jaxflex, "arms", "show", "quanser_rotflex"], work, env)
    assert shown == (ROOT / "jaxflex" / "rigs" / "quanser_rotflex.toml").read_text()
    written = _run([*jaxflex, "datasets", "get", "quanser_rotflex", "--out", "rotflex"], work,
                   env).split()
    assert sorted(Path(p).name for p in written) == ["random_985.csv", "square_wave.csv"]
    _run([*jaxflex, "identify", "rotflex/square_wave.csv", "--arm", "quanser_rotflex", *TINY,
          "--out", "fit.json"], work, env)
    assert json.loads((work / "fit.json").read_text())["settings"]["arm"] == "quanser_rotflex"
    _run([*jaxflex, "validate", "rotflex/square_wave.csv", "rotflex/random_985.csv", "--fit",
          "fit.json", "--json", "table.json", "--report", "report"], work, env)
    table = json.loads((work / "table.json").read_text())
    assert table["rig"] == "quanser_rotflex"  # the rig the fit carries
    figures = sorted(p.name for p in (work / "report").glob("*.png"))
    assert figures == ["frf.png", "random_985_time.png", "square_wave_time.png"]
    rows = table["records"]
    assert [(r["name"], r["role"]) for r in rows] == [
        ("square_wave", "fit"), ("random_985", "held-out")
    ]
    for row in rows:
        assert set(row["nrmse"]) == {"joint_angle", "deflection_angle"}
        assert all(math.isfinite(v) and v > 0 for v in row["nrmse"].values()), row
    _an_invented_rig_end_to_end(jaxflex, work, env)
    _a_users_strip_with_default_options(jaxflex, work, env)


RULER = """\
# A 0.3 m steel ruler on a hobby servo's hub, driven by PWM counts; an encoder on the hub and
# an accelerometer taped a little short of the tip.
name = "ruler"
description = "0.3 m steel ruler, PWM-driven hub, encoder and accelerometer at 0.25 m"

[link]
length = 0.3
width = 0.025
thickness = 0.0008
density = 7850.0

[simulation]
n_elements = 6

[sampling]
dt = 0.002
duration = 1.2

[parameters]
E = { reference = 2.0e11, lower = 1.0e11, upper = 3.0e11 }
J_h = { reference = 0.0004, lower = 1e-4, upper = 2e-3 }
b_v = { reference = 0.002, lower = 1e-4, upper = 0.02 }
tau_c = { reference = 0.002, fixed = true }
alpha = { reference = 0.5, fixed = true }
beta = { reference = 1e-4, fixed = true }

[drive]
type = "command"
unit = "counts"
torque_per_unit = { reference = 0.0002, lower = 5e-5, upper = 1e-3 }
saturation = 255

[[sensors]]
type = "encoder"
channel = "angle"
counts_per_revolution = 2000

[[sensors]]
type = "accelerometer"
channel = "acc"
x = 0.25
noise = 0.05
"""


def _an_invented_rig_end_to_end(jaxflex: list[str], work: Path, env: dict) -> None:
    """A rig written as a user would (other geometry, a PWM drive whose gain is identified,
    a sensor part-way along the link): simulate its log, identify with figures, validate with
    a report, from the installed wheel."""
    (work / "ruler.toml").write_text(RULER)
    _run([*jaxflex, "simulate", "--arm", "ruler.toml", "--input", "pulse", "--amplitude", "200",
          "--rest", "0.2", "--add-noise", "--seed", "2", "--out", "ruler_log.csv"], work, env)
    _run([*jaxflex, "identify", "ruler_log.csv", "--arm", "ruler.toml", "--window", "auto",
          "--generations", "4", "--population", "12", "--quiet", "--out", "ruler_fit.json",
          "--plot", "ruler_fit.png"], work, env)
    fit = json.loads((work / "ruler_fit.json").read_text())
    assert fit["names"] == ["E", "J_h", "b_v", "torque_per_unit"]
    assert fit["settings"]["channels"] == ["angle", "acc"]
    assert fit["model_description"]["drive"]["unit"] == "counts"
    _run([*jaxflex, "validate", "ruler_log.csv", "--fit", "ruler_fit.json", "--report",
          "ruler_report"], work, env)
    assert (work / "ruler_fit_ruler_log.png").is_file()
    figures = sorted(p.name for p in (work / "ruler_report").glob("*.png"))
    assert figures == ["frf.png", "ruler_log_time.png"]
    channels = json.loads((work / "ruler_report" / "comparison.json").read_text())["channels"]
    assert channels == {"angle": "rad", "acc": "m/s^2"}


STRIP = """\
# An aluminium strip on a DC motor behind a voltage amplifier: a 2048-count encoder on the hub,
# a strain gauge near the clamp and an accelerometer short of the tip.
name = "alu_strip"
description = "0.5 m aluminium strip, voltage-driven hub, strain gauge and accelerometer"

[link]
length = 0.5
width = 0.03
thickness = 0.002
density = 2700.0

[simulation]
n_elements = 6

[sampling]
dt = 0.002
duration = 2.0

[parameters]
E = { reference = 7.0e10, lower = 4.0e10, upper = 1.0e11 }
J_h = { reference = 0.003, lower = 5e-4, upper = 2e-2 }
b_v = { reference = 0.01, lower = 1e-4, upper = 0.1 }
tau_c = { reference = 0.02, lower = 1e-3, upper = 0.1 }
alpha = { reference = 0.5, fixed = true }
beta = { reference = 1e-4, fixed = true }

[drive]
type = "voltage"
resistance = 2.0
torque_constant = 0.02
back_emf_constant = 0.02
gear_ratio = 20.0
gearbox_efficiency = 0.9
motor_efficiency = 0.8

[[sensors]]
type = "encoder"
channel = "hub"
counts_per_revolution = 2048

[[sensors]]
type = "strain_gauge"
channel = "gauge"
x = 0.05
noise = 2e-6

[[sensors]]
type = "accelerometer"
channel = "acc"
x = 0.4
noise = 0.05
"""


def _a_users_strip_with_default_options(jaxflex: list[str], work: Path, env: dict) -> None:
    """A newcomer's rig on the default options of each command, which are what a first hour
    runs: what ``simulate`` writes (its default rest, its default input amplitude), ``identify``
    reads without a window or a rest option, ``validate`` compares, and ``discover`` finds
    nothing to add to the right model. Only the search budgets are cut, to the test's time."""
    (work / "strip.toml").write_text(STRIP)
    for name, seed in (("chirp", 1), ("multisine", 2)):
        printed = _run([*jaxflex, "simulate", "--arm", "strip.toml", "--input", name,
                        "--add-noise", "--seed", str(seed), "--out", f"strip_{name}.csv"],
                       work, env)
        assert f"strip_{name}.csv" in printed
    _run([*jaxflex, "identify", "strip_chirp.csv", "--arm", "strip.toml", "--generations",
          "12", "--population", "16", "--quiet", "--out", "strip_fit.json", "--plot",
          "strip_fit.png"], work, env)
    fit = json.loads((work / "strip_fit.json").read_text())
    assert fit["names"] == ["E", "J_h", "b_v", "tau_c"]
    assert fit["settings"]["channels"] == ["hub", "gauge", "acc"]
    for name, true in (("E", 7.0e10), ("J_h", 0.003)):
        lo, hi = fit["intervals"][name]
        assert abs(fit["params"][name] / true - 1) < 0.05, (name, fit["params"][name])
        assert lo < fit["params"][name] < hi
    assert (work / "strip_fit_strip_chirp.png").is_file()
    _run([*jaxflex, "validate", "strip_chirp.csv", "strip_multisine.csv", "--fit",
          "strip_fit.json", "--json", "strip_table.json", "--report", "strip_report"], work, env)
    rows = json.loads((work / "strip_table.json").read_text())["records"]
    assert [(r["name"], r["role"]) for r in rows] == [("strip_chirp", "fit"),
                                                       ("strip_multisine", "held-out")]
    # the right model misses by the sensor noise alone: each NRMSE sits at its noise floor
    report = json.loads((work / "strip_report" / "comparison.json").read_text())["records"]
    for row in report:
        floors = row["noise_floor_percent"]
        assert all(0 < v < 1.25 * floors[c] + 1.0 for c, v in row["nrmse_percent"].items()), row
    _run([*jaxflex, "discover", "strip_chirp.csv", "--holdout", "strip_multisine.csv",
          "--arm", "strip.toml", "--initial", "strip_fit.json", "--quiet", "--json",
          "strip_discover.json"], work, env)
    found = json.loads((work / "strip_discover.json").read_text())
    assert found["steps"][-1]["effects"] == [], [s["added"] for s in found["steps"]]
