"""Faults and bad input at the command line: refused before any work, in one line.

Each test runs ``jaxflex`` as a user would (``main([...])`` or a subprocess) and checks the exit
status, that the error is one line naming the path or option, and that no output or temporary
file was written or changed. Read-only directories are emulated for root with ``setpriv``
dropping the capabilities that bypass file permissions.
"""

from __future__ import annotations

import importlib
import json
import os
import re
import shutil
import signal
import stat
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from helpers import EXAMPLE, fit_data

import jaxflex
from jaxflex._io import TEMP_MARK
from jaxflex.cli import main
from jaxflex.identification import Fit

SETPRIV = shutil.which("setpriv")
DROP_CAPS = [SETPRIV or "setpriv", "--bounding-set", "-dac_override,-dac_read_search",
             "--inh-caps", "-dac_override,-dac_read_search"]


# --- helpers --------------------------------------------------------------------------------------


def snapshot(root: Path) -> dict[str, tuple[bytes, int]]:
    """Every file under ``root`` with its contents and mode (to prove nothing changed)."""
    return {
        str(p.relative_to(root)): (p.read_bytes(), stat.S_IMODE(p.lstat().st_mode))
        for p in sorted(root.rglob("*")) if p.is_file() and not p.is_symlink()
    }


def temp_files(root: Path) -> list[Path]:
    return [p for p in root.rglob("*") if TEMP_MARK in p.name]


def run(argv, capsys) -> tuple[int, list[str]]:
    """Exit status and the stderr lines of ``jaxflex ARGV``."""
    code = main([str(a) for a in argv])
    return code, capsys.readouterr().err.splitlines()


def refused(argv, capsys, root: Path, *fragments: str) -> str:
    """Run ``argv`` expecting exit 2 with one error line holding every fragment, and no file
    under ``root`` written, changed or left behind."""
    before = snapshot(root)
    code, err = run(argv, capsys)
    errors = [line for line in err if ": error: " in line]
    assert code == 2, err
    assert len(errors) == 1 and not any("Traceback" in line for line in err), err
    for fragment in fragments:
        assert fragment in errors[0], (fragment, errors[0])
    assert snapshot(root) == before
    assert temp_files(root) == []
    return errors[0]


def example(tmp_path: Path, name: str = "rec.csv") -> Path:
    path = tmp_path / name
    shutil.copy(EXAMPLE, path)
    return path


def rewrite(tmp_path: Path, name: str, change) -> Path:
    """A copy of the example record with its columns changed by ``change(columns)``."""
    lines = EXAMPLE.read_text().splitlines()
    comments = [ln for ln in lines if ln.startswith("#")]
    body = [ln for ln in lines if ln and not ln.startswith("#")]
    header = body[0].split(",")
    values = np.array([[float(c) for c in ln.split(",")] for ln in body[1:]])
    columns = {h: values[:, j] for j, h in enumerate(header)}
    change(columns)
    rows = [",".join(repr(float(columns[h][i])) for h in header)
            for i in range(len(columns["time"]))]
    path = tmp_path / name
    path.write_text("\n".join([*comments, ",".join(header), *rows]) + "\n")
    return path


def write_fit(path: Path, data) -> Path:
    path.write_text(json.dumps(data))
    return path


def jaxflex_subprocess(args, cwd: Path, *, drop_caps: bool = False, **kwargs):
    command = [sys.executable, "-m", "jaxflex", *map(str, args)]
    if drop_caps and os.geteuid() == 0:
        command = [*DROP_CAPS, *command]
    env = os.environ | {"PYTHONPATH": str(Path(jaxflex.__file__).parent.parent)}
    return subprocess.Popen(command, cwd=cwd, env=env, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, preexec_fn=_default_sigint,
                            **kwargs)


def _default_sigint() -> None:
    """A child started from a background job inherits an ignored SIGINT; a terminal's is not."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


needs_setpriv = pytest.mark.skipif(
    os.geteuid() == 0 and SETPRIV is None,
    reason="running as root without setpriv: cannot drop the capability that ignores permissions",
)


# --- OS errors: refused before the work, one line -------------------------------------------------


@needs_setpriv
@pytest.mark.parametrize("command", [
    ["identify", "{rec}", "--out", "ro/fit.json"],
    ["simulate", "--input", "pulse", "--out", "ro/s.csv"],
    ["validate", "{rec}", "--fit", "{fit}", "--report", "ro/report"],
    ["design", "--max-torque", "1", "--max-angle", "1", "--max-speed", "5", "--out", "ro/d.csv"],
    ["study", "{rec}", "--seeds", "0", "--out", "ro/study.json"],
    ["discover", "{rec}", "--json", "ro/discover.json"],
    ["demo", "--out", "ro/demo"],
])
def test_read_only_directory_is_refused_before_any_work(tmp_path, command):
    rec, fit = example(tmp_path), write_fit(tmp_path / "fit.json", fit_data())
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o555)
    argv = [a.format(rec=rec, fit=fit) for a in command]
    start = time.perf_counter()
    proc = jaxflex_subprocess(argv, tmp_path, drop_caps=True)
    out, err = proc.communicate(timeout=120)
    assert proc.returncode == 2, err
    assert err.count("\n") == 1 and "Traceback" not in err
    assert (f"{argv[-2]} ro/" in err or "demo: error: ro/demo/" in err) and "not writable" in err
    assert list(ro.iterdir()) == []
    assert time.perf_counter() - start < 60  # no search, simulation or design ran


@needs_setpriv
def test_unreadable_input_is_one_line(tmp_path):
    rec = example(tmp_path)
    rec.chmod(0)
    proc = jaxflex_subprocess(["identify", rec, "--out", "fit.json"], tmp_path, drop_caps=True)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 2
    assert err == f"jaxflex identify: error: {rec}: Permission denied; check the permissions of " \
                  "the file and its directory\n"
    assert not (tmp_path / "fit.json").exists()


def test_output_under_a_file_is_refused(tmp_path, capsys):
    rec = example(tmp_path)
    (tmp_path / "afile.csv").write_text("x")
    refused(["identify", rec, "--out", tmp_path / "afile.csv" / "fit.json"], capsys, tmp_path,
            "--out", "afile.csv/fit.json", "afile.csv is a file, not a directory")


# --- permissions ----------------------------------------------------------------------------------


def test_written_files_get_ordinary_permissions_and_links_are_kept(tmp_path, capsys):
    previous = os.umask(0o022)
    try:
        out = tmp_path / "s.csv"
        code, _ = run(["simulate", "--input", "pulse", "--duration", "0.1", "--out", out], capsys)
        assert code == 0 and stat.S_IMODE(out.stat().st_mode) == 0o644
        target = tmp_path / "shared" / "s.csv"
        target.parent.mkdir()
        target.write_text("old")
        target.chmod(0o640)
        link = tmp_path / "link.csv"
        link.symlink_to(target)
        code, _ = run(["simulate", "--input", "pulse", "--duration", "0.1", "--out", link,
                       "--overwrite"], capsys)
        assert code == 0
        assert link.is_symlink() and target.read_text() != "old"  # written through the link
        assert stat.S_IMODE(target.stat().st_mode) == 0o640  # the replaced file's mode
        assert temp_files(tmp_path) == []
    finally:
        os.umask(previous)


# --- --set dt / duration --------------------------------------------------------------------------


@pytest.mark.parametrize("name", ["dt", "duration"])
def test_set_dt_or_duration_points_to_the_option(tmp_path, capsys, name):
    refused(["simulate", "--input", "pulse", "--set", f"{name}=0.01", "--out", tmp_path / "x.csv"],
            capsys, tmp_path, f"--set {name}: use --{name} instead")


# --- a directory named like a record --------------------------------------------------------------


def test_a_subdirectory_named_csv_is_skipped(tmp_path, capsys):
    data = tmp_path / "data"
    data.mkdir()
    example(data)
    (data / "old.csv").mkdir()
    (tmp_path / "fit.json").write_text("{}")
    # loading succeeds; the run stops at the existing output, before any work
    refused(["identify", data, "--out", tmp_path / "fit.json"], capsys, tmp_path,
            "--out", "fit.json: file exists; pass --overwrite")


# --- discover --report and --json -----------------------------------------------------------------


def test_discover_outputs_are_checked_together_before_the_run(tmp_path, capsys):
    rec = example(tmp_path)
    refused(["discover", rec, "--json", tmp_path / "r2" / "discover.json",
             "--report", tmp_path / "r2"], capsys, tmp_path,
            "--report", "discover.json: --json writes the same file")
    (tmp_path / "r3").mkdir()
    (tmp_path / "r3" / "table.txt").write_text("mine")
    refused(["discover", rec, "--json", tmp_path / "d.json", "--report", tmp_path / "r3"],
            capsys, tmp_path, "--report", "r3/table.txt: file exists")
    assert not (tmp_path / "r2").exists()


# --- units ----------------------------------------------------------------------------------------


def _ms(c):
    c["time"] = 1000 * c["time"]


def _small_degrees(c):  # a motion below 25 degrees, the angle written in degrees
    c["torque"], c["tip_acceleration"] = 0.3 * c["torque"], 0.3 * c["tip_acceleration"]
    c["joint_angle"] = np.degrees(0.3 * c["joint_angle"])


def _constant_angle(c):
    c["joint_angle"] = np.full_like(c["joint_angle"], 0.25)


def _huge_torque(c):
    c["torque"] = 1e6 * c["torque"]


@pytest.mark.parametrize(("change", "fragments"), [
    (_ms, ["column 'time': step 1 s", "milliseconds"]),
    (_small_degrees, ["column 'joint_angle'", "is the angle in degrees?"]),
    (_huge_torque, ["column 'torque'", "joint inertia", "is the torque in N m"]),
])
def test_implausible_units_stop_with_the_remedy(tmp_path, capsys, change, fragments):
    path = rewrite(tmp_path, "bad.csv", change)
    refused(["identify", path, "--out", tmp_path / "fit.json"], capsys, tmp_path,
            "bad.csv", *fragments, "pass --no-unit-check to skip this check")
    # the check can be silenced explicitly: loading then goes on (to the existing-output stop)
    (tmp_path / "fit.json").write_text("{}")
    refused(["identify", path, "--out", tmp_path / "fit.json", "--no-unit-check"], capsys,
            tmp_path, "fit.json: file exists")


def test_constant_angle_under_torque_is_reported(tmp_path, capsys):
    from jaxflex.data import RecordWarning

    path = rewrite(tmp_path, "still.csv", _constant_angle)
    (tmp_path / "fit.json").write_text("{}")
    with pytest.warns(RecordWarning, match=r"still\.csv: column 'joint_angle' is constant \(0\.25\)"
                      ".*breakaway friction, or the encoder is not connected"):
        refused(["identify", path, "--out", tmp_path / "fit.json"], capsys, tmp_path,
                "fit.json: file exists")


# --- absurd bounds --------------------------------------------------------------------------------


def test_absurd_bounds_are_refused_before_the_search(tmp_path, capsys):
    refused(["identify", example(tmp_path), "--bound", "J_h=1e-300:1e300", "--out",
             tmp_path / "fit.json"], capsys, tmp_path, "--bound J_h", "600 decades")


def test_a_failed_fit_is_not_written(monkeypatch, tmp_path, capsys):
    """A search whose every candidate diverged (cost inf, as the 1e-300:1e300 box gave) is an
    error, not a fit file full of nulls; the search itself is replaced by its outcome here."""
    import functools
    import types

    module = importlib.import_module("jaxflex.identification")

    @functools.wraps(module.identify)
    def diverged(*args, **kwargs):
        return types.SimpleNamespace(cost=float("inf"))

    monkeypatch.setattr(module, "identify", diverged)
    refused(["identify", example(tmp_path), "--out", tmp_path / "fit.json", "--bound",
             "J_h=1e-4:1e4"], capsys, tmp_path, "the fit failed: its cost is inf",
            "narrow the --bound ranges", "nothing was written")


# --- an output that is a directory ----------------------------------------------------------------


@pytest.mark.parametrize("overwrite", [[], ["--overwrite"]])
def test_an_output_that_is_a_directory_is_refused(tmp_path, capsys, overwrite):
    (tmp_path / "dir").mkdir()
    refused(["identify", example(tmp_path), "--out", tmp_path / "dir", *overwrite], capsys,
            tmp_path, "--out", "dir: is a directory; give a file name inside it")


# --- hand-edited fit files ------------------------------------------------------------------------


@pytest.mark.parametrize(("edit", "field"), [
    (lambda d: d | {"params": [1, 2]}, "field 'params': expected an object, got [1, 2]"),
    (lambda d: "a string", "expected a JSON object"),
    (lambda d: d | {"history": None}, "field 'history': expected an object, got null"),
    (lambda d: d | {"covariance": [[1.0, 0.0], [0.0]]}, "field 'covariance': expected a square"),
    (lambda d: d | {"params": d["params"] | {"E": None}},
     "field 'params.E': expected a finite number, got null"),
    (lambda d: d | {"model_description": d["model_description"] | {
        "simulation": d["model_description"]["simulation"] | {"n_elements": 10**9}}},
     "field 'model_description': simulation.n_elements: expected a whole number in [1, 1000]"),
])
@pytest.mark.parametrize("command", ["validate", "discover"])
def test_hand_edited_fit_names_the_field(tmp_path, capsys, edit, field, command):
    fit = write_fit(tmp_path / "fit.json", edit(fit_data()))
    option = "--fit" if command == "validate" else "--initial"
    refused([command, example(tmp_path), option, fit], capsys, tmp_path,
            f"{option} {fit}: cannot use the fit", field)


# --- partial outputs ------------------------------------------------------------------------------


def test_no_output_is_written_when_another_is_refused(tmp_path, capsys):
    refused(["simulate", "--input", "pulse", "--out", tmp_path / "s.csv", "--plot",
             tmp_path / "s.jpg"], capsys, tmp_path, "--plot", "s.jpg: unsupported file type")
    refused(["identify", example(tmp_path), "--out", tmp_path / "same.png", "--plot",
             tmp_path / "same.png"], capsys, tmp_path, "--out", "same.png", ".json")
    refused(["design", "--max-torque", "1", "--max-angle", "1", "--max-speed", "5", "--out",
             tmp_path / "d.csv", "--plot", tmp_path / "a.png", "--plot-intervals",
             tmp_path / "a.png"], capsys, tmp_path,
            "--plot-intervals", "a.png: --plot writes the same file")


def test_outputs_appear_all_together_or_none(monkeypatch, tmp_path, capsys):
    """A failure while writing the second output leaves neither (the first was staged)."""
    from matplotlib.figure import Figure

    def disk_full(self, fname, **kwargs):
        Path(fname).write_bytes(b"\x89PNG partial")
        raise OSError(28, "No space left on device", str(fname))

    monkeypatch.setattr(Figure, "savefig", disk_full)
    refused(["simulate", "--input", "pulse", "--duration", "0.1", "--out", tmp_path / "s.csv",
             "--plot", tmp_path / "s.png"], capsys, tmp_path,
            "s.png: cannot write (No space left on device)")
    assert not (tmp_path / "s.csv").exists()


# --- sizes ----------------------------------------------------------------------------------------


@pytest.mark.parametrize(("argv", "fragments"), [
    (["simulate", "--input", "pulse", "--duration", "1e7"], ["--duration 1e+07 s", "size limit"]),
    (["simulate", "--input", "pulse", "--dt", "1e-12"], ["--dt 1e-12 s", "size limit"]),
    (["simulate", "--input", "pulse", "--set", "n_elements=1000000"], ["1000000-element beam"]),
    (["simulate", "--input", "pulse", "--max-samples", "100"], ["size limit of 100"]),
    (["design", "--duration", "1e6", "--max-torque", "1", "--max-angle", "1", "--max-speed", "5"],
     ["--duration 1e+06 s", "--max-samples or JAXFLEX_MAX_SAMPLES"]),
    (["simulate", "--input", "pulse", "--seed", "100000000000000000000000"],
     ["argument --seed", "must lie in [0, 4294967295]"]),
    (["simulate", "--input", "pulse", "--seed", "1e23"], ["argument --seed", "not a whole number"]),
])
def test_absurd_sizes_are_refused_up_front(tmp_path, capsys, argv, fragments):
    before = snapshot(tmp_path)
    code, err = run([*argv, "--out", tmp_path / "x.csv"], capsys)
    assert code == 2 and not any("Traceback" in line for line in err)
    assert any(all(f in line for f in fragments) for line in err), err
    assert snapshot(tmp_path) == before


@pytest.mark.parametrize("value", ["1e300", "20", "1e-12"])
def test_a_disturbance_beyond_the_filters_range_is_refused_before_any_work(tmp_path, capsys,
                                                                         value):
    """Squared in the filter, 1e300 N m overflows; it was refused only after the search."""
    shown = repr(float(value))
    refused(["identify", example(tmp_path), "--criterion", "prediction", "--disturbance", value,
             "--out", tmp_path / "f.json"], capsys, tmp_path,
            f"--disturbance {shown}: expected a process-noise torque from 1e-09 to 10 N m")
    records = [jaxflex.load_record(example(tmp_path))]
    with pytest.raises(ValueError, match=rf"^disturbance={re.escape(shown)}: expected a "):
        jaxflex.identify(records, criterion="prediction", disturbance=float(value))


def test_the_size_limit_can_be_raised(tmp_path, capsys, monkeypatch):
    monkeypatch.setenv("JAXFLEX_MAX_SAMPLES", "10")
    refused(["simulate", "--input", "pulse", "--out", tmp_path / "x.csv"], capsys, tmp_path,
            "size limit of 10", "JAXFLEX_MAX_SAMPLES")
    code, _ = run(["simulate", "--input", "pulse", "--duration", "0.1", "--max-samples", "1000",
                   "--out", tmp_path / "x.csv"], capsys)
    assert code == 0 and (tmp_path / "x.csv").exists()


# --- study methods --------------------------------------------------------------------------------


def test_repeated_method_is_refused(tmp_path, capsys):
    refused(["study", example(tmp_path), "--methods", "de,de", "--seeds", "0", "--out",
             tmp_path / "s.json"], capsys, tmp_path, "--methods 'de,de': 'de' given twice")


# --- the environment: checked before JAX starts, one line ---------------------------------------


def jaxflex_env(args, cwd: Path, **settings: str) -> subprocess.CompletedProcess:
    """``jaxflex ARGS`` in a fresh process with the environment variables ``settings``."""
    env = os.environ | {"PYTHONPATH": str(Path(jaxflex.__file__).parent.parent)} | settings
    return subprocess.run([sys.executable, "-m", "jaxflex", *map(str, args)], cwd=cwd, env=env,
                          capture_output=True, text=True, timeout=120)


@pytest.mark.parametrize("value", ["0", "", "abc", "-1"])
def test_a_bad_host_device_count_is_one_line(tmp_path, value):
    done = jaxflex_env(["arms", "list"], tmp_path, JAXFLEX_HOST_DEVICES=value)
    assert (done.returncode, done.stdout) == (2, "")
    assert done.stderr.splitlines() == [
        f"jaxflex arms: error: JAXFLEX_HOST_DEVICES={value!r} must be an integer >= 1 (the CPU "
        "devices to split populations over; unset it for one per usable core)"]


def test_a_host_device_count_beyond_the_machine_is_lowered_with_one_line(tmp_path):
    from jaxflex._host import host_device_ceiling, usable_cores

    done = jaxflex_env(["arms", "list"], tmp_path, JAXFLEX_HOST_DEVICES="100000")
    assert done.returncode == 0 and "quanser_rotflex" in done.stdout
    assert done.stderr.splitlines() == [
        f"jaxflex arms: warning: JAXFLEX_HOST_DEVICES=100000 is more than this machine can use "
        f"(its {usable_cores()} usable cores, or 8 at least); using {host_device_ceiling()} CPU "
        "devices"]


@pytest.mark.parametrize(("folder", "problem"), [
    ("afile", "not a directory"), ("afile/cache", "afile is not a directory")])
def test_an_unusable_cache_folder_is_one_line(tmp_path, folder, problem):
    (tmp_path / "afile").write_text("not a folder")
    env = {"JAX_COMPILATION_CACHE_DIR": "", "JAXFLEX_CACHE_DIR": folder}
    done = jaxflex_env(["simulate", "--input", "pulse", "--out", "s.csv"], tmp_path, **env)
    assert (done.returncode, done.stdout) == (2, "")
    assert done.stderr.splitlines() == [
        f"jaxflex simulate: error: JAXFLEX_CACHE_DIR={folder}: {problem}; set it to a folder "
        "this user may write, or to nothing (JAXFLEX_CACHE_DIR=) to keep no compiled programs"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["afile"]


# --- interruption ---------------------------------------------------------------------------------


def test_ctrl_c_is_one_line_and_leaves_nothing(monkeypatch, tmp_path, capsys):
    from matplotlib.figure import Figure

    def interrupted(self, fname, **kwargs):
        Path(fname).write_bytes(b"")  # half-way through the figure
        raise KeyboardInterrupt

    monkeypatch.setattr(Figure, "savefig", interrupted)
    code, err = run(["simulate", "--input", "pulse", "--duration", "0.1", "--out",
                     tmp_path / "s.csv", "--plot", tmp_path / "s.png"], capsys)
    assert code == 130
    assert err == ["jaxflex simulate: interrupted; no partial output was left"]
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize(("signum", "status", "word"), [
    (signal.SIGTERM, 143, "terminated"), (signal.SIGINT, 130, "interrupted")])
def test_signals_stop_with_one_line_and_no_files(tmp_path, signum, status, word):
    proc = jaxflex_subprocess(["demo", "--out", tmp_path / "demo"], tmp_path)
    assert proc.stdout.readline().startswith("== records")  # at work
    proc.send_signal(signum)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == status
    assert err.strip().splitlines() == [f"jaxflex demo: {word}; no partial output was left"]
    assert [p for p in tmp_path.rglob("*") if p.is_file()] == []


SWALLOWED_CTRL_C = """\
import os, signal, sys, time
from matplotlib.figure import Figure
from jaxflex.cli import main

save = Figure.savefig


def savefig(self, *args, **kwargs):
    try:  # Ctrl-C meets a bare `except:`, as in JAX's tracing: the KeyboardInterrupt is lost
        os.kill(os.getpid(), signal.SIGINT)
        time.sleep(5.0)
    except:  # noqa: E722
        pass
    return save(self, *args, **kwargs)


Figure.savefig = savefig
sys.exit(main(sys.argv[1:]))
"""


def test_ctrl_c_that_meets_a_bare_except_still_stops_the_command(tmp_path):
    """The command line ends on SIGINT itself, as on SIGTERM, not on an exception a library may
    swallow (the command would then go on and write its outputs, and exit 0)."""
    env = os.environ | {"PYTHONPATH": str(Path(jaxflex.__file__).parent.parent)}
    done = subprocess.run(
        [sys.executable, "-c", SWALLOWED_CTRL_C, "simulate", "--input", "pulse", "--duration",
         "0.1", "--out", "s.csv", "--plot", "s.png"], cwd=tmp_path, env=env,
        capture_output=True, text=True, timeout=120, preexec_fn=_default_sigint)
    assert (done.returncode, done.stderr) == (
        130, "jaxflex simulate: interrupted; no partial output was left\n")
    assert list(tmp_path.iterdir()) == []


LONG_COMPILED_CALL = """\
import sys
import jax
from jax import lax
from matplotlib.figure import Figure
from jaxflex.cli import main

endless = jax.jit(lambda x: lax.fori_loop(0, 10**12, lambda i, v: v * 0.5 + 1.0, x))


def savefig(self, *args, **kwargs):  # the CSV is staged; one compiled call that runs for hours
    print("calling", flush=True)
    endless(1.0).block_until_ready()


Figure.savefig = savefig
endless.lower(1.0).compile()
sys.exit(main(sys.argv[1:]))
"""


@pytest.mark.parametrize(("signum", "status", "word"), [
    (signal.SIGTERM, 143, "terminated"), (signal.SIGINT, 130, "interrupted")])
def test_signals_stop_a_long_compiled_call_at_once(tmp_path, signum, status, word):
    """Python runs a signal handler only between bytecodes, never inside one long XLA call:
    the command still ends within seconds, with one line, removing the staged output."""
    env = os.environ | {"PYTHONPATH": str(Path(jaxflex.__file__).parent.parent)}
    proc = subprocess.Popen(
        [sys.executable, "-c", LONG_COMPILED_CALL, "simulate", "--input", "pulse",
         "--duration", "0.1", "--out", "s.csv", "--plot", "s.png"], cwd=tmp_path, env=env,
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, preexec_fn=_default_sigint)
    try:
        assert proc.stdout.readline() == "calling\n"
        assert temp_files(tmp_path)  # the CSV is staged
        time.sleep(1.0)  # inside the call
        proc.send_signal(signum)
        start = time.monotonic()
        _, err = proc.communicate(timeout=30)
        took = time.monotonic() - start
    finally:
        proc.kill()
    assert proc.returncode == status
    assert took < 5.0
    assert err.strip().splitlines() == [f"jaxflex simulate: {word}; no partial output was left"]
    assert list(tmp_path.iterdir()) == []


def test_sigterm_in_the_api_leaves_no_staged_file(tmp_path):
    """Outside the command line too: SIGTERM inside all_or_nothing removes what was staged.
    The child starts with SIGTERM's default action whatever the test runner passed on (an
    ignored or blocked signal is inherited), and says what it was given."""
    script = ("import os, re, signal, sys, time\n"
              "status = '/proc/self/status'  # Linux: the signals blocked and ignored\n"
              "given = re.findall(r'Sig(?:Blk|Ign):\\s*\\S+', open(status).read()"
              " if os.path.exists(status) else '')\n"
              "signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGTERM})\n"
              "signal.signal(signal.SIGTERM, signal.SIG_DFL)\n"
              "from jaxflex._io import all_or_nothing, write_text\n"
              "with all_or_nothing():\n"
              "    write_text(sys.argv[1], 'first')\n"
              "    print('staged', *given, flush=True)\n"
              "    time.sleep(60)\n")
    env = os.environ | {"PYTHONPATH": str(Path(jaxflex.__file__).parent.parent)}
    proc = subprocess.Popen([sys.executable, "-c", script, str(tmp_path / "a.txt")], env=env,
                            stdout=subprocess.PIPE, text=True)
    staged = proc.stdout.readline()
    assert staged.startswith("staged"), staged
    assert len(temp_files(tmp_path)) == 1
    proc.send_signal(signal.SIGTERM)
    try:
        proc.communicate(timeout=60)
    except subprocess.TimeoutExpired:
        proc.kill()
        pytest.fail(f"SIGTERM did not stop the child; it was started with {staged.split()[1:]}")
    assert proc.returncode == 143
    assert list(tmp_path.iterdir()) == []


def test_debug_shows_the_traceback(tmp_path):
    from jaxflex.cli import UsageError

    with pytest.raises(UsageError, match="--set dt: use --dt instead"):
        main(["simulate", "--input", "pulse", "--set", "dt=1", "--out", str(tmp_path / "x.csv"),
              "--debug"])


def test_temp_file_of_a_killed_process_is_removed(tmp_path, capsys):
    stale = tmp_path / f".s.csv{TEMP_MARK}{2**22 + 12345}-dead"
    stale.write_bytes(b"")
    code, _ = run(["simulate", "--input", "pulse", "--duration", "0.1", "--out",
                   tmp_path / "s.csv"], capsys)
    assert code == 0 and not stale.exists() and (tmp_path / "s.csv").exists()


# --- inputs and implausible options ---------------------------------------------------------------


def test_an_input_is_never_an_output(tmp_path, capsys):
    rec = example(tmp_path, "data.csv")
    refused(["identify", rec, "--out", rec, "--overwrite"], capsys, tmp_path, "--out", "data.csv")
    report = tmp_path / "report"
    report.mkdir()
    fit = write_fit(report / "comparison.json", fit_data())
    refused(["validate", rec, "--fit", fit, "--report", report, "--overwrite"], capsys, tmp_path,
            "--report", "comparison.json: is an input of this command")


def test_a_held_out_record_that_is_also_fitted_is_refused(tmp_path, capsys):
    rec = example(tmp_path)
    refused(["discover", rec, "--holdout", rec], capsys, tmp_path,
            f"--holdout {rec}: is also a record to fit")


def test_resampling_names_the_gap(tmp_path, capsys):
    def gap(c):
        keep = np.ones(c["time"].shape, bool)
        keep[500:600] = False  # 100 ms of samples lost
        for k in c:
            c[k] = c[k][keep]

    path = rewrite(tmp_path, "gap.csv", gap)
    (tmp_path / "fit.json").write_text("{}")
    before = snapshot(tmp_path)
    proc = jaxflex_subprocess(["identify", path, "--resample", "--out", "fit.json"], tmp_path)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 2 and snapshot(tmp_path) == before
    warning, error = err.splitlines()  # one line each, no source line
    assert warning.startswith(f"jaxflex identify: warning: {path}: time column is not uniform")
    assert "the longest gap, line" in warning and "(0.101" in warning and "101 steps" in warning
    assert error == "jaxflex identify: error: --out fit.json: file exists; pass --overwrite to " \
                    "replace it"


def test_design_rms_torque_above_the_peak_is_refused(tmp_path, capsys):
    refused(["design", "--max-torque", "0.2", "--rms-torque", "0.5", "--max-angle", "1",
             "--max-speed", "5", "--out", tmp_path / "d.csv"], capsys, tmp_path,
            "--rms-torque 0.5 exceeds --max-torque 0.2")


def test_design_rms_torque_defaults_to_half_the_peak(monkeypatch, tmp_path, capsys):
    import functools

    module = importlib.import_module("jaxflex.design")
    seen = {}

    @functools.wraps(module.design_input)
    def spy(**kwargs):
        seen.update(kwargs)
        raise KeyboardInterrupt  # stop before the design: the settings are the point

    monkeypatch.setattr(module, "design_input", spy)
    code, _ = run(["design", "--max-torque", "0.8", "--max-angle", "1", "--max-speed", "5",
                   "--out", tmp_path / "d.csv"], capsys)
    assert code == 130 and seen["rms_torque"] == 0.4 and seen["max_torque"] == 0.8


@pytest.mark.slow
def test_design_without_information_is_not_written(tmp_path, capsys):
    refused(["design", "--max-torque", "0.5", "--max-angle", "1e-9", "--max-speed", "5",
             "--harmonics", "4", "--iterations", "1", "--out", tmp_path / "d.csv"],
            capsys, tmp_path, "unidentifiable (infinite intervals)", "--max-angle 1e-09")


def test_f_max_above_nyquist_is_refused(tmp_path, capsys):
    fit = write_fit(tmp_path / "fit.json", fit_data())
    refused(["validate", example(tmp_path), "--fit", fit, "--f-max", "1e6"], capsys, tmp_path,
            "--f-max 1e+06 Hz is above the records' Nyquist frequency 500 Hz")


# --- messages in the command line's words ---------------------------------------------------------


def test_quoted_header_and_excel_separator_line_are_read(tmp_path, capsys):
    text = EXAMPLE.read_text().splitlines()
    header = next(i for i, ln in enumerate(text) if not ln.startswith("#"))
    text[header] = ",".join(f'"{c}"' for c in text[header].split(","))
    path = tmp_path / "quoted.csv"
    path.write_text("\n".join(["sep=,", *text]) + "\n")
    (tmp_path / "fit.json").write_text("{}")
    refused(["identify", path, "--out", tmp_path / "fit.json"], capsys, tmp_path,
            "fit.json: file exists; pass --overwrite to replace it")


def test_a_text_file_named_npz_is_refused_saying_why(tmp_path, capsys):
    path = tmp_path / "r.npz"
    shutil.copy(EXAMPLE, path)
    refused(["identify", path, "--out", tmp_path / "fit.json"], capsys, tmp_path,
            "r.npz: not an NPZ file", "wrong suffix")


def test_the_same_file_given_twice_is_refused(tmp_path, capsys):
    rec = example(tmp_path)
    refused(["identify", rec, str(tmp_path / "." / rec.name), "--out", tmp_path / "f.json"],
            capsys, tmp_path, "rec.csv: record file given twice")


def test_option_errors_use_option_names(tmp_path, capsys):
    fit = write_fit(tmp_path / "fit.json", fit_data())
    code, err = run(["validate", example(tmp_path), "--fit", fit, "--t-end", "-1"], capsys)
    assert code == 2 and "argument --t-end" in err[-1] and "t_end=" not in "".join(err)


# --- timings only under "timing" ------------------------------------------------------------------


def test_times_are_kept_only_under_timing(tmp_path):
    data = fit_data()
    data["refinement"] |= {"wall_time": 0.5, "compile_time": 2.0}  # an older fit file
    fit = Fit.from_dict(data)
    assert fit.refinement.wall_time == 0.5
    written = fit.to_dict()
    assert "wall_time" not in written["refinement"] and "compile_time" not in written["refinement"]
    again = Fit.from_dict(written)
    assert again.refinement.wall_time == fit.timing["refine"]  # read back from "timing"


# --- the fitting options shared by identify, study and discover -----------------------------------


@pytest.mark.parametrize(("option", "value", "message"), [
    ("--bound", "J_h=5:1", "--bound J_h=5:1: lower bound 5.0 must be below upper 1.0"),
    ("--fix", "E=abc", "--fix E: 'abc' is not a number"),
    ("--weight", "joint_angle", "--weight 'joint_angle': expected CHANNEL=W"),
    ("--noise", "joint_angle=-1", "--noise joint_angle: '-1' must be > 0"),
    ("--effect", "warp", "--effect warp: unknown effect 'warp'"),
])
@pytest.mark.parametrize("command", ["identify", "study", "discover"])
def test_fitting_options_are_one_definition(tmp_path, capsys, command, option, value, message):
    out = {"identify": "--out", "study": "--out", "discover": "--json"}[command]
    refused([command, example(tmp_path), option, value, out, tmp_path / "o.json"], capsys,
            tmp_path, message)


def test_discover_passes_effects_and_noise_levels_on(monkeypatch, tmp_path, capsys):
    import functools

    module = importlib.import_module("jaxflex.discovery")
    seen = {}

    @functools.wraps(module.discover)
    def spy(records, **kwargs):
        seen.update(kwargs)
        raise KeyboardInterrupt  # stop here: what was passed is the point

    monkeypatch.setattr(module, "discover", spy)
    code, _ = run(["discover", example(tmp_path), "--effect", "payload", "--noise",
                   "joint_angle=2e-4", "--json", tmp_path / "d.json"], capsys)
    assert code == 130
    assert seen["model"].effect_names == ("payload",)
    assert {c: level.sigma for c, level in seen["noise"].items()} == {"joint_angle": 2e-4}
