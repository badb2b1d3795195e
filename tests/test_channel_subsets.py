"""Records that log different subsets of a rig's channels, channels that never move, columns the
rig reads nothing from, and the ``# units =`` line, on an invented rig: a 0.35 m steel strip on a
geared DC motor driven in volts, an encoder on the hub and an accelerometer part-way along."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from jaxflex.arm import load_arm
from jaxflex.cli import main
from jaxflex.comparison import compare
from jaxflex.data import Record, load_record, save_record
from jaxflex.intervals import uncertainty
from jaxflex.measured import channel_notes, logged_record, logged_units, prepare
from jaxflex.model import Model
from jaxflex.objective import build_objective
from jaxflex.signals import reference_input
from jaxflex.simulation import simulate_readings

STRIP = """\
name = "strip"
description = "0.35 m steel strip, geared DC motor in volts, encoder and accelerometer at 0.3 m"

[link]
length = 0.35
width = 0.02
thickness = 0.001
density = 7850.0

[simulation]
n_elements = 3

[sampling]
dt = 0.002
duration = 0.8

[parameters]
E = { reference = 2.0e11, lower = 1.0e11, upper = 3.0e11 }
J_h = { reference = 0.0006, lower = 1e-4, upper = 3e-3 }
b_v = { reference = 0.003, lower = 1e-4, upper = 0.03 }
tau_c = { reference = 0.01, fixed = true }
alpha = { reference = 0.5, fixed = true }
beta = { reference = 1e-4, fixed = true }

[drive]
type = "voltage"
resistance = 2.0
torque_constant = 0.02
back_emf_constant = 0.02
gear_ratio = 10.0
gearbox_efficiency = 0.9
motor_efficiency = 0.8

[[sensors]]
type = "encoder"
channel = "hub"
counts_per_revolution = 2000

[[sensors]]
type = "accelerometer"
channel = "acc"
x = 0.3
noise = 0.05
"""
REST = 0.1  # s at rest before each input


@pytest.fixture(scope="module")
def rig(tmp_path_factory):
    path = tmp_path_factory.mktemp("strip") / "strip.toml"
    path.write_text(STRIP)
    return path


@pytest.fixture(scope="module")
def strip(rig) -> Model:
    return load_arm(rig)


def logged(model: Model, shape: str, volts: float, seed: int, name: str) -> Record:
    """What the strip logs under ``shape`` at ``volts`` after REST s at rest, with its sensors'
    noise and quantisation."""
    _, signal = reference_input(shape, volts, 0.7, 0.002)
    signal = np.concatenate([np.zeros(int(round(REST / 0.002))), signal])
    time = np.arange(signal.size) * 0.002
    return logged_record(model, model.space.reference(), time, signal, seed=seed, name=name)


def without(record: Record, channel: str, name: str) -> Record:
    """``record`` less one column."""
    columns = {c: record.channel(c) for c in record.columns if c != channel}
    return Record.from_columns(columns, name=name, metadata=record.metadata)


@pytest.fixture(scope="module")
def records(strip):
    """A full record (pulse), one of the hub alone (triangle) and one where friction holds the
    hub (a weak multisine), all of one length."""
    full = logged(strip, "pulse", 4.0, 1, "full")
    hub_only = without(logged(strip, "triangular", 3.0, 2, "tri"), "acc", "hub_only")
    held = logged(strip, "multisine", 0.02, 3, "held")
    return {"full": full, "hub_only": hub_only, "held": held}


# --- an objective over records with different channels ---------------------------------------


def test_a_missing_channel_is_masked_and_each_record_keeps_its_weight(strip, records):
    ready = prepare(strip, [records["full"], records["hub_only"]])
    objective = build_objective(ready, strip, weights={"hub": 1.0, "acc": 3.0})
    assert objective.channels == ("hub", "acc")
    observed = objective.observed()
    record, channel, _ = objective.layout()
    assert not observed[(record == 1) & (channel == 1)].any()  # hub_only has no acc
    assert observed[(record == 0) | (channel == 0)].all()
    params = strip.space.reference() | {"E": 1.6e11, "J_h": 0.0008}
    free = {n: params[n] for n in objective.names}
    residuals = np.asarray(objective.residuals(free))
    assert np.all(np.isfinite(residuals)) and not residuals[~observed].any()
    # the cost is the mean over records of each record's weighted mean NRMSE², the weights
    # those of the channels it logs
    expected = []
    for r in ready:
        out = simulate_readings(strip, params, r.input, r.dt)
        own = {c: w for c, w in (("hub", 1.0), ("acc", 3.0)) if c in r.columns}
        squares = {c: np.mean((np.asarray(out.channel(c)) - r.channel(c)) ** 2)
                   / np.mean(r.channel(c) ** 2) for c in own}
        expected.append(sum(own[c] * squares[c] for c in own) / sum(own.values()))
    assert float(objective.cost(free)) == pytest.approx(np.mean(expected), rel=1e-6)


def test_intervals_from_records_with_different_channels_are_finite(strip, records):
    ready = prepare(strip, [records["full"], records["hub_only"]])
    objective = build_objective(ready, strip)
    result = uncertainty(objective, strip.space.reference())
    assert all(math.isfinite(lo) and math.isfinite(hi) for lo, hi in result.intervals.values())
    # each channel's noise counts only the samples that log it: the encoder's quantisation
    # (step 2π/2000, rms step/√12) and the accelerometer's 0.05 m/s², not diluted by the zeros
    assert result.noise["hub"] == pytest.approx(2 * math.pi / 2000 / math.sqrt(12), rel=0.3)
    assert result.noise["acc"] == pytest.approx(0.05, rel=0.2)


def test_a_record_that_logs_no_fitted_channel_is_refused(strip, records):
    ready = prepare(strip, [records["full"], records["hub_only"]])
    with pytest.raises(ValueError, match=r"record 'hub_only' logs none of the fitted channels "
                                         r"\['acc'\]; its columns are \['time', 'voltage', "
                                         r"'hub'\]"):
        build_objective(ready, strip, weights={"hub": 0.0})


# --- the comparison -----------------------------------------------------------------------------


def test_compare_scores_each_record_on_the_channels_it_logs(strip, records):
    ready = prepare(strip, [records["full"], records["hub_only"]])
    c = compare(ready, strip, strip.space.reference(), fit_names=["full"], t_end=None)
    assert c.channels == ("hub", "acc") and c.link == "acc"
    full, hub_only = c["full"], c["hub_only"]
    assert set(full.nrmse) == {"hub", "acc"} and set(hub_only.nrmse) == {"hub"}
    assert all(math.isfinite(v) for v in (*full.nrmse.values(), hub_only.nrmse["hub"]))
    # no accelerometer, no FRF torque -> acc for that record
    assert math.isnan(hub_only.frf_nrmse) and hub_only.frf_bins[0] == 0
    assert math.isfinite(full.frf_nrmse) and full.frf_bins[0] > 0
    assert c.mean("nrmse", role=None)["acc"] == full.nrmse["acc"]
    assert c.mean("nrmse", role=None)["hub"] == pytest.approx(
        (full.nrmse["hub"] + hub_only.nrmse["hub"]) / 2, rel=1e-12)
    row = next(ln for ln in c.table().splitlines() if ln.split()[:3] == ["hub_only", "held-out",
                                                                        "acc"])
    assert row.split()[3:] == ["-", "-", "-"]  # NRMSE, rel.err, floor: no accelerometer logged
    assert "-: the record does not log that channel" in c.table()


def test_a_hub_held_by_friction_is_reported_not_divided_by(strip, records):
    ready = prepare(strip, [records["held"]])
    assert not np.any(ready[0].channel("hub")) and np.any(ready[0].channel("acc"))
    with pytest.warns(UserWarning, match=r"record 'held': measured hub is zero throughout the "
                                         r"time window \(no motion\)"):
        c = compare(ready, strip, strip.space.reference(), t_end=None)
    row = c["held"]
    assert row.still == ("hub",) and math.isnan(row.nrmse["hub"])
    assert math.isnan(row.noise_floor["hub"])  # the encoder's floor: a percent of nothing
    model_hub = np.asarray(c.outputs("held").channel("hub"))
    assert row.rms_error["hub"] == pytest.approx(np.sqrt(np.mean(model_hub**2)), rel=1e-12)
    table = c.table()
    assert "no motion" in next(ln for ln in table.splitlines() if ln.startswith("held"))
    assert f"held hub {row.rms_error['hub']:.3g} rad" in " ".join(table.split())
    data = json.loads(json.dumps(c.to_dict(), allow_nan=False, default=str))
    assert data["records"][0]["no_motion"] == ["hub"]


def test_validate_gives_nan_for_a_channel_that_never_moves(strip, records):
    from jaxflex.measured import validate

    with pytest.warns(UserWarning, match=r"record 'held': hub is zero throughout \(no motion\); "
                                         r"its NRMSE is undefined \(NaN\), its RMS error is"):
        scores = validate([records["held"], records["hub_only"]], strip,
                          strip.space.reference())
    assert math.isnan(scores["held"]["hub"]) and math.isfinite(scores["held"]["acc"])
    assert set(scores["hub_only"]) == {"hub"} and math.isfinite(scores["hub_only"]["hub"])


# --- what the commands say ----------------------------------------------------------------------


def test_channel_notes_name_what_is_left_out_and_what_is_ignored(strip, records):
    extra = records["full"].with_columns(
        {**records["full"].to_dict(), "tip_acceleration": records["full"].channel("acc"),
         "motor_temp": np.full(records["full"].n_samples, 31.0)}, note="two more columns")
    assert channel_notes(strip, [records["full"]]) == []
    assert channel_notes(strip, [extra, records["hub_only"]]) == [
        "record 'full': columns tip_acceleration, motor_temp are no sensor channel of rig "
        "'strip' (hub, acc): ignored",
        "record 'hub_only' does not log acc, a channel of rig 'strip': only hub is used from it",
    ]
    reference = Model()
    t = np.arange(200) * 1e-3
    angle_only = Record.from_columns({"time": t, "torque": np.sin(t), "joint_angle": t**2,
                                      "joint_velocity": 2 * t}, name="angle_only")
    assert channel_notes(reference, [angle_only]) == [
        "record 'angle_only' does not log tip_acceleration, a channel of rig 'reference': only "
        "joint_angle is used from it"
    ]


def test_units_line_names_every_column_the_rig_logs(strip, records, tmp_path):
    path = save_record(records["full"], tmp_path / "full.csv", units=logged_units(strip))
    assert path.read_text().splitlines()[0] == "# units = time s, voltage V, hub rad, acc m/s^2"
    assert load_record(path, channels=strip.channels).columns == records["full"].columns
    with pytest.raises(ValueError, match=r"units given for column\(s\) \['acc'\] that record "
                                         r"'hub_only' does not hold"):
        save_record(records["hub_only"], tmp_path / "h.csv", units=logged_units(strip))


def test_simulate_writes_the_rigs_units(rig, tmp_path, capsys):
    out = tmp_path / "log.csv"
    assert main(["simulate", "--arm", str(rig), "--input", "pulse", "--amplitude", "4",
                 "--rest", "0.1", "--out", str(out)]) == 0
    assert out.read_text().splitlines()[0] == "# units = time s, voltage V, hub rad, acc m/s^2"


def test_identify_and_validate_records_with_different_channels(rig, records, tmp_path, capsys):
    full = save_record(records["full"], tmp_path / "full.csv")
    hub_only = save_record(records["hub_only"], tmp_path / "hub_only.csv")
    held = save_record(records["held"], tmp_path / "held.csv")
    fit = tmp_path / "fit.json"
    with pytest.warns(UserWarning, match="record 'hub_only' does not log acc, a channel of rig "
                                         "'strip': only hub is used from it"):
        assert main(["identify", str(full), str(hub_only), "--arm", str(rig), "--generations",
                     "2", "--population", "6", "--quiet", "--out", str(fit)]) == 0
    data = json.loads(fit.read_text())
    assert data["settings"]["channels"] == ["hub", "acc"]
    assert all(math.isfinite(v) for pair in data["intervals"].values() for v in pair)
    capsys.readouterr()
    with pytest.warns(UserWarning) as caught:
        assert main(["validate", str(full), str(hub_only), str(held), "--fit", str(fit),
                     "--json", str(tmp_path / "table.json"), "--horizon", "0.02",
                     "--report", str(tmp_path / "report")]) == 0
    said = [str(w.message) for w in caught]
    assert any("record 'hub_only' does not log acc" in m for m in said)
    assert any("record 'held': measured hub is zero throughout" in m for m in said)
    out = capsys.readouterr().out
    names = ("full", "hub_only", "held")
    table, _, rest = out.partition("\n\n")  # the time-domain table, then the FRF's and the rest
    rows = {tuple(cells[:3]): cells[3:] for cells in map(str.split, table.splitlines())
            if cells[:1] and cells[0] in names}
    assert rows[("hub_only", "fit", "acc")] == ["-", "-", "-"]
    assert rows[("held", "held-out", "hub")][:4] == ["no", "motion", "no", "motion"]
    # the prediction table: a line per record and the channels it logs
    prediction = rest.partition("k-step-ahead predictions")[2]
    predicted = [cells[:3] for cells in map(str.split, prediction.splitlines())
                 if len(cells) > 3 and cells[0] in names]
    assert predicted == [["full", "fit", "hub"], ["full", "fit", "acc"],
                         ["hub_only", "fit", "hub"], ["held", "held-out", "hub"],
                         ["held", "held-out", "acc"]]
    held_hub = next(ln for ln in prediction.splitlines()
                    if ln.split()[:3] == ["held", "held-out", "hub"])
    assert held_hub.split()[3:] == ["no", "motion"] * 3
    figures = sorted(p.name for p in (tmp_path / "report").glob("*.png"))
    assert figures == ["frf.png", "full_prediction.png", "full_time.png", "held_prediction.png",
                       "held_time.png", "hub_only_prediction.png", "hub_only_time.png"]
    table = json.loads((tmp_path / "table.json").read_text())["records"]
    assert [set(r["nrmse"]) for r in table] == [{"hub", "acc"}, {"hub"}, {"hub", "acc"}]


def test_discover_says_which_channel_it_leaves_out_before_any_fit(strip, records):
    from jaxflex.discovery import discover

    ready = prepare(strip, [records["full"], records["hub_only"]])
    with pytest.warns(UserWarning, match="channel 'acc' is not fitted: record 'hub_only' does "
                                         "not log it, and discovery fits only the channels every "
                                         "record logs"), pytest.raises(ValueError, match="no_such"):
        discover(ready, model=strip, candidates=["no_such"])  # stops before any fit
