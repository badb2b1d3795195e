"""Measured records of the flexible arm: the ``Record`` and ``Dataset`` containers and file IO.

A record holds a time column, one input column (``torque``, or the ``current``, ``voltage`` or raw
``command`` a real drive logs) and any subset of the measured outputs (joint angle, tip
acceleration, or any sensor's channel) as float64 NumPy arrays, plus any extra columns, metadata
from ``# key: value`` comments and where it came from. Records are immutable and always valid:
construction checks shapes, finiteness, strictly increasing and uniform time, so every later
stage can rely on it.

Loading is strict and talkative: every problem in a file is an error (:class:`RecordError`) or a
warning (:class:`RecordWarning`) that names the file, the column and the line to look at.
"""

from __future__ import annotations

import dataclasses
import difflib
import json
import math
import os
import re
import warnings
import zipfile
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import overload

import numpy as np
from numpy.typing import ArrayLike

from jaxflex._arguments import finite_float
from jaxflex._io import atomic_write

REQUIRED_COLUMNS: tuple[str, ...] = ("time", "torque", "joint_angle", "tip_acceleration")
"""The columns of the reference-testbed format; a record may lack all but ``time``."""
OUTPUT_COLUMNS: tuple[str, ...] = ("joint_angle", "tip_acceleration")
"""Outputs fitted by default: joint angle (rad), tip acceleration (m/s²)."""
INPUT_COLUMNS: tuple[str, ...] = ("torque", "current", "voltage", "command")
"""Input columns, one per drive; a record holds exactly one of them. A ``command`` is in the
rig's own unit (counts: the arm file's drive states it), so no unit check reads it."""
KNOWN_UNITS: dict[str, str] = {
    "time": "s",
    "torque": "N m",
    "current": "A",
    "voltage": "V",
    "command": "1",
    "joint_angle": "rad",
    "tip_acceleration": "m/s^2",
    "joint_velocity": "rad/s",
    "joint_acceleration": "rad/s^2",
    "tip_deflection": "m",
    "root_strain": "1",
    "deflection_angle": "rad",
    "joint_torque": "N m",
}
"""Unit of every column jaxflex knows (SI; ``1`` for strain), as a record reports them."""
MIN_FILE_SAMPLES = 16
"""A file with fewer samples is refused: too short to identify anything, probably truncated."""
UNIFORM_RTOL = 1e-3
"""A time step may differ from the median step by this fraction (rounded or float32 time stamps)."""
DATASET_DT_RTOL = 1e-9
"""Records of one data set must share the sampling interval to this relative tolerance."""
_DEGREE_LIMIT = 8 * math.pi  # four turns: more than that from a one-link arm suggests degrees
_NPZ_METADATA_KEY = "_metadata"
_SUFFIXES = (".csv", ".npz")

RowLabel = Callable[[int], str]
"""Names a row of a file for error messages (row index → text), e.g. its line number."""


class RecordError(ValueError):
    """A record or record file is malformed; the message names the file, column and row."""


class RecordWarning(UserWarning):
    """Something in a record looks suspicious (or was repaired) but loading went on."""


@dataclass(frozen=True, eq=False)
class Record:
    """One experiment: a sampled input (torque, current, voltage or command) and measured outputs.

    ``torque``, ``joint_angle`` and ``tip_acceleration`` are ``None`` when the record lacks them;
    a ``current``, ``voltage`` or ``command`` input and other sensors' channels are extras. A
    record holds exactly one input column and at least one other column.

    Arrays are float64 copies marked read-only. Time must be strictly increasing and uniformly
    sampled (steps within ``UNIFORM_RTOL`` of each other); it need not start at 0, but
    :meth:`trim` re-zeroes it because a simulation starts from rest at t = 0.
    """

    time: np.ndarray
    torque: np.ndarray | None = None
    joint_angle: np.ndarray | None = None
    tip_acceleration: np.ndarray | None = None
    extras: dict[str, np.ndarray] = field(default_factory=dict)
    name: str = "record"
    metadata: dict[str, str] = field(default_factory=dict)
    source: str | None = None

    def __post_init__(self) -> None:
        if not isinstance(self.name, str) or not self.name:
            raise RecordError(f"record name must be a non-empty string, got {self.name!r}")
        where = f"record {self.name!r}"
        for optional in ("extras", "metadata"):
            if getattr(self, optional) is None:
                object.__setattr__(self, optional, {})
        if not isinstance(self.extras, Mapping):
            raise RecordError(f"{where}: extras must be a mapping name -> array")
        for key in self.extras:
            _check_extra_name(key, where)
        present = [c for c in REQUIRED_COLUMNS if getattr(self, c) is not None]
        columns = {c: getattr(self, c) for c in present} | dict(self.extras)
        if "time" not in columns:
            raise RecordError(f"{where}: a record needs a 'time' column")
        _check_inputs_and_outputs(list(columns), where)
        columns = _check_arrays(columns, where, _sample_label)
        _check_uniform(columns["time"], where, _sample_label)
        for array in columns.values():
            array.flags.writeable = False
        for c in present:
            object.__setattr__(self, c, columns.pop(c))
        object.__setattr__(self, "extras", columns)
        object.__setattr__(self, "metadata", _clean_metadata(self.metadata, where))
        if self.source is not None:
            object.__setattr__(self, "source", os.fspath(self.source))

    def __repr__(self) -> str:
        return (
            f"Record(name={self.name!r}, n_samples={self.n_samples}, dt={self.dt:.6g}, "
            f"duration={self.duration:.6g}, extras={list(self.extras)})"
        )

    @property
    def n_samples(self) -> int:
        """Number of samples."""
        return self.time.shape[0]

    @property
    def dt(self) -> float:
        """Sampling interval (s): the mean step, exact for a uniform grid."""
        return float(self.time[-1] - self.time[0]) / (self.n_samples - 1)

    @property
    def sample_rate(self) -> float:
        """Sampling rate (Hz), 1/dt."""
        return 1.0 / self.dt

    @property
    def duration(self) -> float:
        """Time from the first to the last sample (s)."""
        return float(self.time[-1] - self.time[0])

    @property
    def columns(self) -> tuple[str, ...]:
        """Column names: the reference-format ones present, then the extras in their order."""
        return tuple(c for c in REQUIRED_COLUMNS if getattr(self, c) is not None) + tuple(
            self.extras
        )

    @property
    def input_name(self) -> str:
        """Name of the input column (``torque``, ``current``, ``voltage`` or ``command``)."""
        return next(c for c in INPUT_COLUMNS if c in self.columns)

    @property
    def input(self) -> np.ndarray:
        """The input signal, in its own unit (the column :attr:`input_name` names)."""
        return self.channel(self.input_name)

    @property
    def units(self) -> dict[str, str]:
        """Unit of every column ('' for an extra column whose unit jaxflex does not know)."""
        return {c: KNOWN_UNITS.get(c, "") for c in self.columns}

    def to_dict(self) -> dict[str, np.ndarray]:
        """All columns by name, in file order."""
        return {c: self.channel(c) for c in self.columns}

    def channel(self, name: str) -> np.ndarray:
        """The array of one column, required or extra."""
        if name in REQUIRED_COLUMNS and getattr(self, name) is not None:
            return getattr(self, name)
        if name in self.extras:
            return self.extras[name]
        raise KeyError(
            f"record {self.name!r} has no channel {name!r}{_did_you_mean(name, self.columns)}; "
            f"available: {list(self.columns)}"
        )

    def replace(self, **changes: object) -> Record:
        """A copy with some fields changed (validated like a new record)."""
        known = [f.name for f in dataclasses.fields(self)]
        unknown = sorted(set(changes) - set(known))
        if unknown:
            raise ValueError(f"unknown Record field(s) {unknown}; fields: {known}")
        return dataclasses.replace(self, **changes)

    def with_outputs(
        self,
        *,
        joint_angle: ArrayLike | None = None,
        tip_acceleration: ArrayLike | None = None,
        **extras: ArrayLike,
    ) -> Record:
        """A copy with outputs replaced (e.g. by a simulation); extras given are added/replaced.

        Extras not given are kept as they are.
        """
        changes: dict[str, object] = {}
        if joint_angle is not None:
            changes["joint_angle"] = joint_angle
        if tip_acceleration is not None:
            changes["tip_acceleration"] = tip_acceleration
        if extras:
            changes["extras"] = self.extras | extras
        return self.replace(**changes)

    def trim(self, t_start: float | None = None, t_end: float | None = None) -> Record:
        """The samples with ``t_start <= time <= t_end``, time re-zeroed to start at 0.

        Bounds are in the record's own time and inclusive (to within 1e-6 of a step). The cut is
        appended to ``metadata['history']``.
        """
        t = self.time
        lo = float(t[0]) if t_start is None else finite_float(t_start, "t_start")
        hi = float(t[-1]) if t_end is None else finite_float(t_end, "t_end")
        if not lo < hi:
            raise ValueError(f"trim: t_start={lo!r} must be below t_end={hi!r}")
        tol = 1e-6 * self.dt
        keep = np.flatnonzero((t >= lo - tol) & (t <= hi + tol))
        if keep.size < 2:
            raise ValueError(
                f"trim: window [{lo!r}, {hi!r}] s holds {keep.size} sample(s) of record "
                f"{self.name!r}, which spans [{float(t[0])!r}, {float(t[-1])!r}] s; need at least 2"
            )
        cut = slice(keep[0], keep[-1] + 1)
        columns = {c: a[cut] for c, a in self.to_dict().items()}
        columns["time"] = columns["time"] - columns["time"][0]
        return self.with_columns(
            columns, note=f"trim [{float(t[cut][0])!r}, {float(t[cut][-1])!r}] s"
        )

    @classmethod
    def from_columns(cls, columns: Mapping[str, np.ndarray], **fields: object) -> Record:
        """A record of ``columns`` by name (``time``, the input, the channels), the
        reference-format ones in their fields and the others as extras; ``fields`` are the
        other fields (``name``, ``metadata``, ...)."""
        return cls(**_split_columns(columns), **fields)

    def with_columns(self, columns: Mapping[str, np.ndarray], note: str) -> Record:
        """A copy with all columns replaced and ``note`` appended to the history."""
        return self.replace(**_split_columns(columns), metadata=self.noted_metadata(note))

    def noted_metadata(self, note: str) -> dict[str, str]:
        """Metadata with ``note`` appended to its 'history' entry (provenance of processing)."""
        history = self.metadata.get("history")
        return self.metadata | {"history": f"{history}; {note}" if history else note}


class Dataset(Sequence[Record]):
    """An immutable, ordered collection of uniquely named records sharing one sampling interval.

    Index it by position, slice, or record name. An empty data set is allowed (e.g. the rest of a
    :meth:`split` that selected everything) but has no ``dt``.
    """

    __slots__ = ("_records",)

    def __init__(self, records: Iterable[Record] = ()) -> None:
        records = tuple(records)
        for i, r in enumerate(records):
            if not isinstance(r, Record):
                raise TypeError(f"Dataset item {i} is a {type(r).__name__}, expected a Record")
        names = [r.name for r in records]
        duplicated = sorted({n for n in names if names.count(n) > 1})
        if duplicated:
            raise RecordError(
                f"record names must be unique in a data set; repeated: {duplicated} "
                "(rename one of the files, or give a name: load_record(path, name=...))"
            )
        for r in records[1:]:
            first = records[0]
            if abs(r.dt - first.dt) > DATASET_DT_RTOL * first.dt:
                raise RecordError(
                    f"records {first.name!r} (dt={first.dt!r} s) and {r.name!r} "
                    f"(dt={r.dt!r} s) have different sampling intervals; resample one of them "
                    "(jaxflex.preprocess.resample) before putting them in one data set"
                )
        self._records: tuple[Record, ...] = records

    def __len__(self) -> int:
        return len(self._records)

    def __iter__(self) -> Iterator[Record]:
        return iter(self._records)

    @overload
    def __getitem__(self, key: int | str) -> Record: ...

    @overload
    def __getitem__(self, key: slice) -> Dataset: ...

    def __getitem__(self, key: int | str | slice) -> Record | Dataset:
        if isinstance(key, str):
            for r in self._records:
                if r.name == key:
                    return r
            raise KeyError(
                f"no record named {key!r}{_did_you_mean(key, self.names)}; "
                f"records: {list(self.names)}"
            )
        if isinstance(key, slice):
            return Dataset(self._records[key])
        return self._records[key]

    def __repr__(self) -> str:
        return f"Dataset({list(self.names)})"

    @property
    def names(self) -> tuple[str, ...]:
        """Record names, in order."""
        return tuple(r.name for r in self._records)

    @property
    def records(self) -> tuple[Record, ...]:
        """The records, in order."""
        return self._records

    @property
    def dt(self) -> float:
        """The common sampling interval (s), that of the first record."""
        if not self._records:
            raise RecordError("an empty data set has no sampling interval")
        return self._records[0].dt

    def split(self, names: str | Iterable[str]) -> tuple[Dataset, Dataset]:
        """(records named in ``names``, in that order; the others, in data-set order).

        Use it to fit on some records and validate on the held-out rest.
        """
        wanted = [names] if isinstance(names, str) else list(dict.fromkeys(names))
        selected = Dataset(self[n] for n in wanted)
        rest = Dataset(r for r in self._records if r.name not in wanted)
        return selected, rest


def load_record(
    path: str | os.PathLike,
    *,
    name: str | None = None,
    resample: bool = False,
    unit_check: bool = True,
    channels: Iterable[str] = (),
) -> Record:
    """Read and validate a record from a ``.csv`` or ``.npz`` file.

    ``name`` defaults to the file stem. ``channels`` names a rig's sensor channels: a column
    named so is that sensor's, never taken for a misspelt reference-format column (a rig's
    ``angle`` is not a typing error for ``joint_angle``). A non-uniform time column is an error
    unless ``resample=True``, which interpolates all columns linearly onto a grid with the median
    step (with a :class:`RecordWarning` that names the longest gap). Columns whose units look wrong
    (time in ms, angle in degrees, torque far off scale; :func:`check_units`) are an error
    unless ``unit_check=False``.
    """
    path = Path(path)
    suffix = _suffix(path)
    where = str(path)
    own = tuple(channels)
    if suffix == ".csv":
        columns, row, metadata = _read_csv(path, own)
    else:
        columns, row, metadata = _read_npz(path, own)
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
    _check_excitation_and_units(columns, where)
    if unit_check:
        check_units(columns, where)
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
) -> Dataset:
    """Load records into a :class:`Dataset`; a directory means all its .csv/.npz files, sorted
    (sub-directories are skipped, whatever their names); ``channels`` as in
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
    return Dataset(load_record(p, resample=resample, unit_check=unit_check, channels=own)
                   for p in files)


def save_record(record: Record, path: str | os.PathLike, *, overwrite: bool = False) -> Path:
    """Write ``record`` as spec CSV (or NPZ for a ``.npz`` path), atomically.

    Metadata become ``# key: value`` comments; numbers are written with ``repr`` (the shortest
    text that reads back to the same float64), so a save/load round trip is exact. An existing
    file is refused (:class:`~jaxflex._io.OutputExistsError`) unless ``overwrite=True``.
    """
    if _suffix(Path(path)) == ".npz":
        return save_npz(record, path, overwrite=overwrite)
    lines = [f"# units = {', '.join(f'{c} {u}' for c, u in record.units.items() if u)}"]
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
    path: Path, own: Sequence[str] = ()
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
            _check_header(header, where, lineno, own)
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


def _check_header(header: list[str], where: str, lineno: int, own: Sequence[str] = ()) -> None:
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
    _check_inputs_and_outputs(header, f"{where}: line {lineno} (header)")


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
    path: Path, own: Sequence[str] = ()
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
    _check_inputs_and_outputs(list(arrays), where)
    ordered = {c: arrays.pop(c) for c in REQUIRED_COLUMNS if c in arrays} | arrays
    return ordered, _index_label, {str(k): str(v) for k, v in metadata.items()}


# --- validation ---------------------------------------------------------------------------------


def _sample_label(i: int) -> str:
    return f"sample {i}"


def _index_label(i: int) -> str:
    return f"index {i}"


def _check_arrays(
    columns: Mapping[str, object], where: str, row: RowLabel, min_samples: int = 2
) -> dict[str, np.ndarray]:
    """float64 1-D arrays of one length, finite, time strictly increasing (else RecordError)."""
    arrays: dict[str, np.ndarray] = {}
    for c, value in columns.items():
        a = np.asarray(value)
        if a.dtype.kind not in "biuf":
            raise RecordError(f"{where}: column {c!r} holds {a.dtype} values, expected numbers")
        if a.ndim != 1:
            raise RecordError(f"{where}: column {c!r} has shape {a.shape}, expected 1-D")
        arrays[c] = np.array(a, dtype=np.float64)
    n = arrays["time"].shape[0]
    for c, a in arrays.items():
        if a.shape[0] != n:
            raise RecordError(f"{where}: column {c!r} has {a.shape[0]} samples but 'time' has {n}")
        bad = np.flatnonzero(~np.isfinite(a))
        if bad.size:
            raise RecordError(
                f"{where}: column {c!r}, {row(int(bad[0]))}: value {float(a[bad[0]])!r} is not "
                f"finite ({bad.size} non-finite value(s) in this column)"
            )
    if n < min_samples:
        raise RecordError(f"{where}: only {n} sample(s); at least {min_samples} are needed")
    time = arrays["time"]
    steps = np.diff(time)
    bad = np.flatnonzero(steps <= 0)
    if bad.size:
        k = int(bad[0]) + 1
        raise RecordError(
            f"{where}: column 'time', {row(k)}: time {float(time[k])!r} is not after "
            f"{float(time[k - 1])!r} ({row(k - 1)}); time must be strictly increasing"
        )
    return arrays


def _irregular_step(time: np.ndarray) -> int | None:
    """Index of the first step differing from the median step by more than UNIFORM_RTOL."""
    steps = np.diff(time)
    median = np.median(steps)
    bad = np.flatnonzero(np.abs(steps - median) > UNIFORM_RTOL * median)
    return int(bad[0]) if bad.size else None


def _check_uniform(time: np.ndarray, where: str, row: RowLabel, hint: str = "") -> None:
    """RecordError naming the first irregular step if ``time`` is not uniformly sampled."""
    k = _irregular_step(time)
    if k is not None:
        steps = np.diff(time)
        median = float(np.median(steps))
        n_bad = int(np.sum(np.abs(steps - median) > UNIFORM_RTOL * median))
        raise RecordError(
            f"{where}: column 'time': non-uniform sampling; the step from {row(k)} to "
            f"{row(k + 1)} is {float(steps[k])!r} s but the median step is {median!r} s "
            f"({n_bad} irregular step(s)){hint}"
        )


def _check_excitation_and_units(columns: Mapping[str, np.ndarray], where: str) -> None:
    """Refuse an input that is zero throughout; warn about a joint angle that looks like degrees."""
    source = next(c for c in INPUT_COLUMNS if c in columns)
    if not np.any(columns[source]):
        raise RecordError(
            f"{where}: column {source!r} is zero in every row; nothing excites the arm"
        )
    if "joint_angle" not in columns:
        return
    angle = columns["joint_angle"]
    peak = float(np.max(np.abs(angle)))
    if peak > _DEGREE_LIMIT:
        warnings.warn(
            f"{where}: column 'joint_angle' reaches {peak:.6g}, more than four turns in "
            "radians; is it in degrees? joint_angle must be in rad",
            RecordWarning,
            stacklevel=3,
        )
    elif peak >= 2 and np.all(angle == np.round(angle)):
        warnings.warn(
            f"{where}: column 'joint_angle' holds only whole numbers (up to {peak:.6g}); it "
            "looks like degrees or encoder counts; joint_angle must be in rad",
            RecordWarning,
            stacklevel=3,
        )


def check_units(columns: Mapping[str, np.ndarray], where: str = "record") -> None:
    """Stop (RecordError) on columns whose units are implausible for a lab arm.

    Runs on every loaded record (:func:`load_record`) unless ``unit_check=False``.

    * time: a step of :data:`MAX_PLAUSIBLE_DT` s or more (milliseconds or sample numbers?);
    * joint angle: constant although the torque is not (a warning: stiction, or no encoder);
    * joint angle against tip acceleration integrated twice (the tip's path, up to a drift): their
      ratio is the arm's length; below :data:`MIN_PLAUSIBLE_LENGTH` the angle is in degrees;
    * torque against angular acceleration, speed and direction (least squares): an inertia
      above :data:`MAX_PLAUSIBLE_INERTIA` means a torque far too large (not in N m).

    Each message says how to load the file anyway (``unit_check=False``; CLI: --no-unit-check).
    """
    skip = " (pass unit_check=False to skip this check)"
    time = columns["time"]
    dt = float(time[-1] - time[0]) / (time.shape[0] - 1)
    if dt >= MAX_PLAUSIBLE_DT:
        raise RecordError(
            f"{where}: column 'time': step {dt:.6g} s ({1 / dt:.3g} Hz sampling); is time in "
            f"milliseconds or sample numbers? time must be in s{skip}"
        )
    angle, torque = columns.get("joint_angle"), columns.get("torque")
    if angle is None or torque is None:  # another drive's input: no torque scale to check
        return
    if np.ptp(angle) == 0:  # possible (torque below breakaway friction), but worth a word
        warnings.warn(
            f"{where}: column 'joint_angle' is constant ({float(angle[0])!r}) although the "
            "torque is not: the torque stays below the joint's breakaway friction, or the "
            "encoder is not connected; such a record tells nothing about the arm's dynamics",
            RecordWarning,
            stacklevel=3,
        )
        return
    if "tip_acceleration" in columns:
        length = _effective_length(time, angle, columns["tip_acceleration"])
        if length is not None and abs(length) < MIN_PLAUSIBLE_LENGTH:
            raise RecordError(
                f"{where}: column 'joint_angle' against the twice-integrated 'tip_acceleration' "
                f"implies an arm {abs(length):.3g} m long (below {MIN_PLAUSIBLE_LENGTH:g} m); is "
                f"the angle in degrees? joint_angle must be in rad{skip}"
            )
    inertia = _effective_inertia(time, angle, torque)
    if inertia is not None and inertia > MAX_PLAUSIBLE_INERTIA:
        raise RecordError(
            f"{where}: column 'torque': the record implies a joint inertia of {inertia:.3g} "
            f"kg m^2, above {MAX_PLAUSIBLE_INERTIA:g}; is the torque in N m (and the angle in "
            f"rad, time in s)?{skip}"
        )


MAX_PLAUSIBLE_DT = 0.05
"""A sampling step this long (20 Hz) cannot resolve a flexible arm: time is in ms, or counts."""
MIN_PLAUSIBLE_LENGTH = 0.05
"""Shortest plausible arm (m), tip path over joint angle; a degree angle makes it 57x shorter."""
MAX_PLAUSIBLE_INERTIA = 1e3
"""A joint inertia (kg m²) above any lab arm's: the torque is far too large (not in N m)."""


def _fit_share(basis: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, float]:
    """Least-squares coefficients of ``y`` on the columns of ``basis``, and how much worse the
    fit gets without the first column (residual ratio; large = the first column is needed)."""
    coef, *_ = np.linalg.lstsq(basis, y, rcond=None)
    rest, *_ = np.linalg.lstsq(basis[:, 1:], y, rcond=None)
    with_first = float(np.sum((y - basis @ coef) ** 2))
    without = float(np.sum((y - basis[:, 1:] @ rest) ** 2))
    return coef, without / with_first if with_first > 0 else math.inf


def _integral(x: np.ndarray, time: np.ndarray) -> np.ndarray:
    """Cumulative trapezoidal integral from the first sample (0 there)."""
    return np.concatenate([[0.0], np.cumsum(0.5 * (x[1:] + x[:-1]) * np.diff(time))])


def _effective_inertia(time: np.ndarray, angle: np.ndarray, torque: np.ndarray) -> float | None:
    """``|J|`` of ``J·θ'' + b·θ' + c·sign(θ') = τ`` integrated twice (noise-robust; constants of
    integration fitted), or None when the angle does not determine it."""
    speed = np.gradient(angle, time)
    sign = np.tanh(speed / (1e-3 + 0.01 * float(np.ptp(speed))))
    tau = (time - time[0]) / (time[-1] - time[0])
    theta = angle - angle[0]
    basis = np.column_stack([theta, _integral(theta, time), _integral(_integral(sign, time), time),
                             np.ones_like(tau), tau])
    coef, needed = _fit_share(basis, _integral(_integral(torque, time), time))
    return abs(float(coef[0])) if needed > 4 else None


def _effective_length(time: np.ndarray, angle: np.ndarray, tip: np.ndarray) -> float | None:
    """``L`` in ``∬ tip_acceleration ≈ L·angle + a + b·t + c·t²`` (the quadratic takes the
    drift of an accelerometer offset), or None when that explains less than half the path."""
    path = _integral(_integral(tip, time), time)
    tau = (time - time[0]) / (time[-1] - time[0])
    basis = np.column_stack([angle - angle[0], np.ones_like(tau), tau, tau**2])
    coef, needed = _fit_share(basis, path)
    return float(coef[0]) if needed > 2 else None


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
    return "; ".join(f"{kind} {c!r} not found{_did_you_mean(c, unused)}" for c in missing)


def _check_inputs_and_outputs(names: Sequence[str], where: str) -> None:
    """Exactly one input column (:data:`INPUT_COLUMNS`) and at least one output column."""
    inputs = [c for c in INPUT_COLUMNS if c in names]
    if len(inputs) != 1:
        found = f"found {inputs}" if inputs else "found none"
        raise RecordError(
            f"{where}: a record needs exactly one input column of {list(INPUT_COLUMNS)}; {found}"
        )
    if not [c for c in names if c not in ("time", *INPUT_COLUMNS)]:
        raise RecordError(
            f"{where}: no output column besides {['time', *inputs]}; a record needs at least "
            "one measured channel (e.g. joint_angle, tip_acceleration)"
        )


def _split_columns(columns: Mapping[str, np.ndarray]) -> dict[str, object]:
    """``columns`` as :class:`Record` fields: the reference-format columns (None where absent)
    and the rest under ``extras``."""
    required = {c: columns.get(c) for c in REQUIRED_COLUMNS}
    return required | {"extras": {c: a for c, a in columns.items() if c not in REQUIRED_COLUMNS}}


def _check_extra_name(key: object, where: str) -> None:
    """Extra column names must be writable as a CSV header cell and not shadow a column."""
    if (
        not isinstance(key, str)
        or not key
        or key != key.strip()
        or any(ch in key for ch in ",\n\r")
        or key.startswith(("#", "_"))
    ):
        raise RecordError(
            f"{where}: extra column name {key!r} must be a non-empty string without commas, "
            "line breaks, surrounding spaces or a leading '#' or '_'"
        )
    if key in REQUIRED_COLUMNS:
        raise RecordError(f"{where}: {key!r} is a required column, not an extra")


def _clean_metadata(metadata: object, where: str) -> dict[str, str]:
    """A ``str -> str`` copy (values stripped) that survives a ``# key: value`` round trip."""
    if not isinstance(metadata, Mapping):
        raise RecordError(f"{where}: metadata must be a mapping str -> str")
    clean: dict[str, str] = {}
    for key, value in metadata.items():
        text = str(value).strip()
        if not isinstance(key, str) or not key or key != key.strip() or ":" in key:
            raise RecordError(
                f"{where}: metadata key {key!r} must be a non-empty string without ':' or "
                "surrounding spaces"
            )
        if any(ch in key + text for ch in "\n\r"):
            raise RecordError(f"{where}: metadata {key!r} must fit on one line")
        clean[key] = text
    return clean


# --- helpers ------------------------------------------------------------------------------------


def resample_columns(columns: Mapping[str, np.ndarray], dt: float) -> dict[str, np.ndarray]:
    """Every column linearly interpolated onto ``time[0] + k·dt`` up to the last time."""
    time = columns["time"]
    n = int(math.floor((time[-1] - time[0]) / dt + 1e-9)) + 1
    grid = time[0] + dt * np.arange(n)
    return {c: grid if c == "time" else np.interp(grid, time, a) for c, a in columns.items()}


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def _did_you_mean(name: str, candidates: Iterable[str]) -> str:
    """The text "; did you mean 'x'?" for the closest candidate (case-insensitive), or ''."""
    candidates = list(candidates)
    lowered = {c.lower(): c for c in candidates}
    close = difflib.get_close_matches(name.lower(), list(lowered), n=1, cutoff=0.6)
    return f"; did you mean {lowered[close[0]]!r}?" if close else ""


def _suffix(path: Path) -> str:
    suffix = path.suffix.lower()
    if suffix not in _SUFFIXES:
        raise ValueError(f"{path}: unsupported record file type {path.suffix!r}; use .csv or .npz")
    return suffix


__all__ = [
    "INPUT_COLUMNS",
    "Dataset",
    "Record",
    "RecordError",
    "RecordWarning",
    "check_units",
    "load_dataset",
    "load_record",
    "save_npz",
    "save_record",
]
