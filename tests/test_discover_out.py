"""``jaxflex discover --out FIT.json``: the final model as a fit file that ``validate --fit`` and
``discover --initial`` and ``identify --initial`` read, checked before any work like every
output."""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest
from discovery_cases import START, one
from scipy import stats

from jaxflex.cli import main
from jaxflex.data import save_record
from jaxflex.fit import load_fit


@pytest.fixture(scope="module")
def case(tmp_path_factory) -> tuple[str, Path]:
    """One short noisy record of the arm with a hidden tip payload, and the start parameters."""
    records, _, _ = one("payload", 0.03, inputs=("pulse",))
    folder = tmp_path_factory.mktemp("discover_out")
    csv = str(folder / f"{records[0].name}.csv")
    save_record(records[0], csv)
    start = folder / "start.json"
    start.write_text(json.dumps(START))
    return csv, start


def discover_args(csv: str, start: Path, *more: str) -> list[str]:
    """A one-step discovery of the payload from the given start (no search)."""
    return ["discover", csv, "--initial", str(start), "--candidates", "payload",
            "--max-steps", "1", "--quiet", *more]


def test_discover_writes_its_final_model_as_a_fit_file(case, tmp_path, capsys):
    """The fit file holds the final step's effects, parameters and intervals; ``validate``
    reproduces discover's NRMSE with it, and its cost is the weighted mean squared NRMSE of
    the whole record; ``discover --initial`` starts from it."""
    csv, start = case
    out, report = tmp_path / "fit.json", tmp_path / "discovery.json"
    assert main(discover_args(csv, start, "--out", str(out), "--json", str(report))) == 0
    said = capsys.readouterr().out
    assert f"wrote {out}\n" in said and f"wrote {report}\n" in said
    final = json.loads(report.read_text())["steps"][-1]
    assert final["structure"] == "base + payload"
    fit = load_fit(out)
    assert fit.effects == ("payload",) == tuple(final["effects"])
    assert fit.params.keys() == final["params"].keys()
    for name, value in final["params"].items():
        assert fit.params[name] == pytest.approx(value, rel=1e-12, abs=0)
    assert fit.params["m_p"] == pytest.approx(0.03, rel=0.1)  # the hidden payload, in kg
    assert set(fit.names) == set(final["intervals"]) == set(final["params"])  # none fixed
    z = stats.norm.ppf(0.975)
    for name, (lo, hi) in final["intervals"].items():
        assert fit.intervals[name] == pytest.approx((lo, hi), rel=1e-12)
        # the 95 % interval is the value ± 1.96 standard deviations of the covariance
        assert (hi - lo) / 2 == pytest.approx(z * fit.std[name], rel=1e-9)
        assert lo < fit.params[name] < hi
    assert fit.covariance.shape == (len(fit.names),) * 2
    assert fit.correlation.diagonal() == pytest.approx(1.0, rel=1e-12)
    assert fit.record_names == (Path(csv).stem,) and fit.seed == 0
    assert fit.settings["structure"] == "base + payload" and fit.settings["rig"]
    assert fit.provenance["versions"]["jaxflex"]
    summary = fit.summary()  # says what made it and how its intervals were computed
    assert summary.startswith("discover (base + payload) seed 0: cost ")
    assert "intervals: Gauss-Newton at the stated noise levels" in summary

    # validate --fit: the model discover ended with, the same NRMSE over the same span
    table = tmp_path / "validate.json"
    assert main(["validate", csv, "--fit", str(out), "--json", str(table), "--quiet"]) == 0
    nrmse = json.loads(table.read_text())["records"][0]["nrmse"]
    assert nrmse.keys() == final["nrmse"].keys()
    for channel, value in final["nrmse"].items():
        assert nrmse[channel] == pytest.approx(value, rel=1e-6)
    # the cost: the identification objective, Σ_c w_c/W · NRMSE_c² over the whole record
    whole = tmp_path / "whole.json"
    assert main(["validate", csv, "--fit", str(out), "--t-end", "1e9", "--json", str(whole),
                 "--quiet"]) == 0
    nrmse = json.loads(whole.read_text())["records"][0]["nrmse"]
    weights = fit.settings["weights"]
    expected = sum(w * (nrmse[c] / 100) ** 2 for c, w in weights.items()) / sum(weights.values())
    assert fit.cost == pytest.approx(expected, rel=1e-6)
    assert math.isnan(fit.cost_search)

    # discover --initial: a run from the fit starts with its effects and stays at its optimum
    again = tmp_path / "again.json"
    assert main(discover_args(csv, out, "--max-steps", "0", "--json", str(again))) == 0
    base = json.loads(again.read_text())["steps"][-1]
    assert base["effects"] == ["payload"]
    assert base["params"]["m_p"] == pytest.approx(fit.params["m_p"], rel=0.02)

    # identify --initial: the fit's rig and effects, its parameters seeding the search, whose
    # best is then no worse than the fit it started from
    seeded = tmp_path / "seeded.json"
    assert main(["identify", csv, "--initial", str(out), "--generations", "1", "--population",
                 "4", "--no-refine", "--quiet", "--out", str(seeded)]) == 0
    refit = load_fit(seeded)
    assert refit.effects == ("payload",) and refit.settings["seeded"] == 1
    assert refit.cost <= fit.cost * (1 + 1e-9)
    capsys.readouterr()


def test_discover_out_is_checked_before_any_work(case, tmp_path, capsys):
    """An existing ``--out`` without ``--overwrite``, one in a folder that is a file, one that
    is not JSON, the ``--json`` file or the start: refused in one line naming ``--out``, nothing
    computed or written."""
    csv, start = case
    existing = tmp_path / "fit.json"
    existing.write_text("{}")
    blocker = tmp_path / "file"
    blocker.write_text("")
    report = tmp_path / "discovery.json"
    for out, why, *more in ((existing, f"--out {existing}: file exists; pass --overwrite"),
                            (blocker / "fit.json", f"--out {blocker / 'fit.json'}: "),
                            (tmp_path / "fit.txt", ".json"),
                            (report, "--json writes the same file"),
                            (start, "is an input of this command", "--overwrite")):
        assert main(discover_args(csv, start, "--out", str(out), "--json", str(report),
                                  *more)) == 2
        said = capsys.readouterr()
        assert said.out == "" and why in said.err
        line, = said.err.strip().splitlines()
        assert "--out" in line
        assert not report.exists()
    assert existing.read_text() == "{}" and json.loads(start.read_text()) == START


def test_identify_initial_is_checked_before_any_work(case, tmp_path, capsys):
    """A missing fit file, or effects given beside one, refused in one line, nothing written."""
    csv, _ = case
    out = tmp_path / "fit.json"
    for more, why in ((["--initial", str(tmp_path / "none.json")],
                       f"--initial {tmp_path / 'none.json'}: fit file not found"),
                      (["--initial", str(out), "--effect", "payload"],
                       "--effect with --initial: the fit file fixes the model's effects")):
        assert main(["identify", csv, *more, "--quiet", "--out", str(out)]) == 2
        said = capsys.readouterr()
        line, = said.err.strip().splitlines()
        assert said.out == "" and line.startswith(f"jaxflex identify: error: {why}")
        assert not out.exists()
