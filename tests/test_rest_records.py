"""Rest on records as rigs and loggers write them: an input that starts from zero, the file's
own stated rest, an encoder's arbitrary zero, noise-aware start checks, units checked before
rest, and a link that rings before its input."""

import math

import numpy as np
import pytest

from jaxflex.arm import arm_from_dict
from jaxflex.cli import UsageError, main
from jaxflex.cli._windows import Window, resolve_window
from jaxflex.data import Record, load_record
from jaxflex.initial import why_not_still
from jaxflex.measured import model_record, rest_span
from jaxflex.model import Model
from jaxflex.rest import REST_SPAN, find_rest, rest_bands, rest_note, stated_rest, why_not_at_rest
from jaxflex.sensors import Encoder, StrainGauge

try:
    import tomllib
except ModuleNotFoundError:  # Python < 3.11
    import tomli as tomllib

#: A lab strip, not the reference one: 0.8 m of 30 x 1.5 mm steel, a 2000-count encoder, an
#: accelerometer part-way along it, lightly damped (zeta near 0.005 in its first mode).
LAB_STRIP = """
name = "lab_strip"
description = "0.8 m steel strip, 2000-count encoder, accelerometer at 0.45 m"

[link]
length = 0.8
width = 0.03
thickness = 0.0015
density = 7850.0

[sampling]
dt = 1e-3
duration = 1.5

[parameters]
E = { reference = 2.0e11, lower = 1.0e11, upper = 3.0e11 }
J_h = { reference = 0.01, lower = 1e-3, upper = 0.1 }
b_v = { reference = 1e-3, lower = 1e-5, upper = 0.3 }
tau_c = { reference = 0.05, lower = 1e-3, upper = 0.3 }
alpha = { reference = 0.05, lower = 1e-3, upper = 4.0 }
beta = { reference = 1e-5, lower = 1e-7, upper = 2e-4 }

[drive]
type = "torque"

[[sensors]]
type = "encoder"
channel = "angle"
counts_per_revolution = 2000

[[sensors]]
type = "accelerometer"
channel = "acc"
x = 0.45
noise = 0.002
"""
ARM = arm_from_dict(tomllib.loads(LAB_STRIP), "lab_strip.toml")
COUNT = 2 * math.pi / 2000
SIGMA = 0.002  # m/s^2, the accelerometer's noise
DT = 1e-3


def logged(values, digits=7):
    """``values`` as a logger writes them: ``digits`` significant digits."""
    return np.array([float(f"{v:.{digits - 1}e}") for v in np.asarray(values, dtype=np.float64)])


def bench_record(acc, torque, start=12.0, counts=137, name="bench"):
    """A logged record of the lab strip: time from ``start``, the encoder still at ``counts``
    (its zero is wherever it was switched on), ``acc`` and ``torque`` as given."""
    t = start + np.arange(acc.size) * DT
    return Record(time=logged(t, 9), torque=logged(torque), name=name,
                  extras={"angle": np.full(acc.size, counts * COUNT), "acc": logged(acc)})


def bands_of(record):
    bands = rest_bands(ARM.sensors, record)
    return bands, {c: record.channel(c) for c in bands}


# -- an input that starts from zero ---------------------------------------------------------


def test_a_record_still_until_its_input_switches_on_starts_at_rest():
    """The input ramps from zero at the first sample and the accelerometer follows at once: it
    moves right after t0, not at t0; held on from t0 instead, the same readings are refused."""
    rng = np.random.default_rng(4)
    n = 400
    ramp = 0.4 * np.arange(n) / n  # N m, from zero at the first sample
    response = 30.0 * np.clip(np.arange(n) - 3, 0, None) * DT  # m/s^2, from the 4th sample
    record = bench_record(response + SIGMA * rng.standard_normal(n), ramp)
    bands, channels = bands_of(record)
    assert why_not_at_rest(record.time, channels, bands, name="bench",
                           input_signal=record.input) is None
    held = bench_record(record.channel("acc"), ramp + 0.1)  # on from t0: the span is judged
    moving = why_not_at_rest(held.time, channels, bands, name="bench", input_signal=held.input)
    assert moving.startswith("record 'bench' does not start at rest at t = 12 s: 'acc' changes by")
    assert "in the first 0.05 s" in moving
    # the window starts where the arm is still: zeroed over the samples before the input
    ready = model_record(ARM, record)
    assert ready.channel("angle")[0] == 0.0
    assert abs(ready.channel("acc")[0]) < 4 * SIGMA


def test_a_record_moving_before_its_input_switches_on_is_refused():
    """A link ringing at t0 (the input still off for 20 ms) moves at t0: it is refused, and the
    message says over which samples."""
    n = 400
    t = np.arange(n) * DT
    ring = 2.0 * np.sin(2 * np.pi * 3.0 * t + 0.4)  # m/s^2, far above the 16 mm/s^2 band
    torque = np.where(t >= 0.02, 0.3, 0.0)
    record = bench_record(ring, torque)
    bands, channels = bands_of(record)
    moving = why_not_at_rest(record.time, channels, bands, name="bench",
                             input_signal=record.input)
    assert moving is not None and moving.startswith(
        "record 'bench' does not start at rest at t = 12 s: 'acc' changes by")
    assert "from t = 12 s until its input switches on at t = 12.02 s" in moving


def test_a_window_cut_where_the_input_crosses_zero_mid_motion_is_refused():
    """A window starting at a zero crossing of a sine input, the arm in full swing: the span
    before the input switches on again reaches back into the motion."""
    n = 2000
    t = np.arange(n) * DT
    torque = 0.3 * np.sin(2 * np.pi * 1.0 * t)  # crosses zero at 0.5 s, 1.0 s, ...
    acc = 5.0 * np.sin(2 * np.pi * 1.0 * t - 0.3)
    record = bench_record(acc, torque)
    bands, channels = bands_of(record)
    moving = why_not_at_rest(record.time, channels, bands, name="bench", t0=13.0,
                             input_signal=record.input)
    assert moving is not None and "until its input switches on at" in moving


def test_simulate_on_a_rig_writes_records_that_start_at_rest(tmp_path, capsys):
    """`simulate --arm` with no rest before the input (`--rest 0`): a triangle, which starts
    from zero, and a pulse, which does not but whose header says so, are read as at rest."""
    rig = tmp_path / "lab_strip.toml"
    rig.write_text(LAB_STRIP)
    records = {}
    for shape in ("triangular", "pulse"):
        out = tmp_path / f"{shape}.csv"
        assert main(["simulate", "--arm", str(rig), "--input", shape, "--add-noise",
                     "--duration", "0.5", "--out", str(out)]) == 0
        records[shape] = load_record(out, channels=("angle", "acc"))
    assert stated_rest(records["pulse"]) == (0.0, 0.0)
    for shape, record in records.items():
        ready = model_record(ARM, record)  # does not raise
        assert ready.channel("angle")[0] == 0.0, shape
        window = resolve_window(Window("auto", auto=True), record, rest_bands(ARM.sensors, record),
                                rest_span(ARM))
        assert window == (0.0, 0.5), shape  # from its first sample, the rest it holds
    # the same pulse without its header's word moves from its first sample: refused
    bare = records["pulse"].replace(metadata={})
    with pytest.raises(ValueError, match=r"^record 'pulse' does not start at rest at t = 0 s: "):
        model_record(ARM, bare)
    capsys.readouterr()


def test_the_header_states_the_rest_and_older_simulated_headers_count():
    record = Record(time=np.arange(5) * 0.1, torque=np.ones(5), joint_angle=np.zeros(5))
    assert stated_rest(record.replace(metadata={"rest": rest_note(0.0, 0.2)})) == (0.0, 0.2)
    older = {"generator": "jaxflex simulate --arm",
             "input": "pulse, torque (N m), after 0.3 s at rest"}
    assert stated_rest(record.replace(metadata=older)) == (0.0, pytest.approx(0.3))
    assert stated_rest(record.replace(metadata=older | {"generator": "a logger"})) is None
    assert stated_rest(record.replace(metadata={"rest": "a while"})) is None


# -- an encoder's zero, and noise ------------------------------------------------------------


def test_an_encoder_zero_off_at_rest_is_re_zeroed_in_the_reference_format():
    """A reference-format record whose encoder reads 137 counts (of 2000) at rest: fitted from
    zero, the start check has nothing to say (it recommended an estimated start before)."""
    n = 300
    t = np.arange(n) * DT
    angle = 137 * COUNT + np.round(0.5 * np.clip(t - 0.01, 0, None) ** 2 / COUNT) * COUNT
    record = Record(time=t, torque=np.where(t >= 0.01, 0.2, 0.0), joint_angle=angle,
                    tip_acceleration=np.zeros(n), name="offset_encoder")
    model = Model()
    assert "joint_angle starts at" in why_not_still(record, model, ("joint_angle",))
    ready = model_record(model, record)
    np.testing.assert_allclose(ready.joint_angle, angle - 137 * COUNT, rtol=0, atol=1e-15)
    assert why_not_still(ready, model, ("joint_angle",)) is None
    assert "joint_angle re-zeroed at rest" in ready.metadata["history"]
    started = record.replace(joint_angle=angle - 137 * COUNT)  # already at zero: unchanged
    assert model_record(model, started) is started


def test_a_reading_well_within_its_noise_of_zero_is_still():
    """A strain gauge reading 0.67 sigma off zero at the start is not 'moving' (its range is
    small, so 2 % of it is below its noise); 10 sigma off is."""
    sigma = 1e-6
    model = Model(sensors=(Encoder(channel="angle", counts_per_revolution=2000),
                           StrainGauge(channel="strain", x=0.05, noise=sigma)))
    rng = np.random.default_rng(7)
    n = 500
    t = np.arange(n) * DT
    swing = 2e-5 * np.sin(2 * np.pi * 2.0 * np.clip(t - 0.1, 0, None)) * (t > 0.1)
    for off, moved in ((0.67, False), (10.0, True)):
        strain = off * sigma + swing + sigma * rng.standard_normal(n)
        record = Record(time=t, torque=np.where(t >= 0.1, 0.1, 0.0), name="gauge",
                        extras={"angle": np.zeros(n), "strain": logged(strain, 6)})
        said = why_not_still(record, model, ("angle", "strain"))
        assert (said is not None and "strain starts at" in said) == moved, off


# -- units before rest ------------------------------------------------------------------------


@pytest.mark.parametrize(("sensor", "scale", "message"), [
    ({"type": "deflection", "channel": "laser", "x": 0.7, "noise": 2e-5}, 1e3,
     r"channel 'laser' reaches .* a deflection longer than the link \(0.8 m\); is it in mm"),
    ({"type": "strain_gauge", "channel": "gauge", "x": 0.02, "noise": 2e-7}, 1e6,
     r"channel 'gauge' reaches .* a strain above 1% .*; is it in µε or %"),
])
def test_a_link_reading_in_another_unit_is_named_before_rest(sensor, scale, message):
    """A laser in mm, a strain in µε: their noise, stated in m and m/m, makes them move far
    beyond their rest bands, but what is wrong is the unit, and that is what is said."""
    data = tomllib.loads(LAB_STRIP)
    data["sensors"] = [data["sensors"][0], sensor]
    arm = arm_from_dict(data, "lab_strip.toml")
    rng = np.random.default_rng(1)
    n = 400
    t = np.arange(n) * DT
    quantity = 0.02 if sensor["type"] == "deflection" else 2e-4  # m, m/m: a real swing
    reading = (quantity * np.sin(2 * np.pi * 2 * t) + 20 * sensor["noise"]
               * rng.standard_normal(n)) * scale
    record = Record(time=t, torque=np.where(t >= 0.1, 0.2, 0.0), name="units",
                    extras={"angle": np.zeros(n), sensor["channel"]: logged(reading)})
    with pytest.raises(ValueError, match=message):
        model_record(arm, record)


# -- a link that rings before its input -------------------------------------------------------


def cantilever_period(length, thickness, modulus, density):
    """The first period (s) of a clamped-free strip (Euler-Bernoulli):
    ``f1 = 1.8751² / (2π L²) · sqrt(E t² / (12 ρ))``."""
    f1 = 1.8751**2 / (2 * math.pi * length**2) * math.sqrt(modulus * thickness**2 / (12 * density))
    return 1.0 / f1


def test_the_rest_span_of_a_rig_is_its_link_s_lowest_period():
    period = cantilever_period(0.8, 0.0015, 2.0e11, 7850.0)  # 0.524 s, 1.91 Hz
    assert rest_span(ARM) == pytest.approx(period, rel=0.01)
    stiff = arm_from_dict(tomllib.loads(LAB_STRIP.replace("length = 0.8", "length = 0.1")
                                        .replace("x = 0.45", "x = 0.05")), "short.toml")
    assert rest_span(stiff) == REST_SPAN  # 122 Hz: a period well inside the 0.05 s


def test_auto_refuses_a_link_ringing_before_its_input():
    """A lightly damped link (zeta = 0.007) rings at its first mode through the whole second
    before the input, the hub held by friction: 0.05 s found a still span at a crest of the
    ringing; a span of the lowest period finds none, and says so."""
    period = rest_span(ARM)
    omega = 2 * math.pi / period
    n = 1500
    t = np.arange(n) * DT
    zeta, amplitude = 0.007, 40 * SIGMA
    ring = amplitude * np.exp(-zeta * omega * t) * np.cos(omega * t + 1.0)
    rng = np.random.default_rng(11)
    torque = np.where(t >= 1.0, 0.3, 0.0)
    acc = ring + np.where(t >= 1.0, 20.0 * (t - 1.0), 0.0) + SIGMA * rng.standard_normal(n)
    record = bench_record(acc, torque, name="ringing")
    bands, channels = bands_of(record)
    fooled = find_rest(record.time, channels, bands, record.input, name="ringing")
    assert fooled < 13.0 - 0.1  # the short span takes a crest of the ringing
    with pytest.raises(UsageError, match=(
            r"^--window auto: record 'ringing' is never at rest for 0.52\d* s before it "
            r"moves")):
        resolve_window(Window("auto", auto=True), record, bands, period)
    # a link at rest before the same input: the rest before it is found
    still = bench_record(acc - ring, torque, name="still")
    t0, _ = resolve_window(Window("auto", auto=True), still, bands, period)
    assert t0 == pytest.approx(13.0 - period, abs=2 * DT)


# -- a rig's rate against its records' -------------------------------------------------------


def test_a_record_in_sample_numbers_is_refused_against_the_rig_s_rate(tmp_path, capsys):
    """Time in sample numbers, the unit check skipped: the rig's sampling.dt says what is
    wrong before any fit starts (it fitted at dt = 1 s before)."""
    rig = tmp_path / "lab_strip.toml"
    rig.write_text(LAB_STRIP)
    n = 300
    rows = [f"{i},{0.2 * (i >= 50):.6g},{137 * COUNT:.9g},{0.01 * (i >= 50) * (i - 50):.7g}"
            for i in range(n)]
    data = tmp_path / "numbered.csv"
    data.write_text("time,torque,angle,acc\n" + "\n".join(rows) + "\n")
    assert main(["identify", str(data), "--arm", str(rig), "--no-unit-check",
                 "--out", str(tmp_path / "fit.json")]) == 2
    assert capsys.readouterr().err == (
        "jaxflex identify: error: record 'numbered': its samples are 1 s apart, 1e+03 times the "
        "sampling.dt of 0.001 s of rig 'lab_strip'; is its time in sample numbers or ms? time "
        "must be in s (or give the rig file the sampling.dt it logs at)\n")
    assert not (tmp_path / "fit.json").exists()


def test_the_daisy_record_is_at_its_packaged_rig_s_rate():
    from helpers import REAL_DATA_DIR, or_skip

    from jaxflex import datasets
    from jaxflex.arm import load_arm
    from jaxflex.measured import check_rate

    sweep = or_skip(datasets.load, "daisy_robot_arm", REAL_DATA_DIR)["sweep"]
    arm = load_arm("daisy_robot_arm")
    assert sweep.dt == pytest.approx(arm.testbed.dt, rel=1e-12)
    check_rate(arm, sweep)  # agrees
    with pytest.raises(ValueError, match=r"its samples are 1 s apart, 100 times the sampling"):
        check_rate(arm, sweep.replace(time=np.arange(sweep.n_samples, dtype=np.float64)))


# -- an encoder's unit ------------------------------------------------------------------------


def encoder_log(tmp_path, values, digits=9):
    """A CSV of the lab strip's log with the encoder column ``joint_angle`` as given."""
    n = values.size
    torque = [0.2 * (i >= 100) for i in range(n)]
    acc = [0.01 * max(0, i - 100) for i in range(n)]
    rows = [f"{i * DT:.6f},{u:.6g},{a:.{digits - 1}e},{y:.7g}"
            for i, (u, a, y) in enumerate(zip(torque, values, acc, strict=True))]
    path = tmp_path / "encoder.csv"
    path.write_text("time,torque,joint_angle,acc\n" + "\n".join(rows) + "\n")
    return path


def encoder_rig(unit=None, gain=None):
    data = tomllib.loads(LAB_STRIP)
    data["sensors"][0]["channel"] = "joint_angle"
    if unit is not None:
        data["sensors"][0]["reading_unit"] = unit
    if gain is not None:
        data["sensors"][0]["gain"] = gain
    return arm_from_dict(data, "lab_strip.toml")


def turning(n=600):
    """Whole counts of a 2000-count encoder: 137 at rest, then turning ever faster."""
    i = np.arange(n)
    return 137 + np.floor(0.002 * np.clip(i - 110, 0, None) ** 2)


def test_an_encoder_declared_in_counts_is_converted_and_read_without_a_warning(tmp_path):
    import warnings

    arm = encoder_rig("counts")
    encoder = arm.sensor("joint_angle")
    assert encoder.gain == pytest.approx(2000 / (2 * math.pi)) and encoder.resolution == 1.0
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # "holds only whole numbers ... encoder counts" before
        record = load_record(encoder_log(tmp_path, turning()), channels=arm.channels)
    ready = model_record(arm, record)
    np.testing.assert_array_equal(ready.channel("joint_angle"), turning() - 137)
    with pytest.raises(ValueError, match=r"gain=3.0 but reading_unit 'counts' is 318.30988"):
        encoder_rig("counts", gain=3.0)
    assert encoder_rig("mrad").sensor("joint_angle").gain == 1e3


@pytest.mark.parametrize(("scale", "guess"), [(2000 / (2 * math.pi), "counts"), (1e3, "mrad")])
def test_an_encoder_logged_in_another_unit_than_its_rig_declares_is_refused(
        tmp_path, scale, guess):
    """The rig says rad; the log is in counts, or in mrad: refused, naming the likely unit, and
    before the rest check (in counts the arm looks far from still)."""
    arm = encoder_rig()
    values = turning() * COUNT * scale  # the same motion in the other unit
    record = load_record(encoder_log(tmp_path, values), channels=arm.channels)
    with pytest.raises(ValueError, match=(
            rf"^record 'encoder': channel 'joint_angle' moves in steps of .*; is it in {guess}\? "
            rf"the rig reads it in rad: declare the encoder's reading_unit = '{guess}'")):
        model_record(arm, record)
    rad = load_record(encoder_log(tmp_path, turning() * COUNT), channels=arm.channels)
    model_record(arm, rad)  # in rad, as declared: read
