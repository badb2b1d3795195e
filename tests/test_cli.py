"""The ``jaxflex`` command as a whole: it answers ``--help`` and ``--version`` without loading
JAX, and long commands show progress by one rule (a bar on a terminal, a line per stage in a
file, ``JAXFLEX_PROGRESS`` forcing either, ``--quiet`` silencing), and every warning is one
line naming the command, in jaxflex's words."""

from __future__ import annotations

import argparse
import importlib.metadata
import os
import subprocess
import sys
from pathlib import Path

import pytest
from helpers import EXAMPLE

import jaxflex
from jaxflex._progress import ENVIRONMENT_SWITCH
from jaxflex.cli import COMMANDS, build_parser, main

ROOT = Path(jaxflex.__file__).parents[1]
TINY_SEARCH = ["--generations", "2", "--population", "8", "--no-refine"]
WARNING = "jaxflex identify: warning: "
"""How the fit's warnings start (its poorly identified parameters, say)."""
HEAVY = ("jax", "jaxlib", "equinox", "optimistix", "scipy", "matplotlib")
"""What a computing command imports and ``--help`` must not."""


def test_help_and_version_load_no_jax():
    """Every parser is built and every ``--help`` printed without importing JAX and the
    libraries jaxflex computes with."""
    script = (
        "import contextlib, io, sys\n"
        "from jaxflex.cli import main\n"
        f"for argv in (['--help'], ['--version'],\n"
        f"             *([c.replace('_', '-'), '--help'] for c in {COMMANDS!r})):\n"
        "    with contextlib.redirect_stdout(io.StringIO()) as out:\n"
        "        assert main(argv) == 0 and out.getvalue(), argv\n"
        f"print(sorted(m for m in {HEAVY!r} if m in sys.modules))\n"
    )
    env = os.environ | {"PYTHONPATH": str(ROOT)}
    done = subprocess.run([sys.executable, "-c", script], env=env, capture_output=True,
                          text=True, check=False)
    assert (done.returncode, done.stderr) == (0, "")
    assert done.stdout == "[]\n"


def test_version_is_the_package_version(capsys):
    assert main(["--version"]) == 0
    assert capsys.readouterr().out == f"jaxflex {jaxflex.__version__}\n"
    assert jaxflex.__version__ == importlib.metadata.version("jaxflex")


def command_parser(name: str):
    """The parser of ``jaxflex NAME``."""
    return next(a for a in build_parser()._actions if a.dest == "command").choices[name]


def test_validate_help_states_the_default_window():
    from jaxflex.comparison import DEFAULT_T_END

    help_text = " ".join(command_parser("validate").format_help().split())
    assert f"(default: {DEFAULT_T_END:g} s for records of the simulator's outputs" in help_text


def test_identify_into_a_file_writes_a_line_per_stage_and_no_bar(monkeypatch, tmp_path,
                                                                  warnings_shown):
    """Redirected to a log, the progress is one line per finished stage: no carriage returns
    of a bar's updates."""
    monkeypatch.delenv(ENVIRONMENT_SWITCH, raising=False)
    log = tmp_path / "log.txt"
    with log.open("w") as stream:
        monkeypatch.setattr(sys, "stderr", stream)
        status = main(["identify", str(EXAMPLE), *TINY_SEARCH, "--out", str(tmp_path / "f.json")])
    text = log.read_text()
    assert status == 0 and "\r" not in text
    lines = [line for line in text.splitlines() if not line.startswith(WARNING)]
    assert [line.split(":")[0] for line in lines] == ["DE", "intervals"]
    assert lines[0].startswith("DE: 2/2 in ") and ", best " in lines[0]


def test_quiet_silences_the_progress(monkeypatch, tmp_path, capsys, warnings_shown):
    monkeypatch.setenv(ENVIRONMENT_SWITCH, "1")
    status = main(["identify", str(EXAMPLE), *TINY_SEARCH, "--quiet",
                   "--out", str(tmp_path / "f.json")])
    err = capsys.readouterr().err
    assert status == 0 and err and all(line.startswith(WARNING) for line in err.splitlines())


@pytest.mark.parametrize("command", ["identify", "study", "discover", "design", "validate"])
def test_every_long_command_takes_quiet(command):
    """One option, one rule: each long command has ``--quiet`` and no other progress switch."""
    options = {o for a in command_parser(command)._actions for o in a.option_strings
               if a.help != argparse.SUPPRESS}
    assert "--quiet" in options and "--progress" not in options


@pytest.fixture
def warnings_shown(monkeypatch):
    """Warnings displayed on stderr as Python displays them outside a test runner (through
    ``warnings.formatwarning``), not recorded by pytest."""
    import warnings

    def show(message, category, filename, lineno, file=None, line=None):
        sys.stderr.write(warnings.formatwarning(message, category, filename, lineno, line))

    monkeypatch.setattr(warnings, "showwarning", show)


def test_every_warning_is_one_line_naming_the_command(monkeypatch, capsys, warnings_shown):
    """jaxflex's warnings, NumPy's and optimistix's: one line each, ``jaxflex COMMAND:
    warning: …``, every run; optimistix's words about root-finds said as what they mean for a
    fit."""
    import warnings

    import numpy as np
    import optimistix as optx

    from jaxflex.cli import datasets
    from jaxflex.data import RecordWarning

    def warns(args):
        warnings.warn("record a.csv:\n  time column is not uniform", RecordWarning, stacklevel=1)
        np.log(np.zeros(1))
        raw = optx.RESULTS[optx.RESULTS.nonlinear_max_steps_reached]
        warnings.warn(f"refinement: {raw}", stacklevel=1)
        return 0

    monkeypatch.setattr(datasets, "run_list", warns)
    for _ in range(2):
        assert main(["datasets", "list"]) == 0
        assert capsys.readouterr().err.splitlines() == [
            "jaxflex datasets: warning: record a.csv: time column is not uniform",
            "jaxflex datasets: warning: divide by zero encountered in log",
            "jaxflex datasets: warning: refinement: Levenberg–Marquardt took all its steps "
            "without meeting its tolerances: the estimate is the best point it reached, not a "
            "proven least-squares optimum, and intervals computed there are only indicative; a "
            "better start (more generations, or --refine-starts above 1) may let it converge",
        ]


def test_a_refinement_out_of_steps_warns_in_the_words_of_a_fit(monkeypatch, tmp_path, capsys,
                                                                warnings_shown):
    """The solver that runs out of steps (optimistix: 'a root-find on a function that has no
    roots') is one warning line saying what it means for the fit; the table stays on stdout."""
    import functools

    from jaxflex import identification
    from jaxflex.refine import LevenbergMarquardt

    monkeypatch.setattr(identification, "LevenbergMarquardt",
                        functools.partial(LevenbergMarquardt, max_steps=1))
    status = main(["identify", str(EXAMPLE), *TINY_SEARCH[:4], "--quiet",
                   "--out", str(tmp_path / "f.json")])
    out, err = capsys.readouterr()
    assert status == 0 and "refinement: nonlinear_max_steps_reached, 1 steps" in out
    assert "warning" not in out and "root-find" not in err + out
    warnings = [line for line in err.splitlines() if "refinement" in line]
    assert warnings == [
        "jaxflex identify: warning: refinement stopped early (nonlinear_max_steps_reached): "
        "Levenberg–Marquardt took all its steps without meeting its tolerances: the estimate is "
        "the best point it reached, not a proven least-squares optimum, and intervals computed "
        "there are only indicative; a better start (more generations, or --refine-starts above "
        "1) may let it converge"
    ]
    assert all(line.startswith(WARNING) for line in err.splitlines())


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["simulate", "--input", "pulse", "--effects", "payload", "--out", "x.csv"],
         "--effects is now --effect NAME (repeatable)"),
        (["simulate", "--input", "pulse", "--noise", "--out", "x.csv"],
         "--noise is now --add-noise"),
        (["discover", "x.csv", "--effects", "payload"], "--effects is now --candidates"),
        (["discover", "x.csv", "--progress"], "--progress is now the default"),
    ],
)
def test_an_option_that_was_renamed_names_its_new_name(argv, message, capsys):
    """One name, one meaning: ``--effect`` adds to the model, ``--noise`` gives noise levels,
    ``--candidates`` lists discover's candidates; an old spelling fails in one line."""
    assert main(argv) == 2
    assert message in capsys.readouterr().err.splitlines()[-1]
