"""Safe file output: atomic writes that never overwrite a user's file unasked; provenance.

Every file jaxflex writes goes through :func:`atomic_write`: the contents go to a hidden
temporary file next to the target (``.NAME.jaxflex-tmp-PID-XXXX``), which is renamed over the
target in one step. So a reader never sees half a file, and a crash leaves the old file intact.

* Permissions are those of an ordinary new file (``0666`` less the umask); a replaced file keeps
  its mode. A symbolic link is kept: the file it points to is replaced.
* The temporary file is removed on every error, on Ctrl-C and on SIGTERM (the command line's
  SIGTERM handler calls :func:`remove_temporaries` and exits; elsewhere SIGTERM inside a write
  does the same, then raises ``SystemExit(143)``). A temporary file left by a killed process
  (SIGKILL) is removed by the next write of the same target.
* :func:`all_or_nothing` groups the writes of one command: files appear together when the block
  ends, and none of them if it fails.
"""

from __future__ import annotations

import contextlib
import contextvars
import json
import os
import platform
import re
import secrets
import stat
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

TEMP_MARK = ".jaxflex-tmp-"
"""Part of the name of every temporary file (``.NAME.jaxflex-tmp-PID-XXXX``)."""
_LIVE: set[Path] = set()
"""Temporary files of this process not yet renamed or removed (see :func:`remove_temporaries`)."""
_CREATED: list[Path] = []
"""Directories made for outputs not yet in place (removed again, when empty, on failure)."""


class OutputError(ValueError):
    """An output path that cannot be written; the message names it and says what to do."""


class OutputExistsError(OutputError, FileExistsError):
    """Raised when an output file exists and overwriting was not asked for."""


def safe_stem(name: str) -> str:
    """A record name as a file-name stem (characters other than letters, digits, ``.-_``
    become ``_``)."""
    return re.sub(r"[^\w.-]+", "_", name).strip("._") or "record"


def check_writable(
    path: str | os.PathLike, overwrite: bool = False, *, suffixes: Iterable[str] | None = None
) -> Path:
    """``path`` as a Path after checking that a file can be written there, before any work.

    Refused (:class:`OutputError`): a directory; an existing file unless ``overwrite``
    (:class:`OutputExistsError`); a suffix not in ``suffixes`` (e.g. ``(".csv", ".npz")``); a
    parent that is a file; a directory that is not writable.
    """
    path = Path(path)
    if path.is_dir():
        raise OutputError(f"{path}: is a directory; give a file name inside it")
    if suffixes is not None:
        allowed = tuple(s.lower() for s in suffixes)
        if path.suffix.lower() not in allowed:
            raise OutputError(
                f"{path}: unsupported file type {path.suffix or '(none)'!r}; the name must end "
                f"in {' or '.join(', '.join(allowed).rsplit(', ', 1))}"
            )
    if (path.exists() or path.is_symlink()) and not overwrite:
        raise OutputExistsError(
            f"{path}: file exists; pass overwrite=True (CLI: --overwrite) to replace it"
        )
    target = _target(path)
    ancestor = _existing_ancestor(target.parent)
    if not ancestor.is_dir():
        raise OutputError(f"{path}: {ancestor} is a file, not a directory")
    if not os.access(ancestor, os.W_OK | os.X_OK):
        raise OutputError(
            f"{path}: directory {ancestor} is not writable; choose another location or "
            "change its permissions"
        )
    return path


def atomic_write(
    path: str | os.PathLike, write: Callable[[Path], None], *, overwrite: bool = False
) -> Path:
    """Write a file through ``write(tmp_path)`` then rename it into place in one step.

    A crash half-way leaves the previous file (if any) untouched, never a truncated one, and no
    temporary file. Inside :func:`all_or_nothing` the rename waits for the end of the block.
    """
    path = check_writable(path, overwrite)
    target = _target(path)
    batch = _BATCH.get()
    created = _make_parents(target.parent)
    if batch is not None:
        batch.created_dirs += created
        _CREATED.extend(created)
    _remove_stale_temps(target)
    mode = _mode_for(target)
    tmp = target.with_name(f".{target.name}{TEMP_MARK}{os.getpid()}-{secrets.token_hex(4)}")
    _LIVE.add(tmp)
    with _sigterm_unwinds():
        try:
            _write_and_place(tmp, target, write, mode, batch, path)
        except BaseException:  # an error, Ctrl-C or SIGTERM: no temporary file stays
            _unlink(tmp)
            raise
    return path


def remove_temporaries() -> None:
    """Remove every temporary file this process has not placed yet, and the output directories
    made for them that are still empty: what a signal handler calls before the process ends."""
    for tmp in list(_LIVE):
        _unlink(tmp)
    for directory in reversed(list(_CREATED)):
        with contextlib.suppress(OSError):
            directory.rmdir()
    _CREATED.clear()


def _write_and_place(tmp: Path, target: Path, write: Callable[[Path], None], mode: int,
                     batch: _Batch | None, path: Path) -> None:
    """Write ``tmp``, give it ``mode`` and rename it onto ``target`` (or stage it in
    ``batch``)."""
    try:
        os.close(os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600))
        write(tmp)
        os.chmod(tmp, mode)
        if batch is not None:
            batch.staged.append((tmp, target))
        else:
            os.replace(tmp, target)
            _LIVE.discard(tmp)
    except OSError as exc:
        raise OutputError(
            f"{path}: cannot write ({exc.strerror or exc}); nothing was written there"
        ) from exc


@dataclass
class _Batch:
    staged: list[tuple[Path, Path]] = field(default_factory=list)
    created_dirs: list[Path] = field(default_factory=list)

    def commit(self) -> None:
        for tmp, target in self.staged:
            os.replace(tmp, target)
            _LIVE.discard(tmp)
        self.staged.clear()

    def discard(self) -> None:
        for tmp, _ in self.staged:
            _unlink(tmp)
        self.staged.clear()
        for directory in reversed(self.created_dirs):
            with contextlib.suppress(OSError):
                directory.rmdir()  # only if still empty
        for directory in self.created_dirs:
            with contextlib.suppress(ValueError):
                _CREATED.remove(directory)
        self.created_dirs.clear()


_BATCH: contextvars.ContextVar[_Batch | None] = contextvars.ContextVar("_BATCH", default=None)


@contextlib.contextmanager
def all_or_nothing() -> Iterator[None]:
    """Group the writes inside the block: they appear together at its end, or not at all.

    On any exception (Ctrl-C included) the staged temporary files and the directories created
    for them are removed. A nested block joins the outer one.
    """
    if _BATCH.get() is not None:
        yield
        return
    batch = _Batch()
    token = _BATCH.set(batch)
    try:
        with _sigterm_unwinds():
            yield
            batch.commit()
    finally:
        batch.discard()
        _BATCH.reset(token)


@contextlib.contextmanager
def _sigterm_unwinds() -> Iterator[None]:
    """Inside the block, SIGTERM raises ``SystemExit(143)`` instead of killing the process at
    once, so that temporary files are removed; only where nobody handles SIGTERM already (the
    command line does), and only in the main thread."""
    import signal
    import threading

    if (threading.current_thread() is not threading.main_thread()
            or signal.getsignal(signal.SIGTERM) is not signal.SIG_DFL):
        yield
        return

    def terminate(signum, frame):
        remove_temporaries()  # first: the exception below may meet a bare `except:`
        raise SystemExit(128 + signum)

    signal.signal(signal.SIGTERM, terminate)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, signal.SIG_DFL)


def write_text(path: str | os.PathLike, text: str, *, overwrite: bool = False) -> Path:
    """Atomically write a text file."""
    return atomic_write(path, lambda p: p.write_text(text, encoding="utf-8"), overwrite=overwrite)


def write_json(path: str | os.PathLike, data: Any, *, overwrite: bool = False) -> Path:
    """Atomically write ``data`` as indented JSON (NumPy/JAX scalars and arrays converted)."""
    return write_text(path, json.dumps(to_jsonable(data), indent=2) + "\n", overwrite=overwrite)


def same_file(a: str | os.PathLike, b: str | os.PathLike) -> bool:
    """Whether two paths name one file (links and ``..`` resolved; also for missing files)."""
    try:
        return os.path.samefile(a, b)
    except OSError:
        return os.path.realpath(a) == os.path.realpath(b)


# --- helpers ------------------------------------------------------------------------------------


def _target(path: Path) -> Path:
    """The file a write to ``path`` replaces: the end of a symbolic link chain, else ``path``."""
    return Path(os.path.realpath(path)) if path.is_symlink() else path


def _existing_ancestor(directory: Path) -> Path:
    directory = Path(os.path.abspath(directory))
    while not directory.exists() and directory != directory.parent:
        directory = directory.parent
    return directory


def _make_parents(directory: Path) -> list[Path]:
    """Create ``directory`` and missing parents; returns the ones created, outermost first."""
    missing = []
    d = Path(os.path.abspath(directory))
    while not d.exists():
        missing.append(d)
        d = d.parent
    for d in reversed(missing):
        d.mkdir()
    return list(reversed(missing))


def _umask() -> int:
    with contextlib.suppress(OSError, ValueError):
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("Umask:"):
                return int(line.split()[1], 8)
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def _mode_for(target: Path) -> int:
    """The mode of the file being replaced, else an ordinary new file's (0666 less umask)."""
    try:
        return stat.S_IMODE(os.stat(target).st_mode)
    except OSError:
        return 0o666 & ~_umask()


def _remove_stale_temps(target: Path) -> None:
    """Remove temporary files of ``target`` left by processes that no longer run."""
    prefix = f".{target.name}{TEMP_MARK}"
    with contextlib.suppress(OSError):
        for entry in target.parent.iterdir():
            if not entry.name.startswith(prefix):
                continue
            pid = entry.name[len(prefix):].split("-", 1)[0]
            if pid.isdigit() and not _alive(int(pid)):
                _unlink(entry)


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except OSError:
        return True
    return True


def _unlink(path: Path) -> None:
    with contextlib.suppress(FileNotFoundError):
        path.unlink()
    _LIVE.discard(path)


def to_jsonable(value: Any) -> Any:
    """Convert arrays, NumPy scalars and tuples into plain JSON values (NaN/inf become None)."""
    import numpy as np

    if isinstance(value, dict):
        return {str(k): to_jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [to_jsonable(v) for v in value]
    if hasattr(value, "__array__") and not isinstance(value, (str, bytes)):
        arr = np.asarray(value)
        if arr.ndim == 0:
            return to_jsonable(arr.item())
        return [to_jsonable(v) for v in arr.tolist()]
    if isinstance(value, float) and not np.isfinite(value):
        return None
    if isinstance(value, (np.floating, np.integer, np.bool_)):
        return to_jsonable(value.item())
    return value


def provenance() -> dict[str, Any]:
    """Versions and machine facts recorded in every results file."""
    from importlib import metadata

    versions = {}
    packages = ("jaxflex", "jax", "jaxlib", "equinox", "optimistix", "jaxopt", "numpy", "scipy")
    for package in packages:
        try:
            versions[package] = metadata.version(package)
        except metadata.PackageNotFoundError:
            versions[package] = None
    return {
        "versions": versions,
        "python": platform.python_version(),
        "machine": {
            "platform": platform.platform(),
            "processor": platform.processor() or platform.machine(),
            "cpu_count": os.cpu_count(),
        },
    }
