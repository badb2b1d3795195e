"""jaxflex.datasets: pinned sources, hash-checked local copies and downloads, converted records.

Tests that need the real files use ``JAXFLEX_DATA_DIR`` (``make test`` points it at the shared
copy) or the network, and skip with the reason when neither is there.
"""

import functools
import http.server
import os
import shutil
import socket
import subprocess
import sys
import threading
from pathlib import Path

import numpy as np
import pytest
from helpers import REAL_DATA_DIR, or_skip

import jaxflex.datasets as datasets
from jaxflex.arm import load_arm
from jaxflex.cli import main
from jaxflex.data import load_record


@pytest.fixture(scope="module")
def rotflex():
    return or_skip(datasets.load, "quanser_rotflex", REAL_DATA_DIR)


@pytest.fixture(scope="module")
def rotflex_files():
    return or_skip(datasets.fetch, "quanser_rotflex", REAL_DATA_DIR)


def test_registry_pins_every_file_by_commit_and_sha256():
    for info in datasets.available():
        source = info.source
        assert len(source.commit) == 40 and int(source.commit, 16) >= 0
        assert source.licence in source.files
        for file, (upstream, sha) in source.files.items():
            assert len(sha) == 64 and int(sha, 16) >= 0
            assert source.url(file) == (
                f"https://raw.githubusercontent.com/{source.repository}/{source.commit}/{upstream}"
            )
    assert [i.name for i in datasets.available()] == sorted(datasets.DATASETS)
    assert set(datasets.DATASETS["quanser_rotflex"].records) == {"square_wave", "random_985"}


def test_unknown_data_set_and_bad_folder_are_named():
    with pytest.raises(datasets.DatasetError, match=r"unknown data set 'rotflex'; data sets: \["):
        datasets.load("rotflex", "/nonexistent")
    with pytest.raises(datasets.DatasetError, match="data_dir='/nonexistent' is not a directory"):
        datasets.load("quanser_rotflex", "/nonexistent")


def test_square_wave_is_the_500_hz_5_s_run(rotflex):
    record = rotflex["square_wave"]
    assert record.n_samples == 2500 and record.dt == pytest.approx(0.002, rel=1e-12)
    assert record.time[0] == pytest.approx(0.002) and record.time[-1] == pytest.approx(5.0)
    assert record.input_name == "voltage" and record.torque is None
    assert record.tip_acceleration is None
    assert np.max(np.abs(record.channel("voltage"))) == pytest.approx(6.2116, abs=1e-4)
    # ±30° set point, in radians; the encoder moves in whole counts of 2π/4096
    assert np.max(np.abs(record.channel("reference"))) == pytest.approx(np.pi / 6)
    counts = np.diff(record.joint_angle) / (2 * np.pi / 4096)
    np.testing.assert_allclose(counts, np.round(counts), atol=1e-9)
    assert 0.1 < np.max(np.abs(record.channel("deflection_angle"))) < 0.2  # about 10°


def test_random_985_is_the_1_khz_60_s_run(rotflex):
    record = rotflex["random_985"]
    assert record.n_samples == 60001 and record.dt == pytest.approx(1e-3, rel=1e-12)
    assert record.time[0] == 0.0 and record.duration == pytest.approx(60.0)
    assert np.max(np.abs(record.channel("voltage"))) == pytest.approx(1.8452, abs=1e-4)
    counts = np.diff(record.joint_angle) / (2 * np.pi / 4096)
    np.testing.assert_allclose(counts, np.round(counts), atol=1e-9)
    assert record.joint_angle[0] == 0.0 and record.channel("deflection_angle")[0] == 0.0


def test_records_carry_source_licence_and_citation(rotflex):
    for name, record in rotflex.items():
        meta = record.metadata
        assert meta["dataset"] == f"quanser_rotflex/{name}"
        assert meta["source"].startswith("github.com/frank1ma/DDRTC-of-UMSs @ 2e08b3a (MIT")
        assert "LICENSE.DDRTC-of-UMSs" in meta["licence"]
        assert "Ma and J.-Q. Sun" in meta["cite"]


def _copy_of(files: dict[str, Path], root: Path, name: str) -> Path:
    folder = root / name
    folder.mkdir(parents=True)
    for file, path in files.items():
        shutil.copyfile(path, folder / file)
    return folder


def test_a_local_copy_is_checked_against_the_hashes(rotflex_files, tmp_path):
    folder = _copy_of(rotflex_files, tmp_path, "quanser_rotflex")
    assert datasets.fetch("quanser_rotflex", tmp_path)["data_vm.mat"] == folder / "data_vm.mat"
    with open(folder / "data_vm.mat", "r+b") as f:  # flip one byte
        f.seek(200)
        byte = f.read(1)
        f.seek(200)
        f.write(bytes([byte[0] ^ 1]))
    with pytest.raises(datasets.DatasetError, match=r"data_vm.mat: SHA-256 is [0-9a-f]{64}, "):
        datasets.load("quanser_rotflex", tmp_path)
    (folder / "data_vm.mat").unlink()
    with pytest.raises(datasets.DatasetError, match="data_vm.mat: file not found; a local"):
        datasets.load("quanser_rotflex", tmp_path)


def test_environment_variable_names_the_local_copy(rotflex_files, tmp_path, monkeypatch):
    _copy_of(rotflex_files, tmp_path, "quanser_rotflex")
    monkeypatch.setenv(datasets.DATA_DIR_VARIABLE, str(tmp_path))
    assert datasets.fetch("quanser_rotflex")["theta985.mat"].parent == tmp_path / "quanser_rotflex"


class _QuietHandler(http.server.SimpleHTTPRequestHandler):
    def log_message(self, *args):
        pass


@pytest.fixture
def mirror(tmp_path, monkeypatch):
    """A local HTTP server laid out like raw.githubusercontent.com, and an empty user cache."""
    root = tmp_path / "mirror"
    root.mkdir()
    handler = functools.partial(_QuietHandler, directory=str(root))
    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), handler)
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    monkeypatch.setenv(datasets.URL_VARIABLE, f"http://127.0.0.1:{server.server_address[1]}/")
    monkeypatch.setenv(datasets.CACHE_DIR_VARIABLE, str(tmp_path / "cache"))
    monkeypatch.delenv(datasets.DATA_DIR_VARIABLE, raising=False)
    yield root
    server.shutdown()
    thread.join()


def test_download_fills_the_cache_and_checks_hashes(mirror, tmp_path):
    source = datasets.DATASETS["daisy_robot_arm"].source
    sweep = np.cos(0.05 * np.arange(64) ** 1.5)
    with pytest.raises(datasets.DataUnavailable, match="cannot download http://127.0.0.1"):
        datasets.load("daisy_robot_arm")  # the mirror is still empty: HTTP 404
    for file, (upstream, _) in source.files.items():
        target = mirror / source.repository / source.commit / upstream
        target.parent.mkdir(parents=True, exist_ok=True)
        target.write_bytes(sweep.tobytes() + file.encode())  # not the published bytes
    with pytest.raises(datasets.DatasetError, match="SHA256 hash of downloaded file"):
        datasets.load("daisy_robot_arm")
    assert not list((tmp_path / "cache").rglob("*.mat"))  # nothing unverified is kept


def test_download_of_the_published_files(mirror, tmp_path):
    files = or_skip(datasets.fetch, "daisy_robot_arm", REAL_DATA_DIR)
    source = datasets.DATASETS["daisy_robot_arm"].source
    for file, (upstream, _) in source.files.items():
        target = mirror / source.repository / source.commit / upstream
        target.parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(files[file], target)
    record = datasets.load("daisy_robot_arm")["sweep"]
    cached = tmp_path / "cache" / "daisy_robot_arm" / "robot_arm_dat.mat"
    assert cached.read_bytes() == files["robot_arm_dat.mat"].read_bytes()
    assert record.columns == ("time", "torque", "acceleration") and record.n_samples == 1024
    assert record.dt == pytest.approx(load_arm("daisy_robot_arm").testbed.dt, rel=1e-12)
    assert "the sampling period is unpublished" in record.metadata["channels"]
    shutil.rmtree(mirror / source.repository)  # now served from the cache alone
    assert datasets.load("daisy_robot_arm")["sweep"].n_samples == 1024


def test_two_link_rig_is_refused_with_the_reason(tmp_path):
    or_skip(datasets.fetch, "quanser_2dsfl", REAL_DATA_DIR)
    with pytest.raises(datasets.DatasetError, match="quanser_2dsfl: a two-link arm"):
        datasets.load("quanser_2dsfl", REAL_DATA_DIR)


def test_cli_list_and_get(rotflex, tmp_path, capsys, monkeypatch):
    assert main(["datasets", "list"]) == 0
    listing = capsys.readouterr().out
    assert "quanser_rotflex:" in listing and "    random_985: closed loop" in listing
    folder = REAL_DATA_DIR
    args = ["datasets", "get", "quanser_rotflex", "--out", str(tmp_path / "d")]
    args += ["--data-dir", folder] if folder else []
    assert main(args) == 0
    for name, record in rotflex.items():
        again = load_record(tmp_path / "d" / f"{name}.csv")
        assert again.columns == record.columns and again.metadata == record.metadata
        for column in record.columns:
            np.testing.assert_array_equal(again.channel(column), record.channel(column))
    capsys.readouterr()
    assert main(args) == 2
    assert capsys.readouterr().err == (
        f"jaxflex datasets: error: {tmp_path / 'd' / 'square_wave.csv'}: file exists; pass "
        "--overwrite to replace it\n"
    )
    assert main(["datasets", "get", "nope", "--out", str(tmp_path)]) == 2
    assert "unknown data set 'nope'" in capsys.readouterr().err


def data_dir_option() -> list[str]:
    return ["--data-dir", REAL_DATA_DIR] if REAL_DATA_DIR else []


@pytest.mark.parametrize("obstacle", ["directory", "dangling link"])
@pytest.mark.parametrize("blocked", ["square_wave", "random_985"])
def test_get_checks_every_file_before_it_writes_any(rotflex, tmp_path, capsys, obstacle,
                                                    blocked):
    assert list(rotflex) == ["square_wave", "random_985"]  # the order they are written in
    out = tmp_path / "d"
    out.mkdir()
    target = out / f"{blocked}.csv"
    if obstacle == "directory":
        target.mkdir()
    else:
        target.symlink_to(tmp_path / "nowhere" / "x.csv")
    assert main(["datasets", "get", "quanser_rotflex", "--out", str(out),
                 *data_dir_option()]) == 2
    why = ("is a directory; give a file name inside it" if obstacle == "directory"
           else "file exists; pass --overwrite to replace it")
    assert capsys.readouterr().err == f"jaxflex datasets: error: {target}: {why}\n"
    assert os.listdir(out) == [target.name]  # nothing was written beside it
    assert not (tmp_path / "nowhere").exists()


def test_get_refuses_an_empty_out(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert main(["datasets", "get", "quanser_rotflex", "--out", "", *data_dir_option()]) == 2
    assert capsys.readouterr().err == (
        "jaxflex datasets: error: --out '': names no folder; give the folder for the record "
        "files\n"
    )
    assert os.listdir(tmp_path) == []
    with pytest.raises(datasets.DatasetError, match="^out='' names no folder; give the folder"):
        datasets.write("quanser_rotflex", "")


def closed_port() -> int:
    """A TCP port on 127.0.0.1 that nothing listens on (bound, then released)."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_a_failed_download_is_one_line_and_leaves_nothing(tmp_path, monkeypatch):
    monkeypatch.setenv(datasets.URL_VARIABLE, f"http://127.0.0.1:{closed_port()}")
    monkeypatch.setenv(datasets.CACHE_DIR_VARIABLE, str(tmp_path / "cache"))
    monkeypatch.delenv(datasets.DATA_DIR_VARIABLE, raising=False)
    done = subprocess.run(
        [sys.executable, "-m", "jaxflex", "datasets", "get", "daisy_robot_arm", "--out",
         str(tmp_path / "d")], capture_output=True, text=True, timeout=120,
    )
    source = datasets.DATASETS["daisy_robot_arm"].source
    first = next(iter(source.files))
    assert (done.returncode, done.stdout) == (2, "")
    assert done.stderr == (
        f"jaxflex datasets: error: daisy_robot_arm: cannot download {source.url(first)} "
        "(ConnectionError); set JAXFLEX_DATA_DIR (or pass data_dir) to a local copy laid out "
        f"as <folder>/daisy_robot_arm/{first}\n"
    )
    assert os.listdir(tmp_path) == []  # no cache folder, no output folder


def test_a_mirror_replaces_the_upstream_host(monkeypatch):
    source = datasets.DATASETS["quanser_rotflex"].source
    monkeypatch.setenv(datasets.URL_VARIABLE, "http://127.0.0.1:1/mirror/")
    for file, (upstream, _) in source.files.items():
        assert source.url(file) == (
            f"http://127.0.0.1:1/mirror/{source.repository}/{source.commit}/{upstream}"
        )
