"""Records as they come from a rig, made ready for the simulator through an arm's drive and sensors.

A logged record holds the drive's input column (``torque``, ``current`` or ``voltage``), some
of the arm's sensor channels in their calibrated units, and time that may start anywhere.
:func:`model_record` cuts the requested window, checks that the arm is at rest at its start (the
simulation starts from rest), removes the rest readings and expresses each sensor channel as the
simulator output it reads (``(reading − offset)/(gain·factor)``, see
:meth:`~jaxflex.sensors.Sensor.simulated_output`). The input stays in the drive's units in the
``torque`` slot: the arm's model turns it into hub torque through its drive.

:func:`validate` simulates a fit on such records and scores each channel (NRMSE, percent);
:func:`logged_record` goes the other way: what the rig would log, simulated.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np

from jaxflex.arm import Arm
from jaxflex.data import Record
from jaxflex.diagnosis import NoiseLevel
from jaxflex.effects import Effect
from jaxflex.metrics import nrmse
from jaxflex.sensors import calibrated, readings
from jaxflex.simulation import simulate

REST_SPAN = 0.05
"""Seconds of stillness that count as rest at a window's start."""


def _at_rest(y: np.ndarray, n: int, step: float) -> bool:
    """True when ``y[:n]`` stays within two quantisation steps (or 1e-3 of its range)."""
    tolerance = max(2.0 * step, 1e-3 * float(np.ptp(y)), 1e-12)
    return float(np.ptp(y[:n])) <= tolerance


def _channels(arm: Arm, record: Record):
    model = arm.model()
    chosen = []
    for sensor in arm.sensors:
        if sensor.channel not in record.columns:
            continue
        mapping = sensor.simulated_output(model)
        if mapping is None:
            raise ValueError(
                f"sensor {sensor.channel!r} ({sensor.kind} at x = {sensor.position!r} m) has no "
                "standard simulated output to be fitted to; place it at the clamp (strain) or "
                "the tip (acceleration, deflection)"
            )
        chosen.append((sensor, *mapping))
    if not chosen:
        raise ValueError(
            f"record {record.name!r} holds none of arm {arm.name!r}'s sensor channels "
            f"{[s.channel for s in arm.sensors]}; its columns are {list(record.columns)}"
        )
    return chosen


def model_record(
    arm: Arm, record: Record, window: tuple[float, float] | None = None
) -> Record:
    """``record`` (cut to ``window``, in its own time) as the simulator sees it (module doc)."""
    drive = arm.drive.name
    if record.input_name != drive:
        raise ValueError(
            f"record {record.name!r} logs {record.input_name!r} but arm {arm.name!r} has a "
            f"{drive} drive, which reads a {drive!r} column"
        )
    chosen = _channels(arm, record)
    cut = record.trim(*window) if window is not None else record.trim()
    n_rest = max(2, int(round(REST_SPAN / cut.dt)))
    outputs: dict[str, np.ndarray] = {}
    for sensor, output, factor in chosen:
        reading = cut.channel(sensor.channel)
        if not _at_rest(reading, n_rest, sensor.resolution):
            t0 = float(record.time[0]) if window is None else float(window[0])
            raise ValueError(
                f"record {record.name!r} does not start at rest at t = {t0!r} s: "
                f"{sensor.channel!r} changes by {float(np.ptp(reading[:n_rest])):.3g} in the "
                f"first {REST_SPAN} s; the simulation starts from rest, so choose a window that "
                "starts where the arm is still (window=(t0, t1))"
            )
        value = (reading - sensor.offset) / (sensor.gain * factor)
        outputs[output] = value - float(np.mean(value[:n_rest]))
    standard = ("joint_angle", "tip_acceleration")
    extras = {c: v for c, v in outputs.items() if c not in standard}
    mapping = ", ".join(f"{s.channel} -> {o}" for s, o, _ in chosen)
    return Record(
        time=cut.time,
        torque=cut.channel(drive),
        joint_angle=outputs.get("joint_angle"),
        tip_acceleration=outputs.get("tip_acceleration"),
        extras=extras,
        name=record.name,
        metadata=cut.metadata
        | {"arm": arm.name, "input": f"{drive} ({arm.drive.unit}) in the torque column"}
        | {"sensors": mapping},
    )


def fit_channels(arm: Arm, record: Record) -> tuple[str, ...]:
    """The simulator outputs a record's sensor channels are fitted to (for ``identify``)."""
    return tuple(output for _, output, _ in _channels(arm, record))


def fit_noise(arm: Arm, record: Record) -> dict[str, NoiseLevel]:
    """The noise model of each sensor in ``record``, in the units of the simulator output it is
    fitted to (for ``discover``): white where the sensor has a noise level, else quantised at
    its resolution; a sensor with neither is left out (its level is estimated)."""
    levels = {}
    for sensor, output, factor in _channels(arm, record):
        scale = abs(sensor.gain * factor)
        if sensor.noise > 0:
            levels[output] = NoiseLevel(sigma=sensor.noise_std / scale)
        elif sensor.resolution > 0:
            levels[output] = NoiseLevel.quantised(sensor.resolution / scale)
    return levels


def validate(
    arm: Arm,
    params: Mapping[str, float],
    records: Sequence[Record],
    windows: Sequence[tuple[float, float] | None] | None = None,
    *,
    effects: Sequence[Effect] = (),
) -> dict[str, dict[str, float]]:
    """NRMSE (percent) of each sensor channel of each record, simulated at ``params``.

    Records are taken as they come (each cut to its window and re-zeroed at rest, as in
    :func:`model_record`); the whole record (or window) is scored. ``effects`` are added to the
    arm's model (``params`` then holds their parameters too).
    """
    windows = [None] * len(records) if windows is None else list(windows)
    model = arm.model(*effects)
    scores: dict[str, dict[str, float]] = {}
    for record, window in zip(records, windows, strict=True):
        ready = model_record(arm, record, window)
        out = calibrated(model, dict(params), simulate(model, dict(params), ready.torque, ready.dt))
        scores[record.name] = {
            sensor.channel: nrmse(ready.channel(output), out.channel(output))
            for sensor, output, _ in _channels(arm, record)
        }
    return scores


def logged_record(
    arm: Arm,
    params: Mapping[str, float],
    time: np.ndarray,
    signal: np.ndarray,
    *,
    effects: Sequence[Effect] = (),
    seed: int | None = None,
    name: str = "simulated",
    metadata: Mapping[str, str] | None = None,
) -> Record:
    """The record the rig would log under ``signal`` (in the drive's units): the drive's column
    and every sensor's reading, exact, or with each sensor's noise and quantisation drawn from
    ``seed`` (:meth:`~jaxflex.sensors.Sensor.observe`)."""
    if not arm.sensors:
        raise ValueError(f"arm {arm.name!r} has no sensors: a record needs at least one output")
    time = np.asarray(time, dtype=np.float64)
    model = arm.model(*effects)
    outputs = simulate(model, dict(params), signal, float(time[1] - time[0]))
    rng = None if seed is None else np.random.default_rng(seed)
    columns = {arm.drive.name: np.asarray(signal, dtype=np.float64)}
    for sensor in arm.sensors:
        read = readings([sensor], model, outputs, params=dict(params))
        reading = np.asarray(read[sensor.channel])
        columns[sensor.channel] = reading if rng is None else sensor.observe(reading, rng)
    standard = {c: columns.pop(c, None) for c in ("torque", "joint_angle", "tip_acceleration")}
    return Record(time=time, **standard, extras=columns, name=name,
                  metadata={"arm": arm.name} | dict(metadata or {}))


__all__ = ["REST_SPAN", "fit_channels", "fit_noise", "logged_record", "model_record",
           "validate"]
