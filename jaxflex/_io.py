"""Safe file output: atomic writes that never overwrite a user's file unasked; provenance."""

from __future__ import annotations

import json
import os
import platform
import re
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import Any


class OutputExistsError(FileExistsError):
    """Raised when an output file exists and overwriting was not asked for."""


def safe_stem(name: str) -> str:
    """A record name as a file-name stem (characters other than letters, digits, ``.-_``
    become ``_``)."""
    return re.sub(r"[^\w.-]+", "_", name).strip("._") or "record"


def check_writable(path: str | os.PathLike, overwrite: bool) -> Path:
    """Return ``path`` as a Path, refusing an existing file unless ``overwrite`` is true."""
    path = Path(path)
    if path.exists() and not overwrite:
        raise OutputExistsError(
            f"{path}: file exists; pass overwrite=True (CLI: --overwrite) to replace it"
        )
    if path.exists() and path.is_dir():
        raise IsADirectoryError(f"{path}: is a directory, expected a file name")
    return path


def atomic_write(
    path: str | os.PathLike, write: Callable[[Path], None], *, overwrite: bool = False
) -> Path:
    """Write a file through ``write(tmp_path)`` then rename it into place in one step.

    A crash half-way leaves the previous file (if any) untouched, never a truncated one.
    """
    path = check_writable(path, overwrite)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=path.suffix, dir=path.parent)
    os.close(fd)
    tmp_path = Path(tmp)
    try:
        write(tmp_path)
        os.replace(tmp_path, path)
    finally:
        if tmp_path.exists():
            tmp_path.unlink()
    return path


def write_text(path: str | os.PathLike, text: str, *, overwrite: bool = False) -> Path:
    """Atomically write a text file."""
    return atomic_write(path, lambda p: p.write_text(text), overwrite=overwrite)


def write_json(path: str | os.PathLike, data: Any, *, overwrite: bool = False) -> Path:
    """Atomically write ``data`` as indented JSON (NumPy/JAX scalars and arrays converted)."""
    return write_text(path, json.dumps(to_jsonable(data), indent=2) + "\n", overwrite=overwrite)


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
