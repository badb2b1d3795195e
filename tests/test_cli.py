"""The ``jaxflex`` command as a whole: it answers ``--help`` and ``--version`` without loading
JAX."""

from __future__ import annotations

import importlib.metadata
import os
import subprocess
import sys
from pathlib import Path

import jaxflex
from jaxflex.cli import COMMANDS, build_parser, main

ROOT = Path(jaxflex.__file__).parents[1]
HEAVY = ("jax", "jaxlib", "equinox", "optimistix", "scipy", "matplotlib")
"""What a computing command imports and ``--help`` must not."""


def test_help_and_version_load_no_jax():
    """Every parser is built and every ``--help`` printed without importing JAX and the
    libraries jaxflex computes with."""
    script = (
        "import contextlib, io, sys\n"
        "from jaxflex.cli import main\n"
        f"for argv in (['--help'], ['--version'], *([c, '--help'] for c in {COMMANDS!r})):\n"
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
    assert f"(default: {DEFAULT_T_END:g} s)" in help_text
