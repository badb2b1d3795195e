"""Records as a rig logs them, made ready for its model: windows, rest and re-zeroed readings.

A logged record holds the drive's input column (``torque``, ``current``, ``voltage``, ...), some
of the rig's sensor channels in their own units, and time that may start anywhere.
:func:`model_record` cuts the requested window, checks that the arm is at rest at its start (the
simulation starts from rest) and re-zeroes each sensor channel at rest, which removes the
sensors' offsets: the model's readings are taken relative to rest
(:meth:`~jaxflex.sensors.AbstractSensor.reading`); a sensor with ``rezero=False`` keeps the
record's zero, less its stated offset. The input keeps its own name and unit; the rig's drive
turns it into hub torque. A link reading no elastic link gives in its unit (a deflection longer
than the link, a strain above 1 %, a deflection angle above 1 rad) is refused as logged in
another unit. A rig without sensors reads records of the simulator's outputs (the
reference format) as they are, cut to the window.

:func:`load_records` reads a rig's record files (or takes records already read) and makes them
ready, as the command line does; :func:`validate` simulates a fit on such records and scores
each channel (NRMSE, percent);
:func:`logged_record` goes the other way: what the rig would log, simulated.
"""

from __future__ import annotations

import math
import os
import warnings
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path

import numpy as np

from jaxflex.data import OUTPUT_COLUMNS, Dataset, Record, load_dataset, load_record
from jaxflex.metrics import nrmse
from jaxflex.model import Model
from jaxflex.noise import NoiseLevel
from jaxflex.objective import check_inputs, check_records, fitted_channels
from jaxflex.rest import (
    REST_SPAN,
    rest_bands,
    rest_stretch,
    stated_rest,
    why_not_at_rest,
)
from jaxflex.sensors import (
    AbstractSensor,
    DeflectionSensor,
    Encoder,
    StrainGauge,
    calibrated,
    readings,
)
from jaxflex.simulation import OUTPUT_NAMES, simulate

Window = tuple[float, float] | None
"""``(t0, t1)`` in a record's own time (seconds), or None for the whole record."""


def logged_sensors(model: Model, record: Record) -> tuple[AbstractSensor, ...]:
    """The rig's sensors whose channels ``record`` holds (at least one, else a one-line error)."""
    found = tuple(s for s in model.sensors if s.channel in record.columns)
    if not found:
        raise ValueError(
            f"record {record.name!r} holds none of rig {model.name!r}'s sensor channels "
            f"{list(model.channels)}; its columns are {list(record.columns)}"
        )
    return found


def model_record(model: Model, record: Record, window: Window = None, *,
                 at_rest: bool = True) -> Record:
    """``record`` (cut to ``window``, in its own time) as the rig's model reads it: the input
    and the sensors' channels re-zeroed at rest (module doc). The readings' units are checked
    first (:func:`_check_scale`), then the rest at the window's start
    (:func:`~jaxflex.rest.why_not_at_rest`: the samples before the input switches on, or before
    the rest the record's header states ends, when that comes within
    :data:`~jaxflex.rest.REST_SPAN`), and the zero is the mean over those samples of the window.
    A record that does not start at rest (``at_rest=False``, for an estimated or periodic start:
    :mod:`jaxflex.initial`) cannot be re-zeroed there: an encoder is zeroed at its first sample
    (the estimated start angle takes up the rest), every other sensor keeps the record's zero
    less its stated offset. A rig without sensors reads the simulator's outputs as they are,
    but for the joint angle, whose zero is an encoder's, re-zeroed at the window's first sample
    when it starts at rest."""
    check_inputs([record], model)
    if not model.sensors:
        return _reference_record(record, window, at_rest)
    cut = record.trim(*window) if window is not None else record.trim()
    chosen = logged_sensors(model, record)
    n_rest = _rest_samples(record, window, cut.dt) if at_rest else 1
    columns = {"time": cut.time, cut.input_name: cut.input}
    for sensor in chosen:
        reading = cut.channel(sensor.channel)
        rezero = sensor.rezero and (at_rest or isinstance(sensor, Encoder))
        zero = float(np.mean(reading[:n_rest])) if rezero else sensor.offset
        columns[sensor.channel] = reading - zero
        _check_scale(model, record.name, sensor, columns[sensor.channel])
    if at_rest:
        bands = rest_bands(chosen, record)
        moving = why_not_at_rest(record.time, {c: record.channel(c) for c in bands}, bands,
                                 name=record.name, t0=None if window is None else window[0],
                                 input_signal=record.input, rested=stated_rest(record))
        if moving is not None:
            raise ValueError(moving)
    found = ", ".join(s.channel for s in chosen)
    where = "at rest" if at_rest else "at its first sample"
    zeros = ", ".join(f"{s.channel} re-zeroed {where}" if s.rezero and (
        at_rest or isinstance(s, Encoder)) else f"{s.channel} less its offset {s.offset!r}"
        for s in chosen)
    ready = cut.with_columns(columns, note=zeros)
    return ready.replace(metadata=ready.metadata | {"rig": model.name, "sensors": found})


def _rest_samples(record: Record, window: Window, dt: float) -> int:
    """How many samples from the window's start re-zero its readings: :data:`REST_SPAN`'s, or
    those before the input switches on (or the header's stated rest ends) when fewer."""
    n_rest = max(2, int(round(REST_SPAN / dt)))
    t0 = None if window is None else window[0]
    stretch = rest_stretch(record.time, record.input, t0=t0, rested=stated_rest(record))
    first = int(np.searchsorted(record.time, (record.time[0] if t0 is None else t0) - 1e-6 * dt))
    return max(1, min(n_rest, stretch.stop - first))


def _reference_record(record: Record, window: Window, at_rest: bool) -> Record:
    """A record of the simulator's outputs cut to ``window``, its joint angle re-zeroed at the
    first sample when it starts ``at_rest``: an encoder's zero is wherever it was switched on,
    and the simulation starts from 0."""
    cut = record if window is None else record.trim(*window)
    if not at_rest or "joint_angle" not in cut.columns or cut.channel("joint_angle")[0] == 0:
        return cut
    angle = cut.channel("joint_angle")
    columns = {c: cut.channel(c) for c in cut.columns} | {"joint_angle": angle - angle[0]}
    return cut.with_columns(columns, note=f"joint_angle re-zeroed at rest ({float(angle[0])!r} "
                            "rad at the first sample)")


def rest_span(model: Model) -> float:
    """Seconds of stillness that show ``model``'s arm at rest when a window is found
    (``--window auto``): :data:`~jaxflex.rest.REST_SPAN`, or one period of the link's lowest
    mode with the hub held (at the rig's reference parameters) where that is longer. A lightly
    damped link rings on while friction holds the hub, and a shorter span can fall on a crest
    or a trough of the ringing, where the readings pause."""
    from scipy.linalg import eigh

    structure = model.structure(model.space.reference() | model.fixed_values)
    mass = np.asarray(structure.mass, dtype=np.float64)[1:, 1:]
    stiffness = np.asarray(structure.stiffness, dtype=np.float64)[1:, 1:]
    lowest = float(eigh(stiffness, mass, eigvals_only=True, subset_by_index=[0, 0])[0])
    return max(REST_SPAN, 2.0 * np.pi / np.sqrt(lowest)) if lowest > 0 else REST_SPAN


def channel_notes(model: Model, records: Sequence[Record]) -> list[str]:
    """One line for each record that does not log every channel the rig reads (the rig's
    sensor channels; for a rig without sensors, the reference format's
    :data:`~jaxflex.records.OUTPUT_COLUMNS`): only those it logs are used from it; and one for
    each record holding a column the rig reads nothing from (no sensor of the rig, or for a rig
    without sensors no simulator output), which is ignored. Nothing for records that log just
    what the rig reads."""
    used = fitted_channels(records, model)
    candidates = model.channels or OUTPUT_COLUMNS
    known = {"time", *candidates, *used, *(() if model.sensors else OUTPUT_NAMES)}
    notes = []
    for record in records:
        missing = [c for c in candidates if c not in record.columns]
        own = [c for c in used if c in record.columns]
        if missing and own:
            what = "a channel" if len(missing) == 1 else "channels"
            notes.append(f"record {record.name!r} does not log {', '.join(missing)}, {what} of "
                         f"rig {model.name!r}: only {', '.join(own)} is used from it")
        ignored = [c for c in record.columns if c not in known and c != record.input_name]
        if ignored:
            what = "column {} is" if len(ignored) == 1 else "columns {} are"
            where = (f"no sensor channel of rig {model.name!r} ({', '.join(model.channels)})"
                     if model.sensors else
                     f"no output jaxflex simulates ({', '.join(OUTPUT_NAMES)})")
            notes.append(f"record {record.name!r}: {what.format(', '.join(ignored))} {where}: "
                         "ignored")
    return notes


MAX_RATE_RATIO = 10.0
"""A record sampled this many times more slowly than its rig's ``sampling.dt`` or more is in
other time units (sample numbers, ms): a rig's log is at its rate or faster."""


def check_rate(model: Model, record: Record) -> None:
    """Stop (one-line ValueError) on a record whose samples lie :data:`MAX_RATE_RATIO` times
    the rig's ``sampling.dt`` apart or more: its time is in sample numbers or ms, or the rig
    file states another rate than the one it logs at."""
    dt, step = model.testbed.dt, record.dt
    if step >= MAX_RATE_RATIO * dt:
        raise ValueError(
            f"record {record.name!r}: its samples are {step:.6g} s apart, {step / dt:.3g} times "
            f"the sampling.dt of {dt:g} s of rig {model.name!r}; is its time in sample numbers "
            "or ms? time must be in s (or give the rig file the sampling.dt it logs at)"
        )


MAX_COUNT_RATIO = 20.0
"""An encoder's channel whose smallest step is this many of its counts or more is in another
unit: counts (``counts_per_revolution/2π`` of them), mrad (1000), degrees (57.3)."""


def _check_counts(name: str, sensor: Encoder, reading: np.ndarray) -> None:
    """Stop (one-line ValueError) on an encoder's channel that moves only in steps of
    :data:`MAX_COUNT_RATIO` counts or more: it is logged in another unit than its rig declares,
    and the likeliest one is named."""
    steps = np.abs(np.diff(reading))
    steps = steps[steps > 0]
    if not (sensor.resolution > 0 and steps.size):
        return
    ratio = float(np.min(steps)) / sensor.resolution
    if ratio < MAX_COUNT_RATIO:
        return
    per_rad = sensor.gain  # the declared unit per rad
    units = {"counts": sensor.counts_per_revolution / (2 * np.pi), "mrad": 1e3,
             "deg": 180 / np.pi}
    guess = min(units, key=lambda u: abs(np.log(ratio * per_rad / units[u])))
    unit = sensor.channel_unit
    raise ValueError(
        f"record {name!r}: channel {sensor.channel!r} moves in steps of {float(np.min(steps)):.6g}"
        f", {ratio:.3g} of the encoder's counts of {sensor.resolution:.3g} {unit}; is it in "
        f"{guess}? the rig reads it in {unit}: declare the encoder's reading_unit = {guess!r} "
        "in the rig file (its gain and resolution follow)"
    )


MAX_STRAIN = 0.01
"""A bending strain above 1 % is not an elastic link's (steel yields near 0.2 %): µε or %."""
MAX_DEFLECTION_ANGLE = 1.0
"""A link deflection angle above 1 rad is no small deflection: mrad or degrees."""


def _check_scale(model: Model, name: str, sensor: AbstractSensor, reading: np.ndarray) -> None:
    """Stop (one-line ValueError) on a link reading no elastic link gives in the sensor's unit:
    a deflection longer than the link, a strain above :data:`MAX_STRAIN`, a deflection angle
    above :data:`MAX_DEFLECTION_ANGLE`: the channel is logged in another unit."""
    peak = float(np.max(np.abs(reading))) if reading.size else 0.0
    quantity = peak / abs(sensor.gain)
    length = model.testbed.length
    if isinstance(sensor, DeflectionSensor) and quantity > length:
        why = (f"a deflection longer than the link ({length!r} m); is it in mm (or mrad)? a "
               "deflection sensor's channel must be in m")
    elif isinstance(sensor, StrainGauge) and sensor.calibration == "strain" and (
            quantity > MAX_STRAIN):
        why = (f"a strain above {MAX_STRAIN:.0%} (steel yields near 0.2 %); is it in µε or %? a "
               "strain channel must be in m/m")
    elif isinstance(sensor, StrainGauge) and sensor.calibration == "deflection_angle" and (
            quantity > MAX_DEFLECTION_ANGLE):
        why = (f"a deflection angle above {MAX_DEFLECTION_ANGLE:g} rad; is it in mrad or "
               "degrees? a deflection angle must be in rad")
    elif isinstance(sensor, Encoder):
        _check_counts(name, sensor, reading)
        return
    else:
        return
    unit = "" if sensor.unit == "1" else f" {sensor.unit}"
    raise ValueError(f"record {name!r}: channel {sensor.channel!r} reaches {peak:.6g}{unit} from "
                     f"rest, {why}")


def prepare(
    model: Model, records: Sequence[Record], windows: Sequence[Window] | None = None, *,
    at_rest: bool = True,
) -> list[Record]:
    """Each record made ready for ``model`` (:func:`model_record`), each cut to its window."""
    windows = [None] * len(records) if windows is None else list(windows)
    return [model_record(model, r, w, at_rest=at_rest)
            for r, w in zip(records, windows, strict=True)]


def load_records(
    paths: str | os.PathLike | Record | Iterable[str | os.PathLike | Record],
    rig: Model | str | os.PathLike,
    windows: Sequence[Window] | None = None,
    *,
    resample: bool = False,
    unit_check: bool = True,
) -> Dataset:
    """A rig's records, read as the command line reads them and made ready for its model.

    ``paths`` is a record file, a directory of them, or a sequence of files, directories and
    records already read (a :class:`~jaxflex.data.Record`, as :func:`jaxflex.datasets.load`
    gives). ``rig`` is a :class:`~jaxflex.model.Model`, a packaged rig's name or an arm file
    (:func:`jaxflex.arm.load_arm`). A column named as one of the rig's sensor channels is that
    sensor's (:func:`~jaxflex.data.load_record` with ``channels=``); each record is then cut to
    its window (``windows``: one ``(t0, t1)`` or None per record), checked to start at rest and
    re-zeroed (:func:`model_record`). ``resample`` and ``unit_check`` are
    :func:`~jaxflex.data.load_record`'s. The records keep the drive's input column and the
    rig's channels in their units: what :func:`jaxflex.identify`, :func:`jaxflex.compare` and
    :func:`jaxflex.discover` take with the same ``rig``.
    """
    from jaxflex.arm import load_arm

    model = rig if isinstance(rig, Model) else load_arm(rig)
    items = [paths] if isinstance(paths, (str, os.PathLike, Record)) else list(paths)
    records: list[Record] = []
    for item in items:
        if isinstance(item, Record):
            records.append(item)
        elif not isinstance(item, (str, os.PathLike)):
            raise TypeError(f"load_records: paths must be record files, directories or "
                            f"records, got {type(item).__name__}")
        elif Path(item).is_dir():
            records += load_dataset(item, resample=resample, unit_check=unit_check,
                                    channels=model.channels)
        else:
            records.append(load_record(item, resample=resample, unit_check=unit_check,
                                       channels=model.channels))
    return Dataset(prepare(model, Dataset(records), windows))


def fit_noise(model: Model, record: Record) -> dict[str, NoiseLevel]:
    """The noise model of each of the rig's sensors in ``record``, in its channel's unit (for
    ``discover``): white where the sensor has a noise level, else quantised at its resolution;
    a sensor with neither is left out (its level is estimated)."""
    levels = {}
    for sensor in logged_sensors(model, record):
        if sensor.noise > 0:
            levels[sensor.channel] = NoiseLevel(sigma=sensor.noise_std)
        elif sensor.resolution > 0:
            levels[sensor.channel] = NoiseLevel.quantised(sensor.resolution)
    return levels


def validate(
    records: Sequence[Record],
    model: Model,
    params: Mapping[str, float],
    windows: Sequence[Window] | None = None,
) -> dict[str, dict[str, float]]:
    """NRMSE (percent) of each channel the rig fits in each record, simulated at ``params``.

    Records are taken as they come (each cut to its window and re-zeroed at rest, as in
    :func:`model_record`); the whole record (or window) is scored. A channel that does not move
    in a record (zero throughout) has no NRMSE: NaN, with a warning that gives the RMS error in
    its unit.
    """
    check_records(records, "validate")
    scores: dict[str, dict[str, float]] = {}
    for ready in prepare(model, records, windows):
        out = calibrated(model, dict(params), simulate(model, dict(params), ready.input, ready.dt))
        scores[ready.name] = {c: _score(ready, c, np.asarray(out.channel(c)))
                              for c in fitted_channels([ready], model)}
    return scores


def _score(record: Record, channel: str, simulated: np.ndarray) -> float:
    """NRMSE (percent) of ``simulated`` against the record's ``channel``; NaN, with a warning
    giving the RMS error, where the channel is zero throughout (no motion)."""
    measured = record.channel(channel)
    if np.any(measured):
        return nrmse(measured, simulated)
    rms = float(np.sqrt(np.mean(np.square(simulated - measured))))
    warnings.warn(f"record {record.name!r}: {channel} is zero throughout (no motion); its NRMSE "
                  f"is undefined (NaN), its RMS error is {rms:.3g}", stacklevel=3)
    return math.nan


def logged_units(model: Model) -> dict[str, str]:
    """The unit of each column the rig logs: its drive's input and every sensor's channel (for
    the ``# units =`` line of its records: :func:`jaxflex.record_files.save_record`)."""
    return {model.drive.name: model.drive.unit} | {s.channel: s.channel_unit
                                                    for s in model.sensors}


def logged_record(
    model: Model,
    params: Mapping[str, float],
    time: np.ndarray,
    signal: np.ndarray,
    *,
    seed: int | None = None,
    name: str = "simulated",
    metadata: Mapping[str, str] | None = None,
) -> Record:
    """The record the rig would log under ``signal`` (in the drive's units): the drive's column
    and every sensor's reading with its offset, exact, or with each sensor's noise and
    quantisation drawn from ``seed`` (:meth:`~jaxflex.sensors.AbstractSensor.observe`)."""
    if not model.sensors:
        raise ValueError(f"rig {model.name!r} has no sensors: a record needs at least one output")
    time = np.asarray(time, dtype=np.float64)
    outputs = simulate(model, dict(params), signal, float(time[1] - time[0]))
    rng = None if seed is None else np.random.default_rng(seed)
    columns = {"time": time, model.drive.name: np.asarray(signal, dtype=np.float64)}
    read = readings(model, outputs, params=dict(params))
    for sensor in model.sensors:
        reading = np.asarray(read[sensor.channel]) + sensor.offset
        columns[sensor.channel] = reading if rng is None else sensor.observe(reading, rng)
    return Record.from_columns(columns, name=name,
                               metadata={"rig": model.name} | dict(metadata or {}))


__all__ = ["MAX_RATE_RATIO", "REST_SPAN", "channel_notes", "check_rate", "fit_noise",
           "load_records", "logged_record", "logged_sensors", "logged_units", "model_record",
           "prepare", "rest_span", "validate"]
