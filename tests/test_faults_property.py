"""Property tests: mangled records, options and fit files never crash jaxflex.

Whatever the input, the loaders raise their documented error (or load), and the command line
exits 0 or 2 with one error line and no traceback, leaving no partial or temporary file. Every
command here is made to stop before its computation (an existing output without
``--overwrite``, or ``--max-samples 1``), so the examples cost milliseconds, not compilations.
"""

from __future__ import annotations

import contextlib
import dataclasses
import io
import json
import os
import tempfile
from pathlib import Path
from typing import Any

import pytest

hypothesis = pytest.importorskip("hypothesis")
from helpers import EXAMPLE, fit_data  # noqa: E402
from hypothesis import HealthCheck, Phase, given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

from jaxflex import Model  # noqa: E402
from jaxflex._io import TEMP_MARK  # noqa: E402
from jaxflex.arm import ArmError, arm_from_dict, arm_to_toml, load_arm  # noqa: E402
from jaxflex.cli import main  # noqa: E402
from jaxflex.data import RecordError, load_record  # noqa: E402
from jaxflex.drives import DRIVES  # noqa: E402
from jaxflex.identification import load_fit  # noqa: E402
from jaxflex.parameters import BASE_PARAMETERS  # noqa: E402
from jaxflex.sensors import SENSORS  # noqa: E402

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
    "simulate": ["--input", "--amplitude", "--set", "--effect", "--duration", "--dt", "--seed",
                 "--plot"],
    "design": ["--duration", "--max-torque", "--rms-torque", "--max-angle", "--max-speed",
               "--harmonics", "--max-frequency", "--seed", "--restarts", "--plot"],
    "identify": ["--generations", "--population", "--effect", "--bound", "--fix", "--weight",
                 "--method", "--seed", "--refine-starts", "--plot"],
    "discover": ["--candidates", "--max-steps", "--alpha", "--generations", "--seed", "--bound",
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


# --- arm files: valid ones round-trip exactly, corrupted ones fail in one line naming the key ---

LINK_SENSORS = ("strain_gauge", "accelerometer", "deflection")
KNOWN_KEYS = {
    "name", "description", "link", "simulation", "sampling", "parameters", "drive", "sensors",
    "effects", "length", "width", "thickness", "density", "mass_per_length", "mass",
    "clamp_offset", "n_elements", "n_substeps", "friction_smoothing", "n_modes", "dt",
    "duration", "reference", "lower", "upper", "fixed", "log_scale", "type",
    *(spec.name for spec in BASE_PARAMETERS),
    *(f.name for cls in DRIVES.values() for f in dataclasses.fields(cls)),
    *(f.name for cls in SENSORS.values() for f in dataclasses.fields(cls)),
}


def _within(lo: float, hi: float) -> st.SearchStrategy[float]:
    return st.floats(lo, hi, allow_nan=False, allow_infinity=False)


@st.composite
def _bounds(draw, reference: float, signed: bool = False) -> dict[str, float]:
    """A table of bounds about ``reference`` (> 0 unless ``signed``)."""
    lower = reference * draw(_within(0.01, 0.9))
    upper = reference * draw(_within(1.1, 100.0))
    if signed and draw(st.booleans()):
        lower = -draw(_within(0.0, 2.0)) * abs(reference)
    return {"reference": reference, "lower": lower, "upper": upper}


@st.composite
def _parameter(draw, spec) -> dict[str, Any]:
    reference = spec.reference * draw(_within(0.5, 2.0))
    if draw(st.booleans()):
        entry = {"reference": reference, "fixed": True}
        if draw(st.booleans()):  # a fixed parameter may keep its bounds
            entry |= {k: v for k, v in draw(_bounds(reference)).items() if k != "reference"}
    else:
        entry = draw(_bounds(reference))
        if draw(st.booleans()):
            entry["fixed"] = False
    if draw(st.booleans()):
        entry["log_scale"] = draw(st.booleans())
    return entry


@st.composite
def _drive(draw) -> dict[str, Any]:
    kind = draw(st.sampled_from(sorted(DRIVES)))
    drive: dict[str, Any] = {"type": kind}
    if kind == "command":
        drive["unit"] = draw(st.sampled_from(["V", "%", "1", "counts", "duty"]))
        gain = draw(_within(1e-3, 10.0))
        drive["torque_per_unit"] = draw(_bounds(gain)) if draw(st.booleans()) else gain
        if draw(st.booleans()):
            drive["saturation"] = draw(_within(0.1, 100.0))
    else:
        for f in dataclasses.fields(DRIVES[kind]):
            efficiency = f.name in getattr(DRIVES[kind], "EFFICIENCIES", ())
            drive[f.name] = draw(_within(0.05, 1.0) if efficiency else _within(0.05, 100.0))
    return drive


@st.composite
def _sensor(draw, i: int, length: float) -> dict[str, Any]:
    kind = draw(st.sampled_from(sorted(SENSORS)))
    sensor: dict[str, Any] = {"type": kind, "channel": f"s{i}_{kind}"}
    if kind in LINK_SENSORS:
        # at the clamp only a gauge reads anything (on the joint axis, as here)
        sensor["x"] = draw(_within(0.0 if kind == "strain_gauge" else 0.01 * length, length))
        if kind == "strain_gauge":
            sensor["calibration"] = draw(st.sampled_from(["strain", "deflection_angle"]))
            if sensor["calibration"] == "deflection_angle" or sensor["x"] >= length:
                sensor["x"] = min(sensor["x"], 0.99 * length)  # a gauge at the tip reads nothing
    if kind == "encoder" and draw(st.booleans()):
        sensor["counts_per_revolution"] = draw(st.integers(1, 100_000))
    gain = draw(_within(0.1, 10.0)) * draw(st.sampled_from([1.0, -1.0]))
    choice = draw(st.sampled_from(["none", "number", "table"]))
    if choice == "number":
        sensor["gain"] = gain
    elif choice == "table":
        sensor["gain"] = draw(_bounds(abs(gain), signed=True))
    if draw(st.booleans()):
        sensor["rezero"] = draw(st.booleans())
    offset = draw(_within(-1.0, 1.0))
    if sensor.get("rezero") is False and draw(st.booleans()):
        sensor["offset"] = {"reference": offset, "lower": offset - draw(_within(0.01, 1.0)),
                            "upper": offset + draw(_within(0.01, 1.0))}
    elif draw(st.booleans()):
        sensor["offset"] = offset
    for key in ("noise", "resolution"):
        if draw(st.booleans()):
            sensor[key] = draw(_within(0.0, 0.1))
    return sensor


@st.composite
def arm_contents(draw) -> dict[str, Any]:
    """The parsed content of a valid arm file: random geometry within sane ranges, every base
    parameter, a drive of any type, sensors of every kind at random x on the link."""
    length = draw(_within(0.1, 2.0))
    width, thickness = draw(_within(0.005, 0.1)), draw(_within(5e-4, 0.01))
    density = draw(_within(1000.0, 9000.0))
    mass_key = draw(st.sampled_from(["density", "mass_per_length", "mass"]))
    link = {"length": length, "width": width, "thickness": thickness,
            mass_key: {"density": density, "mass_per_length": density * width * thickness,
                       "mass": density * width * thickness * length}[mass_key]}
    if draw(st.booleans()):
        link["clamp_offset"] = draw(_within(0.0, 0.1))
    name = draw(st.text(min_size=1, max_size=10).filter(lambda t: t.strip() and t.isprintable()))
    data: dict[str, Any] = {"name": name, "link": link}
    if draw(st.booleans()):
        data["description"] = draw(st.text(max_size=20))
    if draw(st.booleans()):
        n = draw(st.integers(2, 16))
        data["simulation"] = {"n_elements": n, "n_substeps": draw(st.integers(1, 4)),
                              "friction_smoothing": draw(_within(1e-3, 0.1))}
        if draw(st.booleans()):
            data["simulation"]["n_modes"] = draw(st.integers(1, 2 * n))
    if draw(st.booleans()):
        data["sampling"] = {"dt": draw(_within(1e-4, 1e-2)), "duration": draw(_within(0.5, 10.0))}
    data["parameters"] = {spec.name: draw(_parameter(spec)) for spec in BASE_PARAMETERS}
    data["drive"] = draw(_drive())
    n_sensors = draw(st.integers(0, 5))
    if n_sensors or draw(st.booleans()):
        data["sensors"] = [draw(_sensor(i, length)) for i in range(n_sensors)]
    if draw(st.booleans()):
        data["effects"] = draw(st.lists(st.sampled_from(["payload", "delay", "gravity",
                                                         "motor_lag"]), unique=True, max_size=3))
    return data


def _dotted(path: tuple) -> str:
    """A path in the content as the arm errors name it: ``sensors[0].gain.lower``."""
    text = ""
    for key in path:
        text += f"[{key}]" if isinstance(key, int) else f".{key}" if text else key
    return text


def _leaves(value: Any, prefix: tuple = ()):
    """Every (path, value) under ``value``, tables and arrays included."""
    if prefix:
        yield prefix, value
    if isinstance(value, dict):
        for k, v in value.items():
            yield from _leaves(v, (*prefix, k))
    elif isinstance(value, list):
        for i, v in enumerate(value):
            yield from _leaves(v, (*prefix, i))


def _at(data: Any, path: tuple) -> Any:
    for key in path:
        data = data[key]
    return data


WRONG = {  # values of another type than the key's
    float: [True, "1.0", [1.0], "", {"x": 1}],
    int: [2.5, True, "10", [3]],
    str: [1, 2.5, True, ["x"], {"x": "y"}],
    bool: [1, 0, "true", 1.0],
    dict: ["table", [1], True],  # not a number: a table of bounds may be one
    list: [1, "payload", True, {"name": 1}],
}


@st.composite
def corrupted_arms(draw) -> tuple[dict[str, Any], tuple, str]:
    """A valid arm's content with one fault, the path of the key at fault and the fault."""
    data = json.loads(json.dumps(draw(arm_contents())))  # a deep copy
    fault = draw(st.sampled_from(["drop", "wrong type", "inverted bound", "unknown key"]))
    paths = [p for p, _ in _leaves(data)]
    if fault == "inverted bound":
        tables = [p for p, v in _leaves(data)
                  if isinstance(v, dict) and {"lower", "upper"} <= set(v)]
        if not tables:
            fault = "unknown key"
        else:
            path = draw(st.sampled_from(tables))
            entry = _at(data, path)
            entry["lower"], entry["upper"] = entry["upper"], entry["lower"]
            return data, (*path, "lower"), fault
    if fault == "unknown key":
        tables = [()] + [p for p, v in _leaves(data) if isinstance(v, dict)]
        path = draw(st.sampled_from(tables))
        key = draw(st.from_regex(r"[a-z][a-z_]{0,10}", fullmatch=True).filter(
            lambda k: k not in KNOWN_KEYS))
        _at(data, path)[key] = draw(st.sampled_from([1.0, "x", True]))
        return data, (*path, key), fault
    path = draw(st.sampled_from(paths))
    parent = _at(data, path[:-1])
    if fault == "drop":
        del parent[path[-1]]
    else:
        value = parent[path[-1]]
        parent[path[-1]] = draw(st.sampled_from(WRONG[type(value)]))
    return data, path, fault


ROUND = settings(max_examples=HUNT or 40, deadline=None, derandomize=not HUNT,
                 suppress_health_check=[HealthCheck.too_slow],
                 phases=[Phase.explicit, Phase.reuse, Phase.generate])  # shrinking an arm is slow


def _round_trips(model: Model, root: Path) -> None:
    path = root / "arm.toml"
    path.write_text(arm_to_toml(model), encoding="utf-8")
    again = load_arm(path)
    assert again == model
    assert arm_to_toml(again) == arm_to_toml(model)


@ROUND
@given(data=arm_contents())
def test_valid_arm_files_round_trip_exactly(data):
    model = arm_from_dict(data)
    assert isinstance(model, Model)
    with tempfile.TemporaryDirectory() as tmp:
        _round_trips(model, Path(tmp))


@ROUND
@given(case=corrupted_arms())
def test_corrupted_arm_files_fail_in_one_line_naming_the_key(case):
    data, path, fault = case
    key = _dotted(path)
    try:
        model = arm_from_dict(data, "rig.toml")
    except ArmError as err:
        message = str(err)
        assert type(err) is ArmError
        assert "\n" not in message and message.startswith("rig.toml: "), message
        # a dropped key is named, or the key of its table that it leaves missing (a fixed
        # parameter's bounds, a mass key's alternatives, an offset table's rezero = false)
        named = key if fault != "drop" else _dotted(path[:-1]) or key
        assert named in message, (fault, key, message)
        return
    except Exception as err:  # noqa: BLE001 - the property: no other exception type
        raise AssertionError(f"{fault} at {key}: {type(err).__name__}: {err}") from err
    # a dropped optional key (or a wrong type the file may hold) leaves a valid arm
    assert fault == "drop", (fault, key)
    with tempfile.TemporaryDirectory() as tmp:
        _round_trips(model, Path(tmp))


# --- --window texts: a usage error in one line, or a window within the record ---------------

from jaxflex.cli import UsageError  # noqa: E402
from jaxflex.cli._windows import Window, check_window, parse_windows  # noqa: E402

TIMES = st.one_of(
    st.floats().map(repr), st.integers(-10, 10**6).map(str), st.text(max_size=4),
    st.sampled_from(["", " ", "nan", "inf", "-inf", "-0", "1e400", "1e-320", "1_0", "0x10",
                     "１", "auto", "0.5", "1", "2.5", "1500", "-1", " 1 "]),
)


@st.composite
def window_texts(draw, names: list[str]) -> str:
    times = draw(st.one_of(
        st.tuples(TIMES, TIMES).map(":".join),
        st.sampled_from(["auto", ":", "", "1:2:3", "::", "1-2"]),
        st.text(max_size=8),
    ))
    name = draw(st.one_of(st.none(), st.sampled_from(names), st.text(max_size=6)))
    return times if name is None else f"{name}={times}"


@st.composite
def spans(draw) -> tuple[float, float, float]:
    """A record's time span ``(t_start, t_end)`` and its sample step."""
    t_start = draw(st.sampled_from([0.0, 0.0, 1e-3]) | _within(-5.0, 1e5))
    t_end = t_start + draw(st.sampled_from([0.0, 1e-3]) | _within(1e-6, 1e4))
    return t_start, t_end, draw(st.sampled_from([0.0, 1e-3, 2e-3]) | _within(0.0, 1.0))


def _one_line(err: UsageError) -> None:
    message = str(err)
    assert "\n" not in message and message.startswith("--window "), message


@FAST
@given(data=st.data(),
       names=st.lists(st.text(min_size=1, max_size=6), min_size=1, max_size=4, unique=True))
def test_window_texts_are_refused_in_one_line_or_lie_within_the_record(data, names):
    texts = data.draw(st.lists(window_texts(names), max_size=3))
    try:
        windows = parse_windows(texts, names)
    except UsageError as err:
        _one_line(err)
        return
    assert set(windows) == set(names)
    for name, window in windows.items():
        if window is None or window.auto:
            continue
        assert isinstance(window, Window)
        t_start, t_end, dt = data.draw(spans())
        try:
            t0, t1 = check_window(window, name, t_start, t_end, dt)
        except UsageError as err:
            _one_line(err)
            continue
        assert t_start <= t0 < t1 <= t_end, (window, t_start, t_end, t0, t1)
        for end, cut in ((window.start, t0), (window.end, t1)):
            if end is not None:  # a given end is kept, or cut back by at most one sample
                assert abs(end - cut) <= max(dt, 1e-9 * max(1.0, abs(t_start), abs(t_end)))
