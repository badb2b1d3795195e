"""discover on records jaxflex did not write: data-logger file formats, an independent integrator.

Every record set is simulated (by jaxflex, or by SciPy Radau on the FEM equations in
``reference_solver``, a payload and a tilted plane included), read by an encoder of ``counts``
per revolution whose grid is offset from zero and by an accelerometer with the spec's white
noise, and written to CSV as a data logger writes it: with a fixed number of significant digits,
or as float32 numbers. ``discover`` starts near the truth (as in ``test_discover``) or, in slow
cases, identifies the base model from scratch; it estimates every noise level from the files,
and must add nothing to clean records, name a hidden payload or a tilted plane and nothing
beside it, and end within 1.3× the noise floor: the NRMSE of the noise-free truth against the
written records. Slow cases add a compliant clamp and Stribeck friction whose velocity lies
between the discovery grid's starts, read by a coarse encoder.

A few representative cases run by default; the whole matrix (6, 7, 9 and 17 digits, float32,
1024–10000 counts, 500 Hz and 1 kHz, 1.5–3 s) is marked slow.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
from discovery_cases import START, TRUTH
from reference_solver import radau_reference

from jaxflex.comparison import DEFAULT_T_END
from jaxflex.data import Dataset, load_record
from jaxflex.discovery import discover
from jaxflex.effects import Stribeck, get_effect
from jaxflex.metrics import nrmse
from jaxflex.model import Model
from jaxflex.signals import reference_input
from jaxflex.simulation import simulate
from jaxflex.synthetic import ACCELEROMETER_SIGMA

INPUTS = ("triangular", "pulse", "half_sine")
PAYLOAD = 0.03  # kg, the hidden effect
TILT = 0.06  # rad, the motion plane's tilt: another hidden effect
COMPLIANCE = 0.04  # rad/(N m), a compliant clamp: another (it moves the first mode far)
#: A clamp so compliant that the base model cannot follow its first mode: 4.43 Hz, below the
#: 4.79 Hz of the softest link the base model allows (E = 20 GPa).
LOOSE_CLAMP = 0.3  # rad/(N m)
STRIBECK = Stribeck(v_s=0.2)  # a Stribeck velocity between the discovery grid's starts
EXCESS = 0.04  # N m, its breakaway torque above the Coulomb level
CHANNELS = ("joint_angle", "tip_acceleration")
FLOOR_FACTOR = 1.3


@dataclass(frozen=True)
class Logger:
    """How a logger records: digits (``None``: float32), encoder counts/rev, rate, duration."""

    digits: int | None
    counts: int
    rate: float  # Hz
    duration: float  # s

    @property
    def step(self) -> float:
        return 2.0 * math.pi / self.counts

    @property
    def offset(self) -> float:
        """Where the encoder's grid sits: a fraction of a count away from zero."""
        return 0.37 * self.step

    def __str__(self) -> str:
        digits = "float32" if self.digits is None else f"{self.digits}digits"
        return f"{digits}-{self.counts}cpr-{self.rate:g}Hz-{self.duration:g}s"

    def write(self, values: np.ndarray) -> list[str]:
        if self.digits is None:
            return [str(np.float32(v)) for v in values]
        return [f"{v:.{self.digits - 1}e}" for v in values]


MATRIX = (
    Logger(6, 1024, 1000.0, 2.0),
    Logger(7, 2000, 500.0, 3.0),
    Logger(9, 4096, 1000.0, 1.5),
    Logger(17, 10000, 500.0, 2.0),
    Logger(None, 4096, 1000.0, 3.0),
    Logger(6, 10000, 1000.0, 1.5),
    Logger(9, 1000, 500.0, 1.5),
    Logger(None, 2000, 500.0, 2.0),
)
DEFAULT_CLEAN = MATRIX[0]
#: The layout of the clean default (and of test_discover), so the compiled Jacobian is shared.
DEFAULT_PAYLOAD = Logger(9, 4096, 1000.0, 2.0)
#: A coarse encoder (2000 counts, its grid offset) at 1 kHz, in 9 digits and in float32.
COARSE = (Logger(9, 2000, 1000.0, 2.0), Logger(None, 2000, 1000.0, 2.0))


def jaxflex_outputs(model, params, torque, dt):
    out = simulate(model, params, torque, dt)
    return np.asarray(out.joint_angle), np.asarray(out.tip_acceleration)


def radau_outputs(model, params, torque, dt):
    angle, acceleration, _ = radau_reference(model, params, torque, dt, rtol=1e-8, atol=1e-10)
    return angle, acceleration


def logger_records(folder: Path, logger: Logger, effects: dict, outputs=jaxflex_outputs,
                   seed: int = 0) -> tuple[Dataset, dict[str, float]]:
    """The records of the truth (base ``TRUTH`` plus ``effects``: effect or name →
    {param: value}) as ``logger`` writes them, and the noise floor per channel: the NRMSE (%)
    of the noise-free truth over the first 2 s, where discover reports its NRMSE, mean over the
    records."""
    model = Model().with_effects(*(get_effect(e) if isinstance(e, str) else e for e in effects))
    params = {**TRUTH, **{k: v for values in effects.values() for k, v in values.items()}}
    dt = 1.0 / logger.rate
    rng = np.random.default_rng(seed)
    records, floors = [], []
    for name in INPUTS:
        time, torque = reference_input(name, duration=logger.duration, dt=dt)
        angle, acceleration = outputs(model, params, torque, dt)
        read = logger.offset + logger.step * np.round((angle - logger.offset) / logger.step)
        noisy = acceleration + ACCELEROMETER_SIGMA * rng.standard_normal(acceleration.size)
        path = folder / f"{name}.csv"
        columns = [logger.write(c) for c in (time, torque, read, noisy)]
        lines = ["time,torque,joint_angle,tip_acceleration"]
        lines += [",".join(row) for row in zip(*columns, strict=True)]
        path.write_text("\n".join(lines) + "\n")
        record = load_record(path)
        records.append(record)
        window = time <= DEFAULT_T_END + 1e-9 * dt  # the window discover's NRMSE covers
        floors.append([nrmse(record.channel(c)[window], truth[window])
                       for c, truth in zip(CHANNELS, (angle, acceleration), strict=True)])
    return Dataset(records), dict(zip(CHANNELS, np.mean(floors, axis=0), strict=True))


def check_clean(report, floor, logger: Logger) -> None:
    assert report.added == () and report.unexplained is None, report.table()
    angle = report.noise["joint_angle"]
    assert angle.source == "quantisation", report.table()
    assert angle.step == pytest.approx(logger.step, rel=1e-6)
    assert f"noise level joint_angle: σ = {angle.sigma:.4g} rad (quantisation step q=" in (
        report.table())
    obtained = report.to_dict()["settings"]["noise"]
    assert obtained["joint_angle"]["source"] == "quantisation"
    assert obtained["tip_acceleration"]["obtained"] == "white, estimated"
    for c in CHANNELS:
        assert report.final.nrmse[c] <= FLOOR_FACTOR * floor[c], (c, floor, report.table())


def check_found(report, floor, effect: str, key: str, value: float) -> None:
    """The hidden ``effect`` and nothing else (no gain on the encoder beside it: one count is
    known exactly, so it is no default candidate), ``key`` within 5 % of ``value``."""
    assert report.added == (effect,) and report.unexplained is None, report.table()
    assert "sensor_gain:joint_angle" not in report.candidates
    assert report.params[key] == pytest.approx(value, rel=0.05)
    for c in CHANNELS:
        assert report.final.nrmse[c] <= FLOOR_FACTOR * floor[c], (c, floor, report.table())


def check_payload(report, floor) -> None:
    check_found(report, floor, "payload", "m_p", PAYLOAD)


def run_clean(tmp_path, logger, outputs=jaxflex_outputs):
    records, floor = logger_records(tmp_path, logger, {}, outputs)
    check_clean(discover(records, initial=START), floor, logger)


def run_payload(tmp_path, logger, outputs=jaxflex_outputs):
    records, floor = logger_records(tmp_path, logger, {"payload": {"m_p": PAYLOAD}}, outputs)
    check_payload(discover(records, initial=START), floor)


@pytest.mark.slow  # the clean Radau-integrated records below check the same
def test_clean_logger_records_add_nothing(tmp_path):
    run_clean(tmp_path, DEFAULT_CLEAN)


@pytest.mark.slow  # a discovery run; the fast set keeps one of its kind
def test_logger_records_name_a_hidden_payload(tmp_path):
    run_payload(tmp_path, DEFAULT_PAYLOAD)


@pytest.mark.slow  # a discovery run; the fast set keeps one of its kind
def test_radau_records_name_a_tilted_plane(tmp_path):
    records, floor = logger_records(tmp_path, DEFAULT_PAYLOAD, {"gravity": {"phi": TILT}},
                                    radau_outputs)
    check_found(discover(records, initial=START), floor, "gravity", "phi", TILT)


def test_radau_records_name_a_hidden_payload(tmp_path):
    run_payload(tmp_path, DEFAULT_PAYLOAD, radau_outputs)


@pytest.mark.slow
@pytest.mark.parametrize("logger", MATRIX, ids=str)
def test_clean_logger_matrix(tmp_path, logger):
    run_clean(tmp_path, logger)


@pytest.mark.slow
@pytest.mark.parametrize("logger", MATRIX, ids=str)
def test_payload_logger_matrix(tmp_path, logger):
    run_payload(tmp_path, logger)


def test_clean_radau_records_add_nothing(tmp_path):
    run_clean(tmp_path, DEFAULT_CLEAN, radau_outputs)


@pytest.mark.slow
def test_clean_radau_float32_records_add_nothing(tmp_path):
    run_clean(tmp_path, MATRIX[4], radau_outputs)


@pytest.mark.slow
@pytest.mark.parametrize("logger", [MATRIX[2], MATRIX[1]], ids=str)
def test_radau_records_payload(tmp_path, logger):
    run_payload(tmp_path, logger, radau_outputs)


@pytest.mark.slow
def test_radau_records_name_a_compliant_clamp(tmp_path):
    """The compliant clamp lowers the first mode far: the base fit softens E to follow it and
    the score of c_r points the wrong way at the null; its profile finds it."""
    records, floor = logger_records(tmp_path, COARSE[0],
                                    {"root_compliance": {"c_r": COMPLIANCE}}, radau_outputs)
    check_found(discover(records, initial=START), floor, "root_compliance", "c_r", COMPLIANCE)


@pytest.mark.slow
@pytest.mark.parametrize("logger", COARSE, ids=str)
def test_radau_records_fit_the_stribeck_velocity(tmp_path, logger):
    """Stribeck friction whose velocity is none of the grid's starts: the velocity is fitted
    with the breakaway torque, and the fit ends at the noise floor."""
    records, floor = logger_records(tmp_path, logger, {STRIBECK: {"delta_tau_s": EXCESS}},
                                    radau_outputs)
    report = discover(records, initial=START)
    check_found(report, floor, "stribeck", "delta_tau_s", EXCESS)
    assert report.params["v_s"] == pytest.approx(STRIBECK.v_s, rel=0.05)


@pytest.mark.slow
@pytest.mark.parametrize(("logger", "compliance"),
                         [(COARSE[0], COMPLIANCE), *((c, LOOSE_CLAMP) for c in COARSE)], ids=str)
def test_radau_records_name_a_compliant_clamp_from_scratch(tmp_path, logger, compliance):
    """The base model identified from scratch (differential evolution seeded around the
    rigid-body estimate), as ``jaxflex discover DATA.csv`` runs: behind a loose clamp the base
    fit stays far from the data, its link as soft as allowed, yet the clamp is named, and
    nothing else, and the fit ends at the noise floor."""
    records, floor = logger_records(tmp_path, logger,
                                    {"root_compliance": {"c_r": compliance}}, radau_outputs)
    report = discover(records)
    assert report.settings["initial"] == "identified"
    if compliance == LOOSE_CLAMP:
        base = report.steps[1]
        softest = Model().space["E"].lower
        assert base.fit.params["E"] == pytest.approx(softest, rel=1e-6), report.table()
        assert base.nrmse["tip_acceleration"] > 10 * floor["tip_acceleration"], report.table()
    check_found(report, floor, "root_compliance", "c_r", compliance)


@pytest.mark.slow
def test_clean_radau_records_from_scratch_add_nothing(tmp_path):
    records, floor = logger_records(tmp_path, COARSE[0], {}, radau_outputs)
    check_clean(discover(records), floor, COARSE[0])
