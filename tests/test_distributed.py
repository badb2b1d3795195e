"""Two processes on JAX's multi-process runtime give the fit of one process with two devices;
a group that cannot form, or loses a process, stops at once with one line and leaves no process
behind."""

from __future__ import annotations

import contextlib
import json
import os
import signal
import subprocess
import sys
import time

import pytest

from jaxflex.cli import main
from jaxflex.data import save_record
from jaxflex.distributed import STOP_S, free_port
from jaxflex.parallel import usable_cores
from jaxflex.synthetic import make_records

SEARCH = ["--generations", "3", "--population", "40", "--no-refine", "--quiet"]


@pytest.fixture(scope="module")
def record(tmp_path_factory):
    path = tmp_path_factory.mktemp("distributed") / "pulse.csv"
    save_record(make_records(seed=2, duration=0.3, inputs=("pulse",))[0], path)
    return str(path)


def jaxflex(args: list[str], devices: int) -> subprocess.CompletedProcess:
    env = {**os.environ, "JAXFLEX_HOST_DEVICES": str(devices), "JAX_PLATFORMS": "cpu"}
    return subprocess.run([sys.executable, "-m", "jaxflex", *args], env=env,
                          capture_output=True, text=True, timeout=600)


def run_one_and_two(tmp_path, command: list[str]) -> dict[str, dict]:
    """The JSON that ``command`` writes with one process of two devices and with two processes
    of one device each (started by ``--processes 2``)."""
    results = {}
    for label, devices, extra in (("one", 2, []), ("two", 1, ["--processes", "2"])):
        out = tmp_path / f"{label}.json"
        done = jaxflex([*command, *SEARCH, *extra, "--out", str(out)], devices)
        assert done.returncode == 0, done.stderr[-3000:]
        assert done.stdout.count(f"wrote {out}") == 1  # process 0 alone prints and writes
        assert "[Gloo]" not in done.stdout  # the collectives' greeting is not a result
        results[label] = json.loads(out.read_text())
    return results


def test_a_study_on_two_processes_finds_the_parameters_of_one(tmp_path, record):
    """Same seeds → the same parameters, costs and histories, to the bit: each generation's
    population is split over the two processes' devices exactly as over two devices of one."""
    studies = run_one_and_two(tmp_path, ["study", record, "--methods", "de", "--seeds", "4,5"])
    for one, two in zip(studies["one"]["runs"], studies["two"]["runs"], strict=True):
        assert (two["seed"], two["params"]) == (one["seed"], one["params"])
        assert (two["cost"], two["history"]) == (one["cost"], one["history"])


@pytest.mark.slow
def test_identify_on_two_processes_finds_the_parameters_of_one(tmp_path, record):
    fits = run_one_and_two(tmp_path, ["identify", record, "--seed", "5"])
    for key in ("params", "cost", "history", "intervals"):
        assert fits["two"][key] == fits["one"][key]


def test_a_failing_group_stops_with_one_message(tmp_path):
    done = jaxflex(["identify", str(tmp_path / "missing.csv"), "--processes", "2", "--out",
                    str(tmp_path / "fit.json")], 1)
    assert done.returncode == 2
    assert done.stderr.count("missing.csv: record file not found") == 1


def commands_naming(marker: str) -> list[str]:
    """Command lines of the running processes that contain ``marker`` (Linux /proc)."""
    return list(processes_naming(marker).values())


def processes_naming(marker: str) -> dict[int, str]:
    """``pid → command line`` of the running processes whose command line contains ``marker``
    (Linux /proc; zombies, which have none, left out)."""
    found = {}
    for entry in os.listdir("/proc"):
        if not entry.isdigit():
            continue
        try:
            with open(f"/proc/{entry}/cmdline", "rb") as f:
                line = f.read().replace(b"\0", b" ").decode(errors="replace")
        except (OSError, ValueError):
            continue
        if marker in line:
            found[int(entry)] = line
    return found


def connected(port: int) -> bool:
    """Whether a TCP connection to ``port`` on this machine is established (Linux /proc)."""
    for table in ("/proc/net/tcp", "/proc/net/tcp6"):
        with open(table) as f:
            for line in f.readlines()[1:]:
                local, remote, state = line.split()[1:4]
                ports = {int(local.split(":")[1], 16), int(remote.split(":")[1], 16)}
                if state == "01" and port in ports:
                    return True
    return False


@pytest.fixture
def started_group(tmp_path, record):
    """A launcher of a long two-process study, once its group has joined JAX's runtime (which
    handles SIGTERM itself until then), and the study's output path; whatever of it is left
    running at the end of the test is killed."""
    out = str(tmp_path / "s.json")
    env = {**os.environ, "JAXFLEX_HOST_DEVICES": "1", "JAX_PLATFORMS": "cpu"}
    launcher = subprocess.Popen(
        [sys.executable, "-m", "jaxflex", "study", record, "--methods", "de", "--seeds", "0",
         "--generations", "100", "--quiet", "--processes", "2", "--out", out],
        env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )
    deadline = time.monotonic() + 120
    while not (child := commands_naming(f"{out} --process-id 1")) or not connected(
        int(child[0].split("--coordinator localhost:")[1].split()[0])
    ):
        if time.monotonic() > deadline or launcher.poll() is not None:
            launcher.kill()
            pytest.fail(f"the group did not start: {launcher.communicate(timeout=60)}")
        time.sleep(0.2)
    time.sleep(2.0)
    yield launcher, out
    launcher.kill()
    for pid in processes_naming(out):
        with contextlib.suppress(ProcessLookupError):
            os.kill(pid, signal.SIGKILL)
    launcher.communicate(timeout=60)


def gone(marker: str, within: float) -> bool:
    """Whether no process names ``marker`` within ``within`` seconds."""
    deadline = time.monotonic() + within
    while processes_naming(marker):
        if time.monotonic() > deadline:
            return False
        time.sleep(0.1)
    return True


needs_proc = pytest.mark.skipif(not os.path.isdir("/proc"), reason="lists processes in /proc")


@needs_proc
@pytest.mark.parametrize(
    ("signum", "status", "line"),
    [
        (signal.SIGTERM, 143, "jaxflex study: terminated; no partial output was left\n"),
        (signal.SIGINT, 130, "jaxflex study: interrupted; no partial output was left\n"),
    ],
)
def test_a_terminated_launcher_stops_its_group(started_group, signum, status, line):
    launcher, out = started_group
    sent = time.monotonic()
    launcher.send_signal(signum)  # Ctrl-C reaches the launcher alone: its group is its own
    _, err = launcher.communicate(timeout=60)
    assert time.monotonic() - sent < STOP_S  # each process stopped on SIGTERM, none was killed
    assert launcher.returncode == status
    assert err == line  # the launcher's, for the group
    assert not commands_naming(out)  # the launcher's and its group's
    assert not os.path.exists(out)


@needs_proc
def test_a_killed_launcher_takes_its_group_with_it(started_group):
    launcher, out = started_group
    group = processes_naming(f"{out} --process-id")
    assert len(group) == 2
    launcher.kill()  # SIGKILL: the launcher stops nothing itself
    launcher.communicate(timeout=60)
    assert gone(out, within=10.0), processes_naming(out)  # no orphan runs on
    assert not os.path.exists(out)


@needs_proc
def test_a_killed_rank_is_named_and_its_group_stopped(started_group):
    launcher, out = started_group
    (rank_1,) = processes_naming(f"{out} --process-id 1")
    os.kill(rank_1, signal.SIGKILL)
    _, err = launcher.communicate(timeout=60)
    assert launcher.returncode == 1
    assert err == (
        "jaxflex study: error: rank 1 killed by SIGKILL; the group was stopped and wrote nothing\n"
    )
    assert gone(out, within=1.0)
    assert not os.path.exists(out)


def test_a_group_larger_than_the_cores_is_refused_before_it_starts(tmp_path, record, capsys):
    cores = usable_cores()
    out = tmp_path / "fit.json"
    assert main(["identify", record, *SEARCH, "--processes", str(cores + 1), "--out",
                 str(out)]) == 2
    assert capsys.readouterr().err == (
        f"jaxflex identify: error: --processes {cores + 1}: more processes than the {cores} "
        f"usable cores of this machine; give at most {cores}, or start the processes yourself "
        "with --process-id and --coordinator (one per host)\n"
    )
    assert not processes_naming(f"{out} --process-id") and not out.exists()


@pytest.mark.parametrize(
    ("where", "message"),
    [
        ("pulse.csv/fit.json", "--out {tmp}/pulse.csv/fit.json: {tmp}/pulse.csv is a file, not a "
                               "directory"),
        ("old.json", "--out {tmp}/old.json: file exists; pass --overwrite to replace it"),
        ("fit.txt", "--out {tmp}/fit.txt: unsupported file type '.txt'; the name must end in "
                    ".json"),
    ],
)
def test_the_launcher_checks_the_outputs_before_any_process_starts(tmp_path, record, capsys,
                                                                   where, message):
    (tmp_path / "pulse.csv").write_text(open(record).read())
    (tmp_path / "old.json").write_text("{}")
    started = time.monotonic()
    assert main(["study", str(tmp_path / "pulse.csv"), *SEARCH, "--processes", "2", "--out",
                 str(tmp_path / where)]) == 2
    assert capsys.readouterr().err == f"jaxflex study: error: {message.format(tmp=tmp_path)}\n"
    assert time.monotonic() - started < 5.0  # no process was started to find it out
    assert (tmp_path / "old.json").read_text() == "{}"


@pytest.mark.parametrize(
    ("data", "options", "message"),
    [
        (None, ["--seeds", "3-1"], "--seeds '3-1': the range runs backwards"),
        ("missing.csv", [], "{tmp}/missing.csv: record file not found"),
    ],
)
def test_the_launcher_checks_the_inputs_before_any_process_starts(tmp_path, record, capsys,
                                                                  data, options, message):
    data = record if data is None else str(tmp_path / data)
    started = time.monotonic()
    assert main(["study", data, *SEARCH, *options, "--processes", "2", "--out",
                 str(tmp_path / "s.json")]) == 2
    assert capsys.readouterr().err == f"jaxflex study: error: {message.format(tmp=tmp_path)}\n"
    assert time.monotonic() - started < 5.0


def test_a_missing_peer_is_given_up_after_the_peer_timeout(tmp_path, record):
    port = free_port()
    started = time.monotonic()
    done = jaxflex(["identify", record, "--processes", "2", "--process-id", "0", "--coordinator",
                    f"localhost:{port}", "--peer-timeout", "2", "--out",
                    str(tmp_path / "fit.json")], 1)
    assert time.monotonic() - started < 60
    assert done.returncode == 2
    assert done.stderr == (
        f"jaxflex identify: error: the group of 2 processes did not form within 2 s (coordinator "
        f"localhost:{port}): a process has not started or cannot reach the coordinator; start "
        "every process with the same --processes and --coordinator, or wait longer with "
        "--peer-timeout SECONDS\n"
    )
    assert not (tmp_path / "fit.json").exists()


def listening(port: int) -> bool:
    """Whether a TCP socket listens on ``port`` on this machine (Linux /proc)."""
    for table in ("/proc/net/tcp", "/proc/net/tcp6"):
        with open(table) as f:
            for line in f.readlines()[1:]:
                local, _, state = line.split()[1:4]
                if state == "0A" and int(local.split(":")[1], 16) == port:
                    return True
    return False


@needs_proc
@pytest.mark.parametrize(
    ("signum", "status", "line"),
    [
        (signal.SIGINT, 130, "jaxflex identify: interrupted; no partial output was left\n"),
        (signal.SIGTERM, 143, "jaxflex identify: terminated; no partial output was left\n"),
    ],
)
def test_signals_stop_the_wait_for_a_missing_peer(tmp_path, record, signum, status, line):
    port = free_port()
    env = {**os.environ, "JAXFLEX_HOST_DEVICES": "1", "JAX_PLATFORMS": "cpu"}
    waiting = subprocess.Popen(
        [sys.executable, "-m", "jaxflex", "identify", record, "--processes", "2", "--process-id",
         "0", "--coordinator", f"localhost:{port}", "--out", str(tmp_path / "fit.json")],
        env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )
    deadline = time.monotonic() + 60
    while not listening(port):  # process 0's coordinator is up: it waits for process 1
        if time.monotonic() > deadline or waiting.poll() is not None:
            waiting.kill()
            pytest.fail(f"the coordinator did not start: {waiting.communicate(timeout=60)}")
        time.sleep(0.1)
    time.sleep(1.0)
    waiting.send_signal(signum)
    try:
        out, err = waiting.communicate(timeout=10)
    finally:
        waiting.kill()
    assert (waiting.returncode, out, err) == (status, "", line)


def test_a_stale_coordinator_address_is_named(tmp_path, record, monkeypatch):
    monkeypatch.setenv("JAX_COORDINATOR_ADDRESS", "localhost:1")
    done = jaxflex(["study", record, "--out", str(tmp_path / "s.json")], 1)
    assert (done.returncode, done.stdout) == (2, "")
    assert done.stderr == (
        "jaxflex study: error: JAX_COORDINATOR_ADDRESS=localhost:1 is set, but neither "
        "--processes and --process-id nor a cluster environment say which group this process "
        "belongs to; give --processes N --process-id I, or unset JAX_COORDINATOR_ADDRESS to run "
        "as one process\n"
    )


@pytest.mark.parametrize(
    ("options", "message"),
    [
        (["--process-id", "0"], "--process-id needs --processes (the size of the group)"),
        (["--processes", "2", "--process-id", "2", "--coordinator", "localhost:1"],
         "--process-id 2: expected 0 ... 1"),
        (["--processes", "2", "--coordinator", "localhost:1"],
         "--coordinator needs --process-id (this process's place in the group)"),
    ],
)
def test_settings_that_describe_no_group_are_refused(tmp_path, record, capsys, options, message):
    assert main(["study", record, *options, "--out", str(tmp_path / "s.json")]) == 2
    assert capsys.readouterr().err == f"jaxflex study: error: {message}\n"
    assert not (tmp_path / "s.json").exists()


def test_identify_refuses_a_record_its_rig_cannot_read_before_any_process_starts(
    tmp_path, record, capsys
):
    assert main(["identify", record, "--arm", "quanser_rotflex", "--processes", "2",
                 "--out", str(tmp_path / "fit.json")]) == 2
    error = capsys.readouterr().err
    assert error.startswith("jaxflex identify: error: record ") and error.count("\n") == 1
    assert "logs 'torque' but rig 'quanser_rotflex' has a voltage drive" in error
