"""Property tests: mangled records, options and fit files never crash jaxflex.

Whatever the input, the loaders raise their documented error (or load), and the command line
exits 0 or 2 with one error line and no traceback, leaving no partial or temporary file. Every
command here is made to stop before its computation (an existing output without
``--overwrite``, or ``--max-samples 1``), so the examples cost milliseconds, not compilations.
"""

from __future__ import annotations

import contextlib
import io
import json
import os
import tempfile
from pathlib import Path

import pytest

hypothesis = pytest.importorskip("hypothesis")
from hypothesis import HealthCheck, given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

from jaxflex._io import TEMP_MARK  # noqa: E402
from jaxflex.cli import main  # noqa: E402
from jaxflex.data import RecordError, load_record  # noqa: E402
from jaxflex.identification import load_fit  # noqa: E402
from tests.test_faults import EXAMPLE, fit_data  # noqa: E402

HUNT = int(os.environ.get("JAXFLEX_PROPERTY_EXAMPLES", "0"))
"""Set (e.g. to 1000) for a longer, random hunt; the default suite runs 30 fixed examples."""
FAST = settings(max_examples=HUNT or 30, deadline=None, derandomize=not HUNT,
                suppress_health_check=[HealthCheck.too_slow])
LINES = EXAMPLE.read_text().splitlines()[:320]  # the comments, the header and 0.3 s of samples
CELLS = ["", " ", "nan", "inf", "-inf", "1e400", "abc", '"1.5"', "1;2", "0x10", "1e-320", "-0",
         "\x00", "é", "1,2", "#", "sep=;", '"time"', "time"]


def run_cli(argv: list[str], root: Path) -> tuple[int, str]:
    """Exit status and stderr of ``jaxflex ARGV``, checking the contract of every run."""
    before = _files(root)
    err = io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
        code = main(argv)
    text = err.getvalue()
    assert code in (0, 2), text
    assert "Traceback" not in text and "internal error" not in text, text
    if code == 2:
        assert _files(root) == before, "a refused command wrote or changed a file"
        assert sum(": error: " in line for line in text.splitlines()) == 1, text
    assert not [p for p in root.rglob("*") if TEMP_MARK in p.name]
    return code, text


def _files(root: Path) -> dict[str, bytes]:
    return {str(p): p.read_bytes() for p in root.rglob("*") if p.is_file()}


@st.composite
def mangled_lines(draw) -> list[str]:
    lines = list(LINES)
    for _ in range(draw(st.integers(1, 4))):
        i = draw(st.integers(0, len(lines) - 1))
        action = draw(st.sampled_from(["cell", "drop", "copy", "insert", "cut", "swap"]))
        if action == "cell":
            cells = lines[i].split(",")
            cells[draw(st.integers(0, len(cells) - 1))] = draw(st.sampled_from(CELLS) | st.text(
                max_size=6))
            lines[i] = ",".join(cells)
        elif action == "drop" and len(lines) > 1:
            del lines[i]
        elif action == "copy":
            lines.insert(i, lines[i])
        elif action == "insert":
            lines.insert(i, draw(st.text(max_size=20)))
        elif action == "cut":
            lines = lines[: i + 1]
        elif action == "swap" and i + 1 < len(lines):
            lines[i], lines[i + 1] = lines[i + 1], lines[i]
    return lines


@FAST
@given(lines=mangled_lines(), suffix=st.sampled_from([".csv", ".npz"]))
def test_mangled_records_load_or_fail_in_one_line(lines, suffix):
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        path = root / f"rec{suffix}"
        path.write_text("\n".join(lines) + "\n", encoding="utf-8", errors="surrogatepass")
        try:
            load_record(path)
        except RecordError:
            pass
        (root / "fit.json").write_text("{}")  # the run stops there if the record loads
        code, err = run_cli(["identify", str(path), "--out", str(root / "fit.json")], root)
        assert code == 2


@FAST
@given(data=st.binary(max_size=200))
def test_random_bytes_as_npz_or_csv(data):
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        for name in ("r.npz", "r.csv"):
            (root / name).write_bytes(b"PK\x03\x04" + data if name == "r.npz" else data)
            with contextlib.suppress(RecordError):
                load_record(root / name)
            run_cli(["identify", str(root / name), "--out", str(root / "f.json")], root)


VALUES = st.sampled_from(["0", "-1", "1e400", "nan", "inf", "1e-320", "abc", "", "2", "0.5",
                          "1e7", "10000000000000000000000", "de,de", "x=1", "J_h=1:0",
                          "E=nan", "dt=0.1", "n_elements=0.5", "J_h=1e-300:1e300"])
OPTIONS = {
    "simulate": ["--input", "--amplitude", "--set", "--effects", "--duration", "--dt", "--seed",
                 "--plot"],
    "design": ["--duration", "--max-torque", "--rms-torque", "--max-angle", "--max-speed",
               "--harmonics", "--max-frequency", "--seed", "--restarts", "--plot"],
    "identify": ["--generations", "--population", "--effect", "--bound", "--fix", "--weight",
                 "--method", "--seed", "--refine-starts", "--plot"],
    "discover": ["--effects", "--max-steps", "--alpha", "--generations", "--seed", "--bound",
                 "--fix", "--weight", "--effect", "--format"],
}


@FAST
@given(command=st.sampled_from(sorted(OPTIONS)), data=st.data())
def test_odd_options_fail_in_one_line_before_any_work(command, data):
    pairs = data.draw(st.lists(st.tuples(st.sampled_from(OPTIONS[command]), VALUES), max_size=4))
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        options = [str(x) for pair in pairs for x in pair]
        options = [str(root / o) if o.endswith(".png") else o for o in options]
        if command in ("simulate", "design"):  # stops at the size check at the latest
            required = {"simulate": ["--input", "pulse"],
                        "design": ["--max-torque", "1", "--max-angle", "1", "--max-speed", "5"]}
            argv = [command, *required[command], *options, "--out", str(root / "o.csv"),
                    "--max-samples", "1"]
        else:  # stops at the existing output at the latest
            (root / "o.json").write_text("{}")
            out = "--out" if command == "identify" else "--json"
            argv = [command, str(EXAMPLE), *options, out, str(root / "o.json")]
        code, _ = run_cli(argv, root)
        assert code == 2


def _paths(value, prefix=()):
    """Every (path, value) of a JSON tree."""
    yield prefix, value
    if isinstance(value, dict):
        for k, v in value.items():
            yield from _paths(v, (*prefix, k))
    elif isinstance(value, list):
        for i, v in enumerate(value[:3]):
            yield from _paths(v, (*prefix, i))


JSON = st.recursive(
    st.none() | st.booleans() | st.integers(-(2**70), 2**70) | st.floats() | st.text(max_size=5),
    lambda inner: st.lists(inner, max_size=3) | st.dictionaries(st.text(max_size=4), inner,
                                                                max_size=3),
    max_leaves=6,
)
FIT_PATHS = [p for p, _ in _paths(fit_data()) if p]


@FAST
@given(where=st.sampled_from(FIT_PATHS), value=JSON, delete=st.booleans())
def test_mangled_fit_files_fail_in_one_line(where, value, delete):
    data = fit_data()
    parent = data
    for key in where[:-1]:
        parent = parent[key]
    if delete and isinstance(parent, dict):
        del parent[where[-1]]
    else:
        parent[where[-1]] = value
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        fit = root / "fit.json"
        fit.write_text(json.dumps(data))
        try:
            load_fit(fit)
        except ValueError:
            pass
        report = root / "report"
        report.mkdir()
        (report / "table.txt").write_text("mine")  # validate stops there if the fit is usable
        for argv in (["validate", str(EXAMPLE), "--fit", str(fit), "--report", str(report)],
                     ["discover", str(EXAMPLE), "--initial", str(fit), "--report", str(report)]):
            code, _ = run_cli(argv, root)
            assert code == 2
