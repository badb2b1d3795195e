"""`jaxflex simulate`: the record it writes is the simulator's output; bad input is named."""

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
    argv = ["simulate", "--input", "pulse", "--duration", "0.5", "--effects", "payload",
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
