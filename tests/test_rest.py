"""Rest: the tolerance rule, rounding-proof spread checks, why a window is not at rest, and
finding where a record rests before it moves."""

import math
import re

import numpy as np
import pytest
from helpers import ARMS
from scipy.ndimage import maximum_filter1d, minimum_filter1d

from jaxflex.arm import load_arm
from jaxflex.data import Record, load_record
from jaxflex.rest import (
    REST_HINT,
    RestBand,
    _sliding,
    find_rest,
    rest_band,
    rest_bands,
    rest_tolerance,
    spread_within,
    why_not_at_rest,
)
from jaxflex.sensors import Accelerometer, Encoder

COUNT = 2 * math.pi / 4096  # one step of a 4096-count encoder (rad)
DT = 0.001
ANGLE = {"joint_angle": rest_band(COUNT, 0.0, unit="rad")}


def quantised(x):
    return np.round(np.asarray(x) / COUNT) * COUNT


def rig(moves=((0.3, 0.6),), duration=1.0, start=0.0, offset=0.0):
    """Time, a quantised joint angle and a torque that is 1 N m while the arm ``moves``
    (intervals, s) and 0 otherwise; the arm turns at 2 rad/s while driven."""
    t = start + np.arange(round(duration / DT) + 1) * DT
    driven = np.zeros(t.size, dtype=bool)
    for lo, hi in moves:
        driven |= (t >= start + lo - 1e-9) & (t < start + hi - 1e-9)
    torque = driven.astype(float)
    angle = offset + np.cumsum(2.0 * DT * driven)
    return t, quantised(angle), torque


# -- the tolerance rule ---------------------------------------------------------------------


def test_a_quantised_reading_may_span_two_steps_and_noise_eight_sigma():
    assert rest_tolerance(COUNT, 0.0) == 2 * COUNT
    assert rest_tolerance(0.0, 0.01) == pytest.approx(0.08)
    assert rest_tolerance(COUNT, 0.01, signal_range=5.0) == pytest.approx(2 * COUNT + 0.08)


def test_an_ideal_sensor_may_wander_a_thousandth_of_its_range():
    assert rest_tolerance(0.0, 0.0, signal_range=2.5) == pytest.approx(2.5e-3)
    assert rest_tolerance(0.0, 0.0) == 0.0


def test_a_rest_band_says_why():
    assert rest_band(COUNT, 0.0, unit="rad").reason == "2 steps of 0.00153 rad"
    assert rest_band(0.0, 0.01, unit="m/s^2").reason == "8σ, σ = 0.01 m/s^2"
    assert rest_band(COUNT, 1e-4, unit="rad").reason == (
        "2 steps of 0.00153 rad + 8σ, σ = 0.0001 rad"
    )
    assert rest_band(0.0, 0.0, 2.5, "1").reason == (
        "0.001 of the reading's range 2.5, an ideal sensor"
    )


@pytest.mark.parametrize(
    ("args", "message"),
    [
        ((-1.0, 0.0), "resolution=-1.0 must be >= 0.0"),
        ((0.0, math.nan), "noise=nan must be finite"),
        ((0.0, 0.0, "wide"), "signal_range='wide' must be a number"),
    ],
)
def test_a_bad_sensor_figure_is_named(args, message):
    with pytest.raises(ValueError, match=f"^{message}$"):
        rest_tolerance(*args)


def test_rest_bands_follow_the_sensors_a_record_holds():
    t = np.arange(100) * DT
    record = Record(time=t, torque=np.zeros(100), joint_angle=np.linspace(0, 1, 100))
    bands = rest_bands([Encoder(), Accelerometer(channel="tip_acceleration", x=0.5)], record)
    assert bands == {"joint_angle": RestBand(2 * COUNT, "2 steps of 0.00153 rad", "rad")}


# -- spreads and rounding -------------------------------------------------------------------


def test_two_encoder_quanta_are_within_two_quanta_despite_rounding():
    assert 0.406 - 0.404 > 0.002  # what refused a still window
    assert spread_within(np.array([0.404, 0.405, 0.406, 0.404]), 0.002)
    assert not spread_within(np.array([0.404, 0.4061]), 0.002)


def test_quantised_large_angles_are_within_their_steps():
    levels = (np.array([0, 1, 2, 1, 0]) + round(1000.0 / COUNT)) * COUNT  # about 1000 rad
    assert spread_within(levels, rest_tolerance(COUNT, 0.0))
    assert not spread_within(levels + np.array([0, 0, 0, 0, COUNT * 3]), 2 * COUNT)


def test_a_spread_of_one_ulp_of_a_large_value_is_within_a_smaller_tolerance():
    values = np.array([1e6, 1e6 + 1e-10])  # the step rounds to one ulp, 1.16e-10
    assert values[1] - values[0] > 1e-10 * (1 + 1e-9)
    assert spread_within(values, 1e-10)
    assert spread_within(np.full(3, 7.25), 0.0)


def test_a_spread_of_nothing_is_refused():
    with pytest.raises(ValueError, match="^spread_within: values is empty$"):
        spread_within(np.array([]), 1.0)


def test_the_sliding_extremes_run_over_every_n_samples():
    y = np.random.default_rng(0).standard_normal(40)
    for n in (2, 3, 4, 7, 8):
        windows = np.lib.stride_tricks.sliding_window_view(y, n)
        np.testing.assert_array_equal(_sliding(maximum_filter1d, y, n), windows.max(axis=1))
        np.testing.assert_array_equal(_sliding(minimum_filter1d, y, n), windows.min(axis=1))


# -- why a window does not start at rest ----------------------------------------------------


def test_a_still_window_toggling_by_two_quanta_is_at_rest():
    t = 0.4 + np.arange(100) * DT
    angle = np.where(np.arange(100) % 2 == 0, 0.404, 0.406)
    tolerance = {"joint_angle": RestBand(0.002, "2 steps of 0.001 rad", "rad")}
    assert why_not_at_rest(t, {"joint_angle": angle}, tolerance, name="run1") is None


def test_a_moving_start_names_channel_change_tolerance_span_and_time():
    t, angle, torque = rig()
    message = why_not_at_rest(t, {"joint_angle": angle, "tip_acceleration": 5.0 * torque},
                              ANGLE | {"tip_acceleration": rest_band(0.0, 0.01, unit="m/s^2")},
                              name="run1", t0=0.3)
    assert message == (
        "record 'run1' does not start at rest at t = 0.3 s: 'joint_angle' changes by 0.0997 rad "
        "(rest tolerance 0.00307 rad: 2 steps of 0.00153 rad) in the first 0.05 s; "
        f"{REST_HINT}"
    )
    assert why_not_at_rest(t, {"joint_angle": angle, "tip_acceleration": 5.0 * torque},
                           ANGLE | {"tip_acceleration": 0.08}, name="run1", t0=0.28) == (
        "record 'run1' does not start at rest at t = 0.28 s: 'joint_angle' changes by 0.0614 "
        "rad (rest tolerance 0.00307 rad: 2 steps of 0.00153 rad) and 'tip_acceleration' "
        f"changes by 5 (rest tolerance 0.08) in the first 0.05 s; {REST_HINT}"
    )


def test_a_plain_tolerance_is_quoted_without_a_reason():
    t, angle, _ = rig()
    message = why_not_at_rest(t, {"joint_angle": angle}, {"joint_angle": 0.001}, span=0.1,
                              name="run1", t0=0.25)
    assert message == (
        "record 'run1' does not start at rest at t = 0.25 s: 'joint_angle' changes by 0.101 "
        f"(rest tolerance 0.001) in the first 0.1 s; {REST_HINT}"
    )


def test_rest_is_checked_from_the_first_sample_by_default():
    t, angle, _ = rig(moves=((0.0, 0.5),))
    message = why_not_at_rest(t, {"joint_angle": angle}, ANGLE, name="run1")
    assert message.startswith("record 'run1' does not start at rest at t = 0 s: ")


@pytest.mark.parametrize(
    ("channels", "tolerances", "message"),
    [
        ({"joint_angle": np.zeros(5)}, ANGLE,
         "'joint_angle' has shape (5,); time has 1001 samples"),
        ({"joint_angle": np.zeros(1001)}, {}, "no rest tolerance for channel(s) ['joint_angle']"),
        ({"joint_angle": np.zeros(1001)}, {"joint_angle": -1.0},
         "channel 'joint_angle': rest tolerance=-1.0 must be >= 0.0"),
        ({}, ANGLE, "no channels to check for rest"),
    ],
)
def test_bad_arguments_name_the_record(channels, tolerances, message):
    t = np.arange(1001) * DT
    with pytest.raises(ValueError, match=f"^record 'run1': {re.escape(message)}$"):
        why_not_at_rest(t, channels, tolerances, name="run1")


def test_a_start_after_the_record_is_refused():
    t, angle, _ = rig()
    with pytest.raises(ValueError, match=r"^record 'run1': t0=2.0 s is after its last sample "
                                         r"at 1.0 s$"):
        why_not_at_rest(t, {"joint_angle": angle}, ANGLE, name="run1", t0=2.0)


# -- finding rest ---------------------------------------------------------------------------


def test_rest_before_the_motion_is_found_within_a_sample():
    t, angle, torque = rig()
    start = find_rest(t, {"joint_angle": angle}, ANGLE, torque, name="run1")
    assert start == pytest.approx(0.3 - 0.05 - DT)  # 0.05 s (51 samples) before the torque
    assert why_not_at_rest(t, {"joint_angle": angle}, ANGLE, name="run1", t0=start) is None


def test_without_the_input_the_readings_alone_find_the_rest():
    t, angle, _ = rig()
    start = find_rest(t, {"joint_angle": angle}, ANGLE, name="run1")
    assert start == pytest.approx(0.25)  # the angle leaves its band of 2 steps at 0.301 s


def test_an_offset_noise_and_a_late_clock_do_not_disturb_it():
    t, angle, torque = rig(start=12.0, offset=100.0)
    rng = np.random.default_rng(3)
    accel = 0.3 + 0.01 * rng.standard_normal(t.size) + 5.0 * torque
    channels = {"joint_angle": angle, "tip_acceleration": accel}
    bands = ANGLE | {"tip_acceleration": rest_band(0.0, 0.01, unit="m/s^2")}
    start = find_rest(t, channels, bands, torque + 1e-3 * rng.standard_normal(t.size),
                      name="run1")
    assert start == pytest.approx(12.249)


def test_the_rest_before_the_first_motion_is_taken():
    t, angle, torque = rig(moves=((0.3, 0.4), (0.7, 0.8)))
    assert find_rest(t, {"joint_angle": angle}, ANGLE, torque, name="run1") == pytest.approx(0.249)


def test_a_record_that_starts_moving_is_taken_from_its_first_rest_before_a_motion():
    t, angle, torque = rig(moves=((0.0, 0.2), (0.6, 0.8)))
    assert find_rest(t, {"joint_angle": angle}, ANGLE, torque, name="run1") == pytest.approx(0.549)


def test_an_input_the_arm_does_not_follow_at_once_leaves_the_readings_to_mark_the_motion():
    t, angle, torque = rig()
    held = torque + np.where(t < 0.3, 0.2, 0.0)  # on from the first sample, the arm still
    assert find_rest(t, {"joint_angle": angle}, ANGLE, held, name="run1") == pytest.approx(0.25)


def test_an_input_that_switches_on_early_marks_the_motion():
    t, angle, torque = rig()
    early = torque + np.where(t >= 0.1, 0.2, 0.0)  # on at 0.1 s, the arm moves at 0.3 s
    assert find_rest(t, {"joint_angle": angle}, ANGLE, early, name="run1") == pytest.approx(0.049)
    at_once = np.where(t >= 0.02, 1.0, 0.0)  # on before 0.05 s of stillness
    assert find_rest(t, {"joint_angle": angle}, ANGLE, at_once, name="run1") == 0.0


def test_a_record_moving_from_its_first_sample_has_no_rest():
    t, angle, torque = rig(moves=((0.0, 1.0),))
    with pytest.raises(ValueError) as err:
        find_rest(t, {"joint_angle": angle}, ANGLE, torque, name="run1")
    assert str(err.value) == (
        "record 'run1' is never at rest for 0.05 s before it moves: from its first sample at "
        "t = 0 s 'joint_angle' changes by 0.0997 rad (rest tolerance 0.00307 rad: 2 steps of "
        f"0.00153 rad) in the first 0.05 s; {REST_HINT}"
    )


def test_a_record_that_rests_only_after_it_moves_has_no_rest_before_it():
    t, angle, torque = rig(moves=((0.0, 0.5),))
    with pytest.raises(ValueError, match=(
        r"^record 'run1' is never at rest for 0.05 s before it moves: it rests only from "
        r"t = 0.498 s to its end; the simulation starts from rest, ")):
        find_rest(t, {"joint_angle": angle}, ANGLE, torque, name="run1")


def test_a_record_that_never_moves_is_refused():
    t, angle, torque = rig(moves=())
    with pytest.raises(ValueError, match=(
        r"^record 'run1' never moves: every channel stays within its rest tolerance from start "
        r"to end$")):
        find_rest(t, {"joint_angle": angle}, ANGLE, torque, name="run1")


def test_a_record_shorter_than_the_span_has_no_rest():
    t, angle, torque = rig(duration=0.02)
    with pytest.raises(ValueError, match=(
        r"^record 'run1' is never at rest for 0.05 s before it moves: it lasts 0.02 s$")):
        find_rest(t, {"joint_angle": angle}, ANGLE, torque, name="run1")


def test_a_longer_span_moves_the_start_back():
    t, angle, torque = rig()
    start = find_rest(t, {"joint_angle": angle}, ANGLE, torque, span=0.2, name="run1")
    assert start == pytest.approx(0.3 - 0.2 - DT)


# -- a real rig -----------------------------------------------------------------------------


@pytest.fixture(scope="module")
def rotflex(rotflex_csv):
    records = {p.stem: load_record(p) for p in rotflex_csv.glob("*.csv")}
    return records, load_arm(ARMS / "quanser_rotflex.toml")


def test_the_rest_of_a_real_rig_is_where_its_readings_show_it(rotflex):
    """The square wave's link is disturbed from 0.1 s (its voltage is not clean until the first
    step at 0.2 s); the random run's voltage starts at once, the encoder turns at 0.04 s."""
    records, arm = rotflex
    for name, expected in (("square_wave", 0.048), ("random_985", 0.0)):
        r = records[name]
        bands = rest_bands(arm.sensors, r)
        channels = {c: r.channel(c) for c in bands}
        start = find_rest(r.time, channels, bands, r.channel(r.input_name), name=r.name)
        assert start == pytest.approx(expected)
        assert why_not_at_rest(r.time, channels, bands, name=r.name, t0=start) is None
