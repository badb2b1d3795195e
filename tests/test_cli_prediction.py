"""``validate --horizon`` and ``identify --criterion``: prediction beside simulation, and one
line per mistake."""

from __future__ import annotations

import json

import pytest
from test_cli_validate import write_fit
from test_kalman import _record

from jaxflex.cli import main
from jaxflex.data import save_record
from jaxflex.model import Model
from jaxflex.testbed import Testbed


@pytest.fixture(scope="module")
def drifting(tmp_path_factory):
    """A record of a small arm under a white torque disturbance (it drifts from any free
    simulation) and a fit file at the true parameters."""
    root = tmp_path_factory.mktemp("prediction")
    model = Model(testbed=Testbed(n_elements=2))
    params = {k: float(v) for k, v in model.space.reference().items()}
    record = _record(model, params, 600, 0.1, seed=6)
    return {"record": save_record(record, root / "drift.csv"), "root": root,
            "fit": write_fit(root / "fit.json", params, ("drift",), model)}


def test_validate_predicts_beside_the_simulation(drifting, capsys):
    out, report = drifting["root"] / "table.json", drifting["root"] / "report"
    assert main(["validate", str(drifting["record"]), "--fit", str(drifting["fit"]),
                 "--horizon", "0.01", "--horizon", "0.1", "--json", str(out), "--quiet",
                 "--report", str(report)]) == 0
    assert (report / "drift_prediction.png").stat().st_size > 0
    assert json.loads((report / "prediction.json").read_text())["records"][0]["name"] == "drift"
    assert "NRMSE (%) of the simulation and of the k-step-ahead predictions" in (
        capsys.readouterr().out)
    [row] = json.loads(out.read_text())["prediction"]
    scores = row["nrmse_percent"]
    assert set(scores) == {"simulation", "one_step", "0.01 s", "0.1 s"}
    angle = {k: v["joint_angle"] for k, v in scores.items()}
    # the drift dominates the simulation; the filter foresees 10 ms far better than 100 ms
    assert angle["one_step"] < angle["0.01 s"] < angle["0.1 s"] < angle["simulation"]


@pytest.mark.parametrize(("option", "message"), [
    (["--horizon", "0"], "argument --horizon: 0 must be a finite number > 0"),
    (["--horizon", "-1"], "argument --horizon: -1 must be a finite number > 0"),
    (["--horizon", "0.7"], "--horizon 0.7 s is longer than record 'drift' (0.6 s)"),
    (["--horizon", "1e-5"], "--horizon 1e-05 s is shorter than one sample"),
])
def test_validate_refuses_a_bad_horizon(drifting, capsys, option, message):
    assert main(["validate", str(drifting["record"]), "--fit", str(drifting["fit"]),
                 *option]) == 2
    assert message in capsys.readouterr().err.strip().splitlines()[-1]


def test_identify_refuses_an_unknown_criterion(drifting, capsys):
    assert main(["identify", str(drifting["record"]), "--out",
                 str(drifting["root"] / "x.json"), "--criterion", "innovations"]) == 2
    assert "invalid choice: 'innovations'" in capsys.readouterr().err.strip().splitlines()[-1]
