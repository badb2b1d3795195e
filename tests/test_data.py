"""Records, data sets and the record file loader: every malformed file gets a precise message."""

from __future__ import annotations

import math
import re
import warnings
from pathlib import Path

import numpy as np
import pytest

import jaxflex
from jaxflex._io import OutputExistsError
from jaxflex.data import (
    Dataset,
    Record,
    RecordError,
    RecordWarning,
    load_dataset,
    load_record,
    save_npz,
    save_record,
)

N = 32
DT = 1e-3


def arrays(n: int = N, dt: float = DT) -> dict[str, np.ndarray]:
    t = dt * np.arange(n)
    return {
        "time": t,
        "torque": np.where(t < 0.01, 0.25, 0.0),
        "joint_angle": 0.5 * t**2,
        "tip_acceleration": np.sin(40 * t),
    }


def make_record(name: str = "r", n: int = N, dt: float = DT, **extras: np.ndarray) -> Record:
    return Record(**arrays(n, dt), extras=extras, name=name)


def write_csv(path, header: str, rows: list[str], comments: tuple[str, ...] = ()) -> str:
    """Write a small CSV file; returns its path as text (for matching in messages)."""
    path.write_text("\n".join([*comments, header, *rows]) + "\n")
    return str(path)


def good_rows(n: int = N, dt: float = DT) -> list[str]:
    cols = arrays(n, dt)
    return [",".join(repr(float(cols[c][i])) for c in cols) for i in range(n)]


HEADER = "time,torque,joint_angle,tip_acceleration"


def load_error(path: str, *fragments: str, **kwargs) -> str:
    """Load ``path`` expecting a RecordError whose message holds the file and every fragment."""
    with pytest.raises(RecordError) as info:
        load_record(path, **kwargs)
    message = str(info.value)
    for fragment in (path, *fragments):
        assert fragment in message, f"{fragment!r} not in {message!r}"
    return message


# --- Record and Dataset ----------------------------------------------------------------------


def test_record_properties_and_immutability():
    r = make_record(tip_deflection=np.zeros(N), custom=np.ones(N))
    assert r.n_samples == N
    assert r.dt == pytest.approx(DT, rel=1e-12)
    assert r.sample_rate == pytest.approx(1000.0)
    assert r.duration == pytest.approx((N - 1) * DT)
    assert r.units["tip_acceleration"] == "m/s^2" and r.units["tip_deflection"] == "m"
    assert r.units["custom"] == ""
    assert r.columns == (
        "time",
        "torque",
        "joint_angle",
        "tip_acceleration",
        "tip_deflection",
        "custom",
    )
    assert r.time.dtype == np.float64
    with pytest.raises(ValueError):
        r.torque[0] = 1.0  # read-only
    with pytest.raises(AttributeError):
        r.name = "other"  # frozen


def test_record_copies_inputs():
    cols = arrays()
    r = Record(**cols)
    cols["torque"][0] = 99.0
    assert r.torque[0] == 0.25


def test_channel_and_suggestion():
    r = make_record(tip_deflection=np.zeros(N))
    np.testing.assert_array_equal(r.channel("tip_deflection"), np.zeros(N))
    np.testing.assert_array_equal(r.channel("torque"), r.torque)
    with pytest.raises(KeyError, match="tip_deflection") as info:
        r.channel("tip_deflexion")
    assert "did you mean 'tip_deflection'" in str(info.value)


@pytest.mark.parametrize(
    ("change", "fragment"),
    [
        ({"torque": np.zeros(N - 1)}, "column 'torque' has 31 samples but 'time' has 32"),
        ({"joint_angle": np.zeros((N, 2))}, "column 'joint_angle' has shape (32, 2)"),
        (
            {"tip_acceleration": np.r_[np.zeros(5), np.nan, np.zeros(N - 6)]},
            "column 'tip_acceleration', sample 5: value nan is not finite",
        ),
        ({"time": np.r_[DT * np.arange(10), DT * np.arange(9, N - 1)]}, "column 'time', sample 10"),
        ({"time": DT * np.arange(N) ** 1.01}, "non-uniform sampling"),
        ({"torque": np.array(["a"] * N)}, "column 'torque' holds <U1 values"),
    ],
)
def test_record_validation_names_column_and_sample(change, fragment):
    with pytest.raises(RecordError) as info:
        make_record(name="bad").replace(**change)
    assert "record 'bad'" in str(info.value)
    assert fragment in str(info.value)


def test_record_rejects_bad_extras_and_metadata():
    with pytest.raises(RecordError, match="required column"):
        make_record(torque=np.zeros(N))
    with pytest.raises(RecordError, match="extra column name"):
        make_record(**{"a,b": np.zeros(N)})
    with pytest.raises(RecordError, match="metadata key"):
        make_record().replace(metadata={"a:b": "x"})
    with pytest.raises(RecordError, match="one line"):
        make_record().replace(metadata={"a": "x\ny"})
    with pytest.raises(ValueError, match="unknown Record field"):
        make_record().replace(torq=np.zeros(N))


def test_with_outputs_keeps_the_rest():
    r = make_record(tip_deflection=np.ones(N))
    s = r.with_outputs(joint_angle=np.zeros(N), joint_velocity=np.full(N, 2.0))
    np.testing.assert_array_equal(s.joint_angle, np.zeros(N))
    np.testing.assert_array_equal(s.tip_acceleration, r.tip_acceleration)
    np.testing.assert_array_equal(s.extras["tip_deflection"], np.ones(N))
    np.testing.assert_array_equal(s.extras["joint_velocity"], np.full(N, 2.0))
    assert s.name == r.name


def test_trim_rezeroes_time_and_is_inclusive():
    r = make_record(n=101, tip_deflection=np.arange(101.0))
    s = r.trim(0.02, 0.05)
    assert s.n_samples == 31
    assert s.time[0] == 0.0
    assert s.dt == pytest.approx(DT, rel=1e-9)
    np.testing.assert_array_equal(s.extras["tip_deflection"], np.arange(20.0, 51.0))
    assert "trim" in s.metadata["history"]
    with pytest.raises(ValueError, match="t_start"):
        r.trim(0.05, 0.02)
    with pytest.raises(ValueError, match="holds 0 sample"):
        r.trim(0.0205, 0.0207)


def test_dataset_indexing_split_and_dt():
    ds = Dataset([make_record("a"), make_record("b"), make_record("c")])
    assert len(ds) == 3 and ds.names == ("a", "b", "c")
    assert ds["b"] is ds[1]
    assert ds.dt == pytest.approx(DT)
    assert isinstance(ds[1:], Dataset) and ds[1:].names == ("b", "c")
    fit, held_out = ds.split(["c", "a"])
    assert fit.names == ("c", "a") and held_out.names == ("b",)
    fit, held_out = ds.split("b")
    assert fit.names == ("b",) and held_out.names == ("a", "c")
    with pytest.raises(KeyError, match="did you mean 'b'"):
        ds.split(["B"])
    _, empty = ds.split(ds.names)
    assert len(empty) == 0
    with pytest.raises(RecordError, match="empty"):
        _ = empty.dt


def test_dataset_refuses_mixed_dt_and_repeated_names():
    with pytest.raises(RecordError) as info:
        Dataset([make_record("fast"), make_record("slow", dt=2e-3)])
    message = str(info.value)
    assert "'fast'" in message and "'slow'" in message
    assert "0.001" in message and "0.002" in message
    with pytest.raises(RecordError, match="repeated"):
        Dataset([make_record("a"), make_record("a")])
    with pytest.raises(TypeError):
        Dataset([make_record("a"), "b"])


# --- loader: malformed files -------------------------------------------------------------------


def test_missing_column_suggests_close_match(tmp_path):
    header = "time,torque,joint_angle,tip_accel"
    path = write_csv(tmp_path / "r.csv", header, good_rows())
    load_error(path, "line 1", "column 'tip_acceleration' not found", "did you mean 'tip_accel'?")


def test_misspelt_column_by_case(tmp_path):
    path = write_csv(tmp_path / "r.csv", "Time,torque,joint_angle,tip_acceleration", good_rows())
    load_error(path, "column 'time' not found", "did you mean 'Time'?")


def test_a_record_holds_any_subset_of_outputs(tmp_path):
    rows = [",".join(r.split(",")[:3]) for r in good_rows()]
    path = write_csv(tmp_path / "r.csv", "time,torque,joint_angle", rows)
    record = load_record(path)
    assert record.columns == ("time", "torque", "joint_angle")
    assert record.tip_acceleration is None
    rows = [",".join(r.split(",")[:2]) for r in good_rows()]
    path = write_csv(tmp_path / "s.csv", "time,torque", rows)
    load_error(path, "line 1 (header)", "no output column besides ['time', 'torque']")
    path = write_csv(tmp_path / "v.csv", "time,voltage,root_strain", [r + ",1e-5" for r in rows])
    assert load_record(path).input_name == "voltage"
    path = write_csv(tmp_path / "w.csv", "time,joint_angle", rows)
    load_error(path, "exactly one input column of ['torque', 'current', 'voltage', 'command']; "
               "found none")


def test_duplicated_column(tmp_path):
    rows = [r + ",0.0" for r in good_rows()]
    path = write_csv(tmp_path / "r.csv", HEADER + ",torque", rows)
    load_error(path, "line 1", "column 'torque' appears twice", "columns 2 and 5")


def test_non_numeric_cell(tmp_path):
    rows = good_rows()
    rows[6] = rows[6].replace(rows[6].split(",")[2], "abc", 1)
    path = write_csv(tmp_path / "r.csv", HEADER, rows, comments=("# rig: A",))
    load_error(path, "line 9", "column 'joint_angle'", "'abc' is not a number")


def test_empty_cell(tmp_path):
    rows = good_rows()
    cells = rows[3].split(",")
    cells[1] = ""
    rows[3] = ",".join(cells)
    path = write_csv(tmp_path / "r.csv", HEADER, rows)
    load_error(path, "line 5", "column 'torque'", "empty cell")


@pytest.mark.parametrize("bad", ["nan", "inf", "-inf"])
def test_non_finite_cell(tmp_path, bad):
    rows = good_rows()
    cells = rows[10].split(",")
    cells[3] = bad
    rows[10] = ",".join(cells)
    path = write_csv(tmp_path / "r.csv", HEADER, rows)
    load_error(path, "column 'tip_acceleration'", "line 12", "not finite")


def test_wrong_number_of_cells(tmp_path):
    rows = good_rows()
    rows[4] = rows[4] + ",1.0"
    path = write_csv(tmp_path / "r.csv", HEADER, rows)
    load_error(path, "line 6", "5 cells", "names 4 columns")


def test_time_not_increasing_names_first_row(tmp_path):
    rows = good_rows()
    rows[8], rows[9] = rows[9], rows[8]
    path = write_csv(tmp_path / "r.csv", HEADER, rows)
    load_error(path, "column 'time'", "line 11", "strictly increasing")


def test_non_uniform_sampling_offers_resample(tmp_path):
    cols = arrays()
    cols["time"][12:] += 0.0004
    rows = [",".join(repr(float(cols[c][i])) for c in cols) for i in range(N)]
    path = write_csv(tmp_path / "r.csv", HEADER, rows)
    load_error(path, "non-uniform sampling", "line 13", "line 14", "resample=True")


def test_resample_fixes_jittered_time(tmp_path):
    rng = np.random.default_rng(1)
    n = 200
    t = DT * np.arange(n) + rng.uniform(-0.2, 0.2, n) * DT
    t[0] = 0.0
    cols = {
        "time": t,
        "torque": np.ones(n),
        "joint_angle": 3.0 * t,
        "tip_acceleration": 2.0 * t + 1.0,
    }
    rows = [",".join(repr(float(cols[c][i])) for c in cols) for i in range(n)]
    path = write_csv(tmp_path / "jitter.csv", HEADER, rows)
    with pytest.warns(RecordWarning, match="resampled"):
        r = load_record(path, resample=True)
    dt = float(np.median(np.diff(t)))
    assert r.dt == pytest.approx(dt, rel=1e-12)
    np.testing.assert_allclose(np.diff(r.time), dt, rtol=1e-9)
    # linear columns are reproduced exactly by linear interpolation
    np.testing.assert_allclose(r.joint_angle, 3.0 * r.time, atol=1e-12)
    np.testing.assert_allclose(r.tip_acceleration, 2.0 * r.time + 1.0, atol=1e-12)


def test_too_few_samples(tmp_path):
    path = write_csv(tmp_path / "short.csv", HEADER, good_rows(n=10))
    load_error(path, "only 10 sample(s)", "at least 16")


def test_all_zero_torque(tmp_path):
    rows = [",".join([r.split(",")[0], "0", *r.split(",")[2:]]) for r in good_rows()]
    path = write_csv(tmp_path / "r.csv", HEADER, rows)
    load_error(path, "column 'torque'", "nothing excites the arm")


def test_angle_in_degrees_warns(tmp_path):
    cols = arrays()
    cols["joint_angle"] = np.linspace(0.0, 80.0, N) + 0.5  # large, not whole numbers
    rows = [",".join(repr(float(cols[c][i])) for c in cols) for i in range(N)]
    path = write_csv(tmp_path / "deg.csv", HEADER, rows)
    with pytest.warns(RecordWarning, match=re.escape(path) + ".*'joint_angle'.*degrees"):
        load_record(path)


def test_angle_in_whole_numbers_warns(tmp_path):
    cols = arrays()
    cols["joint_angle"] = np.round(np.linspace(0.0, 20.0, N))  # below four turns, but integral
    rows = [",".join(repr(float(cols[c][i])) for c in cols) for i in range(N)]
    path = write_csv(tmp_path / "counts.csv", HEADER, rows)
    with pytest.warns(RecordWarning, match="'joint_angle' holds only whole numbers"):
        load_record(path)


def test_radian_angle_does_not_warn(tmp_path):
    path = write_csv(tmp_path / "ok.csv", HEADER, good_rows())
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        load_record(path)


def test_semicolon_separated_file(tmp_path):
    rows = [r.replace(",", ";") for r in good_rows()]
    path = write_csv(tmp_path / "r.csv", HEADER.replace(",", ";"), rows)
    load_error(path, "line 1", "semicolons", "comma-separated")


def test_empty_file_and_header_only(tmp_path):
    path = write_csv(tmp_path / "empty.csv", "# only: comments", [])
    load_error(path, "no header line")
    path = write_csv(tmp_path / "header.csv", HEADER, [])
    load_error(path, "only 0 sample(s)")


def test_missing_header(tmp_path):
    rows = good_rows()
    path = write_csv(tmp_path / "r.csv", rows[0], rows[1:], comments=("# rig: A",))
    load_error(path, "line 2 looks like data, not a header")


def test_not_an_npz_file(tmp_path):
    path = tmp_path / "r.npz"
    path.write_text("time,torque\n")
    load_error(str(path), "not an NPZ file", "is it a text file with the wrong suffix?")


def test_unsupported_suffix(tmp_path):
    with pytest.raises(ValueError, match="unsupported record file type '.txt'"):
        load_record(tmp_path / "r.txt")


def test_comments_blank_lines_and_extras(tmp_path):
    rows = [r + f",{i * 0.5!r}" for i, r in enumerate(good_rows())]
    rows.insert(5, "")
    rows.insert(9, "# a comment between rows")
    comments = ("# operator: J. Doe", "# free text without a colon", "#rig : arm-2 ")
    path = write_csv(tmp_path / "run7.csv", HEADER + ",tip_deflection", rows, comments)
    r = load_record(path)
    assert r.name == "run7" and r.source == path
    assert r.metadata == {"operator": "J. Doe", "rig": "arm-2"}
    np.testing.assert_array_equal(r.extras["tip_deflection"], 0.5 * np.arange(N))
    assert load_record(path, name="custom").name == "custom"


def test_repeated_metadata_key_warns(tmp_path):
    path = write_csv(tmp_path / "r.csv", HEADER, good_rows(), comments=("# a: 1", "# a: 2"))
    with pytest.warns(RecordWarning, match="line 2.*'a'"):
        r = load_record(path)
    assert r.metadata["a"] == "2"


# --- saving ------------------------------------------------------------------------------------


def awkward_record() -> Record:
    rng = np.random.default_rng(7)
    cols = arrays(n=40)
    cols["tip_acceleration"] = rng.standard_normal(40) * 1e-7 + 1 / 3
    return Record(
        **cols,
        extras={"tip_deflection": rng.standard_normal(40) * 1e300, "joint_velocity": -cols["time"]},
        name="awk",
        metadata={"operator": "J. Doe", "note": "ratio 1:2, units: SI", "empty": ""},
    )


@pytest.mark.parametrize("suffix", [".csv", ".npz"])
def test_round_trip_is_exact(tmp_path, suffix):
    r = awkward_record()
    path = tmp_path / f"awk{suffix}"
    save_record(r, path)
    s = load_record(path)
    assert s.columns == r.columns
    for c in r.columns:
        np.testing.assert_array_equal(s.channel(c), r.channel(c))
    assert s.metadata == r.metadata
    assert s.name == "awk"


def test_save_npz_directly(tmp_path):
    r = awkward_record()
    save_npz(r, tmp_path / "x.npz")
    np.testing.assert_array_equal(load_record(tmp_path / "x.npz").torque, r.torque)
    with pytest.raises(ValueError, match=".npz"):
        save_npz(r, tmp_path / "x.csv")


@pytest.mark.parametrize("suffix", [".csv", ".npz"])
def test_no_silent_overwrite(tmp_path, suffix):
    path = tmp_path / f"user{suffix}"
    path.write_bytes(b"precious")
    with pytest.raises(OutputExistsError):
        save_record(awkward_record(), path)
    assert path.read_bytes() == b"precious"
    assert sorted(p.name for p in tmp_path.iterdir()) == [path.name]  # no temp files left
    save_record(awkward_record(), path, overwrite=True)
    assert load_record(path).n_samples == 40


def test_saved_csv_is_readable_text(tmp_path):
    path = save_record(make_record(), tmp_path / "r.csv")
    lines = path.read_text().splitlines()
    assert lines[0].startswith("# units = time s")
    assert lines[1] == HEADER
    assert lines[2] == "0.0,0.25,0.0,0.0"


# --- NPZ -----------------------------------------------------------------------------------------


def test_npz_validation_names_array_and_index(tmp_path):
    cols = arrays()
    cols["joint_angle"] = cols["joint_angle"].copy()
    cols["joint_angle"][7] = np.inf
    path = tmp_path / "bad.npz"
    np.savez(path, **cols)
    load_error(str(path), "column 'joint_angle'", "index 7", "not finite")

    cols = arrays()
    cols["tip_accel"] = cols.pop("tip_acceleration")
    np.savez(path, **cols)
    load_error(str(path), "'tip_acceleration' not found", "did you mean 'tip_accel'?")


def test_load_dataset_from_directory_and_list(tmp_path):
    for name in ("b", "a"):
        save_record(make_record(name), tmp_path / f"{name}.csv")
    save_record(make_record("c"), tmp_path / "c.npz")
    (tmp_path / "notes.txt").write_text("ignored")
    ds = load_dataset(tmp_path)
    assert ds.names == ("a", "b", "c")
    assert load_dataset([tmp_path / "b.csv"]).names == ("b",)
    assert math.isclose(ds.dt, DT, rel_tol=1e-12)


@pytest.mark.parametrize(
    ("column", "scale", "fragment"),
    [
        ("time", 1000.0, "column 'time': step 1 s (1 Hz sampling); is time in milliseconds"),
        ("joint_angle", 180 / np.pi, "is the angle in degrees? joint_angle must be in rad"),
        ("torque", 1e6, "column 'torque': the record implies a joint inertia of"),
    ],
)
def test_implausible_units_stop_loading_unless_unchecked(tmp_path, column, scale, fragment):
    """Units checked against physics (tip path over angle; torque over angular motion) on a
    record the test scales, with the remedy named; unit_check=False loads it as it is."""
    example = Path(jaxflex.__file__).parent / "data" / "example_pulse.csv"
    record = load_record(example)
    columns = record.to_dict()
    columns[column] = scale * columns[column]
    rows = [",".join(repr(float(v)) for v in row) for row in zip(*columns.values(), strict=True)]
    path = write_csv(tmp_path / "scaled.csv", ",".join(columns), rows)
    load_error(path, fragment, "(pass unit_check=False to skip this check)")
    assert load_record(path, unit_check=False).channel(column)[5] == columns[column][5]
