"""``jaxflex validate`` in-process: the table, the report, and one clear line per user mistake."""

from __future__ import annotations

import json

import numpy as np
import pytest

from jaxflex.cli import main
from jaxflex.data import RecordWarning, save_record
from jaxflex.identification import Fit, History
from jaxflex.model import Model
from jaxflex.parameters import reference_parameters
from jaxflex.synthetic import make_records

NOISE_ARGS = ["--encoder-counts", "4096", "--accel-sigma", "0.05"]


def write_fit(path, params=None, record_names=("triangular",), model=None):
    """A fit file as `jaxflex identify` writes it, with the given parameter values."""
    model = Model() if model is None else model
    params = {k: float(v) for k, v in (params or reference_parameters()).items()}
    fit = Fit(
        params=params,
        names=tuple(params),
        fixed={},
        model=model,
        cost=0.0,
        cost_search=0.0,
        intervals={},
        std={},
        covariance=np.zeros((0, 0)),
        correlation=np.zeros((0, 0)),
        noise={},
        poorly_identifiable=(),
        warnings=(),
        history=History(np.zeros(1), np.zeros(1), {k: np.array([v]) for k, v in params.items()}),
        refinement=None,
        method="de",
        seed=0,
        settings={},
        timing={},
        record_names=tuple(record_names),
    )
    return fit.to_json(path)


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    """Three noisy reference records as CSV files and a fit file at the true parameters."""
    root = tmp_path_factory.mktemp("validate")
    paths = [save_record(r, root / "data" / f"{r.name}.csv") for r in make_records(seed=2)]
    return {"records": paths, "dir": root / "data", "fit": write_fit(root / "fit.json")}


def validate(*args):
    return main(["validate", *map(str, args)])


def test_prints_the_table_and_writes_the_report(files, tmp_path, capsys):
    report = tmp_path / "report"
    rc = validate(*files["records"], "--fit", files["fit"], "--report", report, *NOISE_ARGS)
    out = capsys.readouterr().out
    assert rc == 0
    rows = {
        ln.split()[0]: ln.split()[1]
        for ln in out.splitlines()
        if ln.split() and ln.split()[0] in ("triangular", "pulse", "half_sine")
    }
    assert rows == {"triangular": "fit", "pulse": "held-out", "half_sine": "held-out"}
    assert ["channel", "NRMSE", "%", "rel.err", "floor", "%"] == out.split("\n")[0].split()[2:]
    assert "floor FRF %" in out
    assert f"wrote 6 files to {report}" in out
    names = sorted(p.name for p in report.iterdir())
    assert names == sorted(
        [
            "table.txt",
            "comparison.json",
            "frf.png",
            "triangular_time.png",
            "pulse_time.png",
            "half_sine_time.png",
        ]
    )
    data = json.loads((report / "comparison.json").read_text())
    for row in data["records"]:  # the fit file holds the true parameters: noise-limited errors
        for out_name, floor in row["noise_floor_percent"].items():
            if out_name in row["nrmse_percent"]:
                assert row["nrmse_percent"][out_name] <= 1.3 * floor

    # a second run refuses to overwrite, naming the file and the flag
    rc = validate(*files["records"], "--fit", files["fit"], "--report", report)
    err = capsys.readouterr().err
    assert rc == 2 and "file exists" in err and "--overwrite" in err
    assert (
        validate(
            *files["records"],
            "--fit",
            files["fit"],
            "--report",
            report,
            "--overwrite",
            "--format",
            "pdf",
        )
        == 0
    )
    assert (report / "frf.pdf").read_bytes()[:5] == b"%PDF-"


def test_directory_of_records_and_raw_frf(files, capsys):
    assert validate(files["dir"], "--fit", files["fit"], "--raw-frf", "--f-max", "12") == 0
    out = capsys.readouterr().out
    assert "every bin" in out and "0 < f <= 12 Hz" in out
    assert "24/24" in out  # all bins of (0, 12] Hz compared


def test_missing_fit_file(files, tmp_path, capsys):
    assert validate(files["records"][0], "--fit", tmp_path / "nope.json") == 2
    err = capsys.readouterr().err
    assert err.startswith("jaxflex validate: error: ")
    assert "nope.json: fit file not found" in err and "jaxflex identify" in err


def test_fit_with_unknown_effect_or_parameter(files, tmp_path, capsys):
    data = json.loads(files["fit"].read_text())
    data["model_description"]["effects"] = [{"name": "warp_drive", "settings": {}}]
    bad_effect = tmp_path / "effect.json"
    bad_effect.write_text(json.dumps(data))
    assert validate(files["records"][0], "--fit", bad_effect) == 2
    err = capsys.readouterr().err
    assert "effect.json" in err and "unknown effect 'warp_drive'" in err

    data = json.loads(files["fit"].read_text())
    data["params"]["flux"] = 1.0
    bad_param = tmp_path / "param.json"
    bad_param.write_text(json.dumps(data))
    assert validate(files["records"][0], "--fit", bad_param) == 2
    err = capsys.readouterr().err
    assert "param.json" in err and "unknown parameter(s) ['flux']" in err

    not_json = tmp_path / "fit.json"
    not_json.write_text("time,torque\n")
    assert validate(files["records"][0], "--fit", not_json) == 2
    assert "not valid JSON" in capsys.readouterr().err


def test_record_with_a_missing_column(files, tmp_path, capsys):
    text = files["records"][0].read_text().replace("tip_acceleration", "tip_accel")
    bad = tmp_path / "bad.csv"
    bad.write_text(text)
    assert validate(bad, "--fit", files["fit"]) == 2
    err = capsys.readouterr().err
    assert str(bad) in err
    assert "column 'tip_acceleration' not found" in err and "did you mean 'tip_accel'?" in err


def rewrite_rows(src, dst, change):
    """Copy a record file, applying ``change(rows)`` to its data rows (lists of cells)."""
    lines = src.read_text().splitlines()
    first = next(i for i, ln in enumerate(lines) if not ln.startswith("#"))
    rows = [ln.split(",") for ln in lines[first + 1 :]]
    change(rows)
    dst.write_text("\n".join(lines[: first + 1] + [",".join(r) for r in rows]) + "\n")
    return dst, first + 2  # the file line of data row 0


@pytest.mark.parametrize(
    "case, change, expected",
    [
        ("text", lambda rows: rows[5].__setitem__(2, "x"), ["line {l5}", "'x' is not a number"]),
        ("nan", lambda rows: rows[7].__setitem__(3, "nan"), ["line {l7}", "not finite"]),
        ("order", lambda rows: rows.insert(9, rows.pop(8)), ["strictly increasing"]),
        ("short", lambda rows: rows.__delitem__(slice(10, None)), ["only 10 sample(s)"]),
    ],
)
def test_malformed_records_name_file_and_line(files, tmp_path, capsys, case, change, expected):
    path, line0 = rewrite_rows(files["records"][0], tmp_path / f"{case}.csv", change)
    assert validate(path, "--fit", files["fit"]) == 2
    err = capsys.readouterr().err
    assert str(path) in err
    for fragment in expected:
        assert fragment.format(l5=line0 + 5, l7=line0 + 7) in err


def test_non_uniform_time_points_to_the_resample_flag(files, tmp_path, capsys):
    def jitter(rows):
        for row in rows[100:]:
            row[0] = repr(float(row[0]) + 0.0004)

    path, _ = rewrite_rows(files["records"][1], tmp_path / "jitter.csv", jitter)
    assert validate(path, "--fit", files["fit"]) == 2
    err = capsys.readouterr().err
    assert "non-uniform sampling" in err and "--resample" in err
    with pytest.warns(RecordWarning, match="resampled"):
        assert validate(path, "--fit", files["fit"], "--resample") == 0


def test_angle_in_degrees_is_flagged(files, tmp_path, capsys):
    def degrees(rows):
        for row in rows:
            row[2] = repr(float(np.degrees(float(row[2]))) + 0.5)

    path, _ = rewrite_rows(files["records"][1], tmp_path / "deg.csv", degrees)
    with pytest.warns(RecordWarning, match="'joint_angle'.*degrees"):
        assert validate(path, "--fit", files["fit"]) == 2  # stopped by the unit check
    err = capsys.readouterr().err
    assert "deg.csv: column 'joint_angle'" in err and "is the angle in degrees?" in err
    assert "pass --no-unit-check to skip this check" in err
    with pytest.warns(RecordWarning, match="'joint_angle'.*degrees"):
        assert validate(path, "--fit", files["fit"], "--no-unit-check") == 0
    (row,) = [ln.split() for ln in capsys.readouterr().out.splitlines()
              if ln.startswith("deg ") and ln.split()[2] == "angle"]
    assert float(row[3]) > 90  # NRMSE %: the model, in radians, misses by a factor 57


def test_missing_record_file(files, tmp_path, capsys):
    assert validate(tmp_path / "none.csv", "--fit", files["fit"]) == 2
    assert "none.csv: record file not found" in capsys.readouterr().err
