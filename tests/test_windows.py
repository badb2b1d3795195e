"""``--window``: its forms, every refusal in one exact line, checks against a record's span, and
resolving ``auto`` to the rest before the motion."""

import argparse
import math
import re

import numpy as np
import pytest

from jaxflex.cli import UsageError
from jaxflex.cli._errors import describe
from jaxflex.cli._windows import (
    Window,
    add_windows_argument,
    check_window,
    parse_windows,
    resolve_window,
)
from jaxflex.data import Record
from jaxflex.rest import rest_band

NAMES = ["run1", "run2", "square_wave"]


def refused(function, *args, message: str, **kwargs):
    with pytest.raises(UsageError, match=f"^{re.escape(message)}$"):
        function(*args, **kwargs)


# -- parsing --------------------------------------------------------------------------------


def test_no_window_is_the_whole_of_every_record():
    assert parse_windows(None, NAMES) == dict.fromkeys(NAMES)
    assert parse_windows([], NAMES) == dict.fromkeys(NAMES)


def test_one_window_serves_every_record():
    window = Window("0.1:0.5", None, 0.1, 0.5)
    assert parse_windows(["0.1:0.5"], NAMES) == dict.fromkeys(NAMES, window)
    assert parse_windows("0.1:0.5", NAMES) == dict.fromkeys(NAMES, window)  # a single option


def test_a_named_window_overrides_the_one_for_every_record():
    windows = parse_windows(["0:1", "run2=0.5:", "square_wave=:"], NAMES)
    assert windows == {
        "run1": Window("0:1", None, 0.0, 1.0),
        "run2": Window("run2=0.5:", "run2", 0.5, None),
        "square_wave": None,  # ':' is the whole record
    }


def test_open_ends_and_auto():
    windows = parse_windows(["run1=:0.25", "auto"], NAMES)
    assert windows["run1"] == Window("run1=:0.25", "run1", None, 0.25)
    assert windows["run2"] == windows["square_wave"] == Window("auto", auto=True)
    assert parse_windows(["run2=auto"], NAMES)["run2"] == Window("run2=auto", "run2", auto=True)


@pytest.mark.parametrize(
    ("texts", "message"),
    [
        (["run1.csv=0:1"], "--window run1.csv=0:1: no record is named 'run1.csv'; did you mean "
                           "'run1'?"),
        (["fast=0:1"], "--window fast=0:1: no record is named 'fast'; the records are 'run1', "
                       "'run2', 'square_wave'"),
        (["=0:1"], "--window =0:1: the record name before '=' is empty"),
        (["run1=0:1", "run1=auto"], "--window run1=auto: record 'run1' already has a window "
         "(--window run1=0:1); give one window for every record and NAME=T0:T1 for each record "
         "that differs"),
        (["0:1", "auto"], "--window auto: every record already has a window (--window 0:1); "
         "give one window for every record and NAME=T0:T1 for each record that differs"),
        (["2:1"], "--window 2:1: T0 = 2 s must be below T1 = 1 s"),
        (["run1=0.5:0.5"], "--window run1=0.5:0.5: T0 = 0.5 s must be below T1 = 0.5 s"),
        (["0:abc"], "--window 0:abc: T1 = 'abc' must be a finite number of seconds >= 0"),
        (["0:inf"], "--window 0:inf: T1 = 'inf' must be a finite number of seconds >= 0"),
        (["nan:1"], "--window nan:1: T0 = 'nan' must be a finite number of seconds >= 0"),
        (["-1:2"], "--window -1:2: T0 = '-1' must be a finite number of seconds >= 0"),
        (["0.5"], "--window 0.5: expected T0:T1, T0:, :T1 or auto, optionally after NAME= "
                  "(times in seconds)"),
        (["0:1:2"], "--window 0:1:2: expected T0:T1, T0:, :T1 or auto, optionally after NAME= "
                    "(times in seconds)"),
    ],
)
def test_a_bad_window_is_refused_in_one_line(texts, message):
    refused(parse_windows, texts, NAMES, message=message)


def test_a_long_list_of_records_is_cut_short():
    names = [f"take{i}" for i in range(9)]
    refused(parse_windows, ["zz=0:1"], names, message=(
        "--window zz=0:1: no record is named 'zz'; the records are 'take0', 'take1', 'take2', "
        "'take3', 'take4', 'take5' and 3 more"))


def test_the_option_may_be_given_once_per_record():
    parser = argparse.ArgumentParser()
    add_windows_argument(parser)
    args = parser.parse_args(["--window", "0:1", "--window", "run2=auto"])
    windows = parse_windows(args.window, NAMES)
    assert windows["run2"].auto and windows["run1"] == Window("0:1", None, 0.0, 1.0)
    assert parse_windows(parser.parse_args([]).window, NAMES) == dict.fromkeys(NAMES)


def test_a_refused_window_exits_with_status_two():
    with pytest.raises(UsageError) as err:
        parse_windows(["0:inf"], NAMES)
    assert describe(err.value) == ("--window 0:inf: T1 = 'inf' must be a finite number of "
                                   "seconds >= 0", 2)


# -- checks against a record ----------------------------------------------------------------


def window(text):
    return parse_windows([text], NAMES)["run1"]


def test_a_window_inside_the_record_is_kept_and_open_ends_filled_in():
    assert check_window(window("0.1:0.3"), "run1", 0.0, 0.5) == (0.1, 0.3)
    assert check_window(window("run1=0.1:"), "run1", 0.0, 0.5) == (0.1, 0.5)
    assert check_window(window(":0.3"), "run1", 0.05, 0.5) == (0.05, 0.3)


def test_an_end_within_a_sample_of_the_record_is_cut_back():
    assert check_window(window("0:2"), "run1", 0.0, 1.999, dt=0.001) == (0.0, 1.999)


@pytest.mark.parametrize(
    ("text", "span", "message"),
    [
        ("run1=0:400", (0.0, 0.5),
         "--window run1=0:400: the record spans 0 to 0.5 s; is the window in ms? times are in "
         "seconds"),
        ("100:", (0.0, 2.0),
         "--window 100:: record 'run1' spans 0 to 2 s; is the window in ms? times are in "
         "seconds"),
        ("3:4", (0.0, 2.0), "--window 3:4: record 'run1' spans 0 to 2 s; the window lies after it"),
        ("0:1", (10.0, 12.5),
         "--window 0:1: record 'run1' spans 10 to 12.5 s; the window lies before it"),
        ("run1=0:0.3", (0.1, 0.5),
         "--window run1=0:0.3: the record spans 0.1 to 0.5 s; the window starts before it "
         "(use T0 >= 0.1, or leave T0 out)"),
        ("run1=0.2:0.8", (0.1, 0.5),
         "--window run1=0.2:0.8: the record spans 0.1 to 0.5 s; the window ends after it "
         "(use T1 <= 0.5, or leave T1 out)"),
        ("0:0.8", (0.1, 0.5),
         "--window 0:0.8: record 'run1' spans 0.1 to 0.5 s; the window starts before it "
         "(use T0 >= 0.1, or leave T0 out) and ends after it (use T1 <= 0.5, or leave T1 out)"),
    ],
)
def test_a_window_beyond_the_record_is_refused(text, span, message):
    refused(check_window, window(text), "run1", *span, message=message)


def test_an_auto_window_is_not_checked_by_hand():
    with pytest.raises(ValueError, match=r"^check_window: --window auto is found by "
                                         r"resolve_window$"):
        check_window(window("auto"), "run1", 0.0, 1.0)


# -- resolving ------------------------------------------------------------------------------


COUNT = 2 * math.pi / 4096
BANDS = {"joint_angle": rest_band(COUNT, 0.0, unit="rad")}


def rig_record(name="run1", moving_from=0.3):
    """0.3 s at rest, then 1 N m turning the arm at 2 rad/s, logged by a 4096-count encoder."""
    t = 5.0 + np.arange(1001) * 0.001
    torque = (t >= 5.0 + moving_from - 1e-9).astype(float)
    angle = np.round(np.cumsum(2.0 * 0.001 * torque) / COUNT) * COUNT
    return Record(time=t, torque=torque, joint_angle=angle, name=name)


def test_auto_starts_at_the_rest_before_the_motion_and_runs_to_the_end():
    record = rig_record()
    t0, t1 = resolve_window(Window("auto", auto=True), record, BANDS)
    assert t0 == pytest.approx(5.249) and t1 == 6.0


def test_an_explicit_window_is_checked_and_none_is_the_whole_record():
    record = rig_record()
    assert resolve_window(None, record, BANDS) is None
    assert resolve_window(window("5.2:"), record, BANDS) == (5.2, 6.0)
    refused(resolve_window, window("0:1"), record, BANDS, message=(
        "--window 0:1: record 'run1' spans 5 to 6 s; the window lies before it"))


def test_auto_on_a_record_that_never_rests_says_so():
    record = rig_record(moving_from=0.0)
    refused(resolve_window, Window("run1=auto", "run1", auto=True), record, BANDS, message=(
        "--window run1=auto: record 'run1' is never at rest for 0.05 s before it moves: from "
        "its first sample at t = 5 s 'joint_angle' changes by 0.0997 rad (rest tolerance 0.00307 "
        "rad: 2 steps of 0.00153 rad) in the first 0.05 s; the simulation starts from rest, so "
        "start the window where the arm is still (--window run1=T0:T1), or fit where the "
        "record starts (--initial-state estimate, slower)"))
