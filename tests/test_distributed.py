"""Two processes on JAX's multi-process runtime give the fit of one process with two devices."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time

import pytest

from jaxflex.cli import main
from jaxflex.data import save_record
from jaxflex.distributed import STOP_S
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
    found = []
    for entry in os.listdir("/proc"):
        try:
            with open(f"/proc/{entry}/cmdline", "rb") as f:
                line = f.read().replace(b"\0", b" ").decode(errors="replace")
        except (OSError, ValueError):
            continue
        if marker in line and entry.isdigit():
            found.append(line)
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


@pytest.mark.skipif(not os.path.isdir("/proc"), reason="lists processes through /proc")
def test_a_terminated_launcher_stops_its_group(tmp_path, record):
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
    ):  # terminated once the group has joined JAX's runtime (which handles SIGTERM itself)
        assert time.monotonic() < deadline and launcher.poll() is None
        time.sleep(0.2)
    time.sleep(2.0)
    sent = time.monotonic()
    launcher.terminate()
    _, err = launcher.communicate(timeout=60)
    assert time.monotonic() - sent < STOP_S  # each process stopped on SIGTERM, none was killed
    assert launcher.returncode == 143
    assert err.endswith("jaxflex study: terminated; no partial output was left\n")
    assert not commands_naming(out)  # the launcher's and its group's
    assert not os.path.exists(out)


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
