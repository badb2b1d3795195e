"""`jaxflex simulate`: the record it writes is the simulator's output; bad input is named."""

import os
import subprocess
import sys

import numpy as np
import pytest

from jaxflex.cli import main
from jaxflex.data import load_record
from jaxflex.effects import get_effect
from jaxflex.model import Model
from jaxflex.signals import reference_input
from jaxflex.simulation import simulate


def test_writes_the_simulated_record_and_refuses_to_overwrite(tmp_path, capsys):
    out = tmp_path / "pulse.csv"
    argv = ["simulate", "--input", "pulse", "--duration", "0.5", "--effect", "payload",
            "--set", "m_p=0.03", "--set", "E=6e10", "--out", str(out)]
    assert main(argv) == 0
    assert "wrote" in capsys.readouterr().out
    record = load_record(out)
    model = Model(effects=(get_effect("payload"),))
    params = {**{k: float(v) for k, v in model.space.reference().items()}, "m_p": 0.03, "E": 6e10}
    _, torque = reference_input("pulse", duration=0.5)
    want = simulate(model, params, torque)
    np.testing.assert_array_equal(record.torque, torque)
    for name in ("joint_angle", "tip_acceleration", "joint_velocity", "tip_deflection"):
        np.testing.assert_allclose(
            record.channel(name), np.asarray(want.channel(name)), rtol=1e-12, atol=1e-15
        )
    assert record.metadata["effects"] == "payload" and record.metadata["noise"] == "none"
    # an existing file is refused, and left as it was
    before = out.read_bytes()
    assert main(argv) == 2
    assert "file exists" in capsys.readouterr().err
    assert out.read_bytes() == before


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["--set", "E_mod=1"], "unknown name(s) ['E_mod']"),
        (["--set", "E"], "--set expects NAME=VALUE, got 'E'"),
        (["--set", "E=abc"], "--set E: 'abc' is not a number"),
        (["--dt", "0"], "argument --dt: 0 must be a finite number > 0"),
        (["--duration", "0.001"], "shorter than two samples"),
    ],
)
def test_bad_input_is_named(tmp_path, capsys, extra, message):
    out = tmp_path / "x.csv"
    assert main(["simulate", "--input", "pulse", "--out", str(out), *extra]) == 2
    assert message in capsys.readouterr().err
    assert not out.exists()



def _without_jax_cache(tmp_path, cache_dir: str | None) -> dict[str, str]:
    """This process's environment without JAX's cache setting, with a fresh home folder and
    ``JAXFLEX_CACHE_DIR`` set to ``cache_dir`` (None: unset)."""
    env = {k: v for k, v in os.environ.items() if k not in NO_CACHE_SETTINGS}
    env["HOME"] = str(tmp_path / "home")
    if cache_dir is not None:
        env["JAXFLEX_CACHE_DIR"] = cache_dir
    return env


NO_CACHE_SETTINGS = ("JAX_COMPILATION_CACHE_DIR", "JAXFLEX_CACHE_DIR", "XDG_CACHE_HOME")


def test_the_command_keeps_its_compiled_programs_between_runs(tmp_path):
    """A run fills the cache folder with the programs it compiled, the next finds them there
    and writes the same record; an empty JAXFLEX_CACHE_DIR keeps nothing; by default the
    cache is ~/.cache/jaxflex."""
    cache = tmp_path / "cache"
    env = _without_jax_cache(tmp_path, str(cache))
    for name in ("a.csv", "b.csv"):
        run = subprocess.run(
            [sys.executable, "-m", "jaxflex", "simulate", "--input", "pulse", "--duration",
             "0.3", "--out", str(tmp_path / name)],
            env=env, capture_output=True, text=True, timeout=300,
        )
        assert run.returncode == 0, run.stderr
        if name == "a.csv":
            kept = sorted(p.name for p in cache.iterdir())
            assert kept  # at least the simulator's program (it compiles for over a second)
    assert sorted(p.name for p in cache.iterdir()) == kept  # found, not compiled again
    assert (tmp_path / "a.csv").read_bytes() == (tmp_path / "b.csv").read_bytes()
    probe = (
        "import jax; from jaxflex.cli import use_persistent_cache; use_persistent_cache(); "
        "print(jax.config.jax_compilation_cache_dir)"
    )
    default = str(tmp_path / "home" / ".cache" / "jaxflex")
    for setting, expected in (("", "None"), (None, default), ("/elsewhere", "/elsewhere")):
        run = subprocess.run(
            [sys.executable, "-c", probe], env=_without_jax_cache(tmp_path, setting),
            capture_output=True, text=True, timeout=120,
        )
        assert run.stdout.strip() == expected, run.stderr
