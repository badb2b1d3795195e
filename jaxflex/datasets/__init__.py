"""Public measurements from real flexible-link rigs, fetched — never copied into the project.

Each data set is one module here: its :class:`Source` (repository, pinned commit, files with
SHA-256, licence) and a converter from the original files to jaxflex records. The files come from
a local folder (``data_dir=`` or ``JAXFLEX_DATA_DIR``, laid out as ``<folder>/<data set>/<file>``)
or, failing that, from the pinned upstream URLs (or the mirror ``JAXFLEX_DATA_URL`` names) into
a user cache (pooch); either way every file is checked against its hash. :func:`write` checks
every file it will write before it fetches anything, and writes all of them or none. Records
carry their source, licence and citation in ``metadata``::

    records = jaxflex.datasets.load("quanser_rotflex")  # {"square_wave": ..., "random_985": ...}
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from types import ModuleType

from jaxflex._io import all_or_nothing, check_writable
from jaxflex.data import Record, save_record
from jaxflex.datasets import daisy_robot_arm, quanser_2dsfl, quanser_rotflex
from jaxflex.datasets._source import (
    CACHE_DIR_VARIABLE,
    DATA_DIR_VARIABLE,
    URL_VARIABLE,
    DatasetError,
    DataUnavailable,
    Source,
    cache_dir,
    check_data_dir,
    fetch_files,
    local_data_dir,
)

_MODULES: tuple[ModuleType, ...] = (quanser_rotflex, daisy_robot_arm, quanser_2dsfl)


@dataclass(frozen=True)
class DatasetInfo:
    """What :func:`available` lists: a data set's name, source and the records it converts to."""

    name: str
    description: str
    source: Source
    records: dict[str, str]


DATASETS: dict[str, DatasetInfo] = {
    m.SOURCE.name: DatasetInfo(m.SOURCE.name, m.SOURCE.description, m.SOURCE, dict(m.RECORDS))
    for m in _MODULES
}
"""Every public real-rig data set by name: description, source and its records."""


def _module(name: str) -> ModuleType:
    for module in _MODULES:
        if module.SOURCE.name == name:
            return module
    raise DatasetError(f"unknown data set {name!r}; data sets: {sorted(DATASETS)}")


def available() -> tuple[DatasetInfo, ...]:
    """Every known data set, in name order."""
    return tuple(DATASETS[n] for n in sorted(DATASETS))


def fetch(name: str, data_dir: str | os.PathLike | None = None) -> dict[str, Path]:
    """Paths of the original files of data set ``name``, each verified against its SHA-256."""
    check_data_dir(data_dir, "datasets.fetch")
    return fetch_files(_module(name).SOURCE, data_dir)


def load(name: str, data_dir: str | os.PathLike | None = None) -> dict[str, Record]:
    """The records of data set ``name``, converted from its verified original files."""
    check_data_dir(data_dir, "datasets.load")
    module = _module(name)
    return module.convert(fetch_files(module.SOURCE, data_dir))


def write(
    name: str,
    out: str | os.PathLike,
    data_dir: str | os.PathLike | None = None,
    *,
    overwrite: bool = False,
) -> list[Path]:
    """Write each record of ``name`` as ``out/<record>.csv``: every file is checked first (an
    existing one is refused unless ``overwrite``), before anything is fetched, and the files
    appear together, or none of them."""
    check_data_dir(data_dir, "datasets.write")
    module = _module(name)
    if not os.fspath(out):
        raise DatasetError("out='' names no folder; give the folder for the record files")
    out = Path(out)
    targets = {r: check_writable(out / f"{r}.csv", overwrite) for r in module.RECORDS}
    records = load(name, data_dir)
    with all_or_nothing():
        return [save_record(records[r], p, overwrite=overwrite) for r, p in targets.items()]


__all__ = [
    "CACHE_DIR_VARIABLE",
    "DATASETS",
    "DATA_DIR_VARIABLE",
    "DataUnavailable",
    "DatasetError",
    "DatasetInfo",
    "Source",
    "URL_VARIABLE",
    "available",
    "cache_dir",
    "fetch",
    "load",
    "local_data_dir",
    "write",
]
