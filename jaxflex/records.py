"""Measured records of the flexible arm: the ``Record`` and ``Dataset`` containers.

A record holds a time column, one input column (``torque``, or the ``current``, ``voltage`` or raw
``command`` a real drive logs) and any subset of the measured outputs (joint angle, tip
acceleration, or any sensor's channel) as float64 NumPy arrays, plus any extra columns, metadata
from ``# key: value`` comments and where it came from. Records are immutable and always valid:
construction checks shapes, finiteness, strictly increasing and uniform time, so every later
stage can rely on it. Files are read and written by :mod:`jaxflex.record_files`.
"""

from __future__ import annotations

import dataclasses
import difflib
import math
import os
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from typing import overload

import numpy as np
from numpy.typing import ArrayLike

from jaxflex._arguments import finite_float

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
    "root_strain": "m/m",
    "deflection_angle": "rad",
    "joint_torque": "N m",
}
"""Unit of every column jaxflex knows (SI; ``1`` for strain), as a record reports them."""
UNIFORM_RTOL = 1e-3
"""A time step may differ from the median step by this fraction (rounded or float32 time stamps)."""
DATASET_DT_RTOL = 1e-9
"""Records of one data set must share the sampling interval to this relative tolerance."""

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


def _sample_label(i: int) -> str:
    return f"sample {i}"


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


def _check_inputs_and_outputs(names: Sequence[str], where: str, drive: str | None = None
                              ) -> None:
    """Exactly one input column (:data:`INPUT_COLUMNS`), or several of which one is the
    ``drive``'s, and at least one output column."""
    inputs = [c for c in INPUT_COLUMNS if c in names]
    if len(inputs) != 1 and drive not in inputs:
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


def _did_you_mean(name: str, candidates: Iterable[str]) -> str:
    """The text "; did you mean 'x'?" for the closest candidate (case-insensitive), or ''."""
    candidates = list(candidates)
    lowered = {c.lower(): c for c in candidates}
    close = difflib.get_close_matches(name.lower(), list(lowered), n=1, cutoff=0.6)
    return f"; did you mean {lowered[close[0]]!r}?" if close else ""


__all__ = [
    "REQUIRED_COLUMNS",
    "OUTPUT_COLUMNS",
    "INPUT_COLUMNS",
    "KNOWN_UNITS",
    "UNIFORM_RTOL",
    "DATASET_DT_RTOL",
    "Record",
    "Dataset",
    "RecordError",
    "RecordWarning",
    "resample_columns",
]
