"""Record files: reading and writing a :class:`~jaxflex.records.Record` as CSV or NPZ.

Loading is strict and talkative: every problem in a file is an error
(:class:`~jaxflex.records.RecordError`) or a warning (:class:`~jaxflex.records.RecordWarning`)
that names the file, the column and the line to look at; the units of what was read are checked
(:func:`jaxflex.units.check_units`) before a record is made of it.
"""

from __future__ import annotations

import json
import os
import re
import warnings
import zipfile
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path

import numpy as np

from jaxflex._io import atomic_write
from jaxflex.records import (
    INPUT_COLUMNS,
    REQUIRED_COLUMNS,
    Dataset,
    Record,
    RecordError,
    RecordWarning,
    RowLabel,
    _check_arrays,
    _check_inputs_and_outputs,
    _check_uniform,
    _did_you_mean,
    _irregular_step,
    _sample_label,
    resample_columns,
)
from jaxflex.units import _check_excitation_and_units, check_units

MIN_FILE_SAMPLES = 16
"""A file with fewer samples is refused: too short to identify anything, probably truncated."""
_NPZ_METADATA_KEY = "_metadata"
_SUFFIXES = (".csv", ".npz")


def load_record(
    path: str | os.PathLike,
    *,
    name: str | None = None,
    resample: bool = False,
    unit_check: bool = True,
    channels: Iterable[str] = (),
    drive: str | None = None,
) -> Record:
    """Read and validate a record from a ``.csv`` or ``.npz`` file.

    ``name`` defaults to the file stem. ``channels`` names a rig's sensor channels: a column
    named so is that sensor's, never taken for a misspelt reference-format column (a rig's
    ``angle`` is not a typing error for ``joint_angle``); a rig's records are read with them by
    :func:`jaxflex.measured.load_records`, which also makes them ready for the rig. A non-uniform
    time column is an error unless ``resample=True``, which interpolates all columns linearly
    onto a grid with the median step (with a :class:`RecordWarning` that names the longest
    gap). Columns whose units look wrong
    (time in ms, angle in degrees, torque far off scale; :func:`check_units`) are an error
    unless ``unit_check=False``; a rig's own channels are in the units its rig declares, and
    the rig checks them (:func:`jaxflex.measured.model_record`). ``drive`` is a rig's input
    column (its drive's name): of a file holding several input columns (a command and the
    current it drew), that one is read and the others are ignored, with a
    :class:`RecordWarning` that names them.
    """
    path = Path(path)
    suffix = _suffix(path)
    where = str(path)
    own = tuple(channels)
    if suffix == ".csv":
        columns, row, metadata = _read_csv(path, own, drive)
    else:
        columns, row, metadata = _read_npz(path, own, drive)
    ignored = [c for c in INPUT_COLUMNS if c in columns and c != drive]
    if len(ignored) < len([c for c in INPUT_COLUMNS if c in columns]) and ignored:
        columns = {c: a for c, a in columns.items() if c not in ignored}
        warnings.warn(
            f"{where}: column(s) {ignored} ignored: the rig's drive reads column {drive!r}",
            RecordWarning,
            stacklevel=2,
        )
    columns = _check_arrays(columns, where, row, min_samples=MIN_FILE_SAMPLES)
    n = columns["time"].shape[0]
    if resample and _irregular_step(columns["time"]) is not None:
        steps = np.diff(columns["time"])
        dt = float(np.median(steps))
        gap = int(np.argmax(steps))
        gap_text = f"{row(gap)} to {row(gap + 1)} ({float(steps[gap]):.6g} s)"
        columns = resample_columns(columns, dt)
        row = _sample_label
        warnings.warn(
            f"{where}: time column is not uniformly sampled; resampled {n} samples onto "
            f"{columns['time'].shape[0]} with the median step {dt!r} s by linear interpolation; "
            f"the longest gap, {gap_text}, is {float(steps[gap]) / dt:.3g} steps: the samples "
            "in it are interpolated, not measured",
            RecordWarning,
            stacklevel=2,
        )
    _check_uniform(columns["time"], where, row, hint="; pass resample=True to resample it")
    _check_excitation_and_units(columns, where, own)
    if unit_check:  # a rig's own channels are in the units its rig declares, checked there
        check_units({c: a for c, a in columns.items() if c not in own}, where)
    extras = {c: a for c, a in columns.items() if c not in REQUIRED_COLUMNS}
    return Record(
        **{c: columns.get(c) for c in REQUIRED_COLUMNS},
        extras=extras,
        name=path.stem if name is None else name,
        metadata=metadata,
        source=where,
    )


def load_dataset(
    paths: str | os.PathLike | Iterable[str | os.PathLike],
    *,
    resample: bool = False,
    unit_check: bool = True,
    channels: Iterable[str] = (),
    drive: str | None = None,
) -> Dataset:
    """Load records into a :class:`Dataset`; a directory means all its .csv/.npz files, sorted
    (sub-directories are skipped, whatever their names); ``channels`` and ``drive`` as in
    :func:`load_record`."""
    if isinstance(paths, (str, os.PathLike)):
        root = Path(paths)
        if root.is_dir():
            files = sorted(
                p for p in root.iterdir() if p.suffix.lower() in _SUFFIXES and p.is_file()
            )
            if not files:
                raise RecordError(f"{root}: directory holds no .csv or .npz record files")
        else:
            files = [root]
    else:
        files = [Path(p) for p in paths]
    own = tuple(channels)
    return Dataset(load_record(p, resample=resample, unit_check=unit_check, channels=own,
                               drive=drive)
                   for p in files)


def save_record(record: Record, path: str | os.PathLike, *, overwrite: bool = False,
                units: Mapping[str, str] | None = None) -> Path:
    """Write ``record`` as spec CSV (or NPZ for a ``.npz`` path), atomically.

    The first line names each column's unit (``# units = time s, ...``): the ones jaxflex knows
    (:attr:`~jaxflex.records.Record.units`), with ``units`` (column → unit) giving or replacing
    those of other columns, e.g. a rig's sensor channels
    (:func:`jaxflex.measured.logged_units`); a column whose unit is known from neither is left
    out of it. Metadata become ``# key: value`` comments; numbers are written with ``repr`` (the
    shortest text that reads back to the same float64), so a save/load round trip is exact. An
    existing file is refused (:class:`~jaxflex._io.OutputExistsError`) unless
    ``overwrite=True``.
    """
    if _suffix(Path(path)) == ".npz":
        return save_npz(record, path, overwrite=overwrite)
    given = dict(units or {})
    unknown = sorted(set(given) - set(record.columns))
    if unknown:
        raise ValueError(f"units given for column(s) {unknown} that record {record.name!r} does "
                         f"not hold; its columns are {list(record.columns)}")
    named = {c: given.get(c) or u for c, u in record.units.items()}
    lines = [f"# units = {', '.join(f'{c} {u}' for c, u in named.items() if u)}"]
    lines += [f"# {k}: {v}" for k, v in record.metadata.items()]
    lines.append(",".join(record.columns))
    table = np.column_stack(list(record.to_dict().values()))
    lines += [",".join(map(repr, row)) for row in table.tolist()]
    text = "\n".join(lines) + "\n"
    return atomic_write(path, lambda p: p.write_text(text, encoding="utf-8"), overwrite=overwrite)


def save_npz(record: Record, path: str | os.PathLike, *, overwrite: bool = False) -> Path:
    """Write ``record`` as NPZ (one array per column, metadata as JSON), atomically."""
    if _suffix(Path(path)) != ".npz":
        raise ValueError(f"{path}: an NPZ record file must end in .npz")
    arrays = record.to_dict() | {_NPZ_METADATA_KEY: np.array(json.dumps(record.metadata))}

    def write(p: Path) -> None:
        with open(p, "wb") as f:
            np.savez(f, **arrays)

    return atomic_write(path, write, overwrite=overwrite)


# --- reading ------------------------------------------------------------------------------------


def _read_csv(
    path: Path, own: Sequence[str] = (), drive: str | None = None
) -> tuple[dict[str, np.ndarray], RowLabel, dict[str, str]]:
    """Parse a CSV record into columns, a row labeller (file line numbers) and metadata."""
    where = str(path)
    try:
        text = path.read_text(encoding="utf-8-sig")
    except UnicodeDecodeError as err:
        raise RecordError(f"{where}: not a UTF-8 text file ({err})") from None
    except IsADirectoryError:
        raise RecordError(f"{where}: is a directory, not a record file") from None
    metadata: dict[str, str] = {}
    header: list[str] | None = None
    header_line = 0
    lines: list[int] = []
    rows: list[list[str]] = []
    for lineno, line in enumerate(text.splitlines(), start=1):
        stripped = line.strip()
        if not stripped:
            continue
        if stripped.startswith("#"):
            _parse_comment(stripped[1:], metadata, where, lineno)
        elif header is None and not rows and _excel_separator(stripped, where, lineno):
            continue
        elif header is None:
            header, header_line = [_unquote(c) for c in stripped.split(",")], lineno
            _check_header(header, where, lineno, own, drive)
        else:
            lines.append(lineno)
            rows.append([_unquote(c) for c in stripped.split(",")])
    if header is None:
        raise RecordError(f"{where}: no header line (expected {', '.join(REQUIRED_COLUMNS)})")
    values = np.empty((len(rows), len(header)))
    for i, (lineno, cells) in enumerate(zip(lines, rows, strict=True)):
        if len(cells) != len(header):
            raise RecordError(
                f"{where}: line {lineno}: {len(cells)} cells, but the header (line "
                f"{header_line}) names {len(header)} columns"
            )
        for j, cell in enumerate(cells):
            values[i, j] = _parse_cell(cell, where, lineno, header[j])
    columns = {c: values[:, j] for j, c in enumerate(header)}
    return columns, lambda i: f"line {lines[i]}", metadata


def _excel_separator(line: str, where: str, lineno: int) -> bool:
    """Whether ``line`` is Excel's ``sep=,`` line (skipped); another separator is an error."""
    match = re.fullmatch(r'"?sep=(.)"?,*', line)
    if match is None:
        return False
    if match.group(1) != ",":
        raise RecordError(
            f"{where}: line {lineno}: {line!r} declares the separator {match.group(1)!r}; record "
            "files are comma-separated"
        )
    return True


def _unquote(cell: str) -> str:
    """A CSV cell without surrounding spaces and RFC-4180 double quotes (``"time"`` → time)."""
    cell = cell.strip()
    if len(cell) >= 2 and cell[0] == cell[-1] == '"':
        cell = cell[1:-1].replace('""', '"').strip()
    return cell


def _parse_comment(text: str, metadata: dict[str, str], where: str, lineno: int) -> None:
    """Record a ``key: value`` comment in ``metadata``; other comments are free text."""
    match = re.match(r"\s*([^:]+?)\s*:(.*)$", text)
    if match is None:
        return
    key, value = match.group(1), match.group(2).strip()
    if key in metadata:
        warnings.warn(
            f"{where}: line {lineno}: metadata key {key!r} given again; the later value "
            f"{value!r} replaces {metadata[key]!r}",
            RecordWarning,
            stacklevel=4,
        )
    metadata[key] = value


def _check_header(header: list[str], where: str, lineno: int, own: Sequence[str] = (),
                  drive: str | None = None) -> None:
    """Refuse empty, duplicated or missing column names, suggesting close matches."""
    if len(header) == 1:
        for sep, label in ((";", "semicolons"), ("\t", "tabs")):
            if sep in header[0]:
                raise RecordError(
                    f"{where}: line {lineno}: the header seems to be separated by {label}; "
                    "record files are comma-separated"
                )
    if all(_is_number(c) for c in header):
        raise RecordError(
            f"{where}: line {lineno} looks like data, not a header; the first non-comment line "
            f"must name the columns ({', '.join(REQUIRED_COLUMNS)}, ...)"
        )
    for j, c in enumerate(header):
        if not c:
            raise RecordError(f"{where}: line {lineno}: header column {j + 1} has no name")
        if header.index(c) != j:
            raise RecordError(
                f"{where}: line {lineno}: column {c!r} appears twice (columns "
                f"{header.index(c) + 1} and {j + 1})"
            )
    details = _missing_columns(header, "column", own)
    if details:
        raise RecordError(f"{where}: line {lineno} (header): {details}; header is {header}")
    _check_inputs_and_outputs(header, f"{where}: line {lineno} (header)", drive)


def _parse_cell(cell: str, where: str, lineno: int, column: str) -> float:
    """One number, or a RecordError naming the line and column."""
    cell = cell.strip()
    if not cell:
        raise RecordError(f"{where}: line {lineno}, column {column!r}: empty cell")
    try:
        return float(cell)
    except ValueError:
        raise RecordError(
            f"{where}: line {lineno}, column {column!r}: cell {cell!r} is not a number"
        ) from None


def _read_npz(
    path: Path, own: Sequence[str] = (), drive: str | None = None
) -> tuple[dict[str, np.ndarray], RowLabel, dict[str, str]]:
    """Read an NPZ record: one array per column, optional JSON metadata."""
    where = str(path)
    try:
        with open(path, "rb") as f:
            magic = f.read(4)
    except IsADirectoryError:
        raise RecordError(f"{where}: is a directory, not a record file") from None
    if magic != b"PK\x03\x04":
        raise RecordError(
            f"{where}: not an NPZ file (an .npz record is a NumPy zip archive, written by "
            "numpy.savez; is it a text file with the wrong suffix?)"
        )
    try:
        with np.load(path, allow_pickle=False) as npz:
            arrays = {k: npz[k] for k in npz.files}
    except (ValueError, zipfile.BadZipFile) as err:  # object arrays, corrupt or foreign files
        raise RecordError(f"{where}: cannot read as an NPZ record ({err})") from None
    metadata: dict[str, str] = {}
    if _NPZ_METADATA_KEY in arrays:
        try:
            metadata = json.loads(str(arrays.pop(_NPZ_METADATA_KEY)[()]))
        except (json.JSONDecodeError, IndexError) as err:
            raise RecordError(
                f"{where}: {_NPZ_METADATA_KEY!r} is not a JSON object ({err})"
            ) from None
        if not isinstance(metadata, dict):
            raise RecordError(f"{where}: {_NPZ_METADATA_KEY!r} is not a JSON object")
    details = _missing_columns(list(arrays), "array", own)
    if details:
        raise RecordError(f"{where}: {details}; arrays are {list(arrays)}")
    _check_inputs_and_outputs(list(arrays), where, drive)
    ordered = {c: arrays.pop(c) for c in REQUIRED_COLUMNS if c in arrays} | arrays
    return ordered, _index_label, {str(k): str(v) for k, v in metadata.items()}


# --- labels and names ----------------------------------------------------------------------------


def _index_label(i: int) -> str:
    return f"index {i}"


def _missing_columns(names: Sequence[str], kind: str, own: Sequence[str] = ()) -> str:
    """'column X not found; did you mean Y?' for each absent column that a present one resembles.

    ``time`` is always required; the other reference-format columns are optional, but a name close
    to one of them is far more likely a misspelling than another sensor, unless it is one of the
    rig's own sensor channels ``own``.
    """
    unused = [c for c in names if c not in (*REQUIRED_COLUMNS, *INPUT_COLUMNS, *own)]
    missing = [
        c
        for c in REQUIRED_COLUMNS
        if c not in names and (c == "time" or _did_you_mean(c, unused))
    ]
    details = "; ".join(f"{kind} {c!r} not found{_did_you_mean(c, unused)}" for c in missing)
    if not own and any(c != "time" and _did_you_mean(c, unused) for c in missing):
        details += (" (if it is a rig's sensor channel, read the record for the rig: --arm RIG on "
                    "the command line, jaxflex.load_records(paths, rig) in Python)")
    return details


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def _suffix(path: Path) -> str:
    suffix = path.suffix.lower()
    if suffix not in _SUFFIXES:
        raise ValueError(f"{path}: unsupported record file type {path.suffix!r}; use .csv or .npz")
    return suffix


__all__ = [
    "MIN_FILE_SAMPLES",
    "load_record",
    "load_dataset",
    "save_record",
    "save_npz",
]
