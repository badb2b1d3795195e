"""Model vs measurement: noise floors, FRF masking, a wrong stiffness, the table and JSON."""

from __future__ import annotations

import importlib
import json
import math

import numpy as np
import pytest
import scipy.signal as ss

from jaxflex.comparison import Comparison, FRFSettings, compare, fit_and_validate, noise_floor
from jaxflex.data import Dataset, Record
from jaxflex.metrics import nrmse
from jaxflex.model import Model
from jaxflex.parameters import reference_parameters
from jaxflex.synthetic import make_records

NOISE = {"encoder_counts": 4096, "accel_sigma": 0.05}
OUTPUTS = ("joint_angle", "tip_acceleration")


@pytest.fixture(scope="module")
def records() -> Dataset:
    return make_records(seed=0)


@pytest.fixture(scope="module")
def right(records) -> Comparison:
    return compare(records, Model(), reference_parameters(), fit_names=["triangular"], **NOISE)


@pytest.fixture(scope="module")
def wrong(records) -> Comparison:
    params = reference_parameters() | {"E": 0.9 * reference_parameters()["E"]}
    return compare(records, Model(), params, fit_names=["triangular"], **NOISE)


def test_noise_free_records_are_reproduced_exactly():
    clean = make_records(noise=False)
    c = compare(clean, Model(), reference_parameters())
    for row in c.rows:
        assert max(row.nrmse.values()) < 1e-9
        assert row.frf_nrmse < 1e-9 and row.frf_nrmse_raw < 1e-9
        assert row.noise_floor == {}
        assert row.measured_peaks_hz == pytest.approx(row.model_peaks_hz)


def test_correct_model_scores_at_the_noise_floor(right):
    assert right.names == ("triangular", "pulse", "half_sine")
    assert [r.role for r in right.rows] == ["fit", "held-out", "held-out"]
    for row in right.rows:
        for out in OUTPUTS:
            floor = row.noise_floor[out]
            assert row.nrmse[out] <= 1.3 * floor, (row.name, out)
            assert row.relative_error[out] == pytest.approx(row.nrmse[out] / 100, rel=1e-12)
        # white accelerometer noise sits right on its floor (2001 samples: ±3 % spread)
        ratio = row.nrmse["tip_acceleration"] / row.noise_floor["tip_acceleration"]
        assert 0.9 < ratio < 1.1
        assert row.frf_nrmse <= 2.0 * row.noise_floor["frf"]
        assert row.frf_nrmse < 0.5  # percent
    held = right.mean("nrmse")
    assert held["tip_acceleration"] == pytest.approx(
        np.mean([right[n].nrmse["tip_acceleration"] for n in ("pulse", "half_sine")])
    )


def test_wrong_stiffness_is_visible_in_frf_and_resonances(right, wrong):
    # natural frequencies scale with sqrt(E)
    assert wrong.resonances_hz[0] == pytest.approx(math.sqrt(0.9) * right.resonances_hz[0], 1e-9)
    assert 8.0 < right.resonances_hz[0] < 9.0
    for good, bad in zip(right.rows, wrong.rows, strict=True):
        assert bad.frf_nrmse > 5.0 and bad.frf_nrmse > 20 * good.frf_nrmse, bad.name
        assert bad.nrmse["tip_acceleration"] > 10 * bad.noise_floor["tip_acceleration"]
        # the right model puts every FRF peak where the measurement has one
        assert good.model_peaks_hz == pytest.approx(good.measured_peaks_hz, abs=0.015)
    # the pulse excites the first flexible mode: its measured FRF peak lies next to the model's
    # resonance; the softer model loses that peak
    (mode_peak,) = [f for f in right["pulse"].measured_peaks_hz if 7.5 < f < 9.0]
    assert abs(mode_peak - right.resonances_hz[0]) < 0.25
    assert min(abs(f - mode_peak) for f in right["pulse"].model_peaks_hz) < 0.02
    assert min(abs(f - mode_peak) for f in wrong["pulse"].model_peaks_hz) > 0.3


def test_frf_matches_scipy_h1_and_masks_the_pulse_nulls(right, records):
    row, pulse = right["pulse"], records["pulse"]
    n = pulse.n_samples
    kw = {"fs": pulse.sample_rate, "window": "boxcar", "nperseg": n, "detrend": "constant"}
    _, s_yx = ss.csd(pulse.torque, pulse.tip_acceleration, **kw)
    _, s_xx = ss.welch(pulse.torque, **kw)
    band = row.frf.band
    np.testing.assert_allclose(row.frf.measured[band], s_yx[band] / s_xx[band], rtol=1e-9)
    # a 0.3 s pulse has no power at multiples of 1/0.3 Hz: those bins are left out
    left_out = row.frf.freqs[band & ~row.frf.compared]
    nulls = np.array([10 / 3, 20 / 3, 10.0, 40 / 3])
    assert left_out.size and np.all(np.min(np.abs(left_out[:, None] - nulls), axis=1) < 0.6)
    assert row.frf.compared[1:6].all()  # the low-frequency bins are compared
    assert row.frf_bins == (int(row.frf.compared.sum()), int(band.sum()))
    # the raw definition keeps the null bins, where noise is divided by almost nothing
    assert row.frf_nrmse_raw > row.frf_nrmse


def test_masking_can_be_switched_off(records):
    raw = FRFSettings(min_input_db=None)
    c = compare(records["half_sine"], Model(), reference_parameters(), frf=raw)
    row = c[0]
    assert row.frf_bins[0] == row.frf_bins[1] == 30
    assert row.frf_nrmse == row.frf_nrmse_raw


def test_welch_estimate_masks_on_coherence():
    rec = make_records(inputs=("multisine",), amplitudes={"multisine": 0.4}, seed=3)[0]
    settings = FRFSettings(nperseg=500, min_coherence=0.9)
    row = compare(rec, Model(), reference_parameters(), frf=settings)[0]
    compared = row.frf.compared
    assert compared.any() and np.all(row.frf.coherence[compared] >= 0.9)
    assert not np.all(row.frf.coherence[row.frf.band] >= 0.9)  # something was left out
    assert row.frf_bins[0] < row.frf_bins[1]
    assert "coherence >= 0.9" in settings.describe()


def test_a_joint_that_never_moves_gives_nan_not_a_crash():
    weak = make_records(inputs=("multisine",), amplitudes={"multisine": 0.05},  # < tau_c
                        seed=3)[0]
    assert not np.any(weak.joint_angle)
    with pytest.warns(UserWarning, match="'multisine': measured joint_angle is zero"):
        c = compare(weak, Model(), reference_parameters())
    assert math.isnan(c[0].nrmse["joint_angle"]) and math.isfinite(c[0].nrmse["tip_acceleration"])
    assert c[0].still == ("joint_angle",)
    row = next(ln for ln in c.table().splitlines() if ln.split()[:3] == ["multisine",
                                                                         "held-out", "angle"])
    assert row.split()[3:5] == ["no", "motion"]
    model_angle = np.asarray(c.outputs(0).joint_angle)[weak.time <= 2.0 + 1e-9]  # t_end 2 s
    assert c[0].rms_error["joint_angle"] == pytest.approx(
        np.sqrt(np.mean(model_angle**2)), rel=1e-12)
    assert f"multisine joint_angle {c[0].rms_error['joint_angle']:.3g} rad" in " ".join(
        c.table().split())
    assert (
        json.loads(json.dumps(c.to_dict(), allow_nan=False))["records"][0]["nrmse_percent"][
            "joint_angle"
        ]
        is None
    )


def test_time_window_limits_the_metrics(right, records):
    c = compare(records["pulse"], Model(), reference_parameters(), t_end=1.0)
    keep = records["pulse"].time <= 1.0 + 1e-12
    sim = np.asarray(right.outputs("pulse").tip_acceleration)
    expected = nrmse(records["pulse"].tip_acceleration[keep], sim[keep])
    assert c[0].nrmse["tip_acceleration"] == pytest.approx(expected, rel=1e-12)
    assert c[0].nrmse["tip_acceleration"] != pytest.approx(right["pulse"].nrmse["tip_acceleration"])


def test_noise_floor_has_the_known_value():
    t = np.arange(2001) * 1e-3
    angle = np.full_like(t, 0.5)
    acc = 3.0 * np.sin(2 * np.pi * 5 * t)
    rec = Record(t, np.sin(t), angle, acc, name="known")
    floor = noise_floor(rec, encoder_counts=4096, accel_sigma=0.05)
    assert floor["joint_angle"] == pytest.approx(100 * (2 * np.pi / 4096 / np.sqrt(12)) / 0.5)
    assert floor["tip_acceleration"] == pytest.approx(100 * 0.05 / (3.0 / np.sqrt(2)), rel=1e-3)
    assert noise_floor(rec, encoder_counts=None, accel_sigma=0.05).keys() == {"tip_acceleration"}
    with pytest.raises(ValueError, match="encoder_counts"):
        noise_floor(rec, encoder_counts=0)
    with pytest.raises(ValueError, match="accel_sigma"):
        noise_floor(rec, accel_sigma=-1.0)


def test_table_has_a_row_per_record_and_channel_and_says_what_it_compares(right):
    text = right.table()
    lines = text.splitlines()
    assert lines[0].split() == ["record", "role", "channel", "NRMSE", "%", "rel.err", "floor",
                                "%"]
    frf_header = next(ln for ln in lines if ln.startswith("record") and "FRF NRMSE %" in ln)
    assert frf_header.split()[-3:] == ["floor", "FRF", "%"]
    assert max(len(ln) for ln in lines) <= 100
    for row in right.rows:
        matching = [ln.split() for ln in lines if ln.split() and ln.split()[0] == row.name]
        assert len(matching) == 3  # angle, tip acc, then the FRF row
        assert [cells[1] for cells in matching] == [row.role] * 3
        angle, tip, frf = matching
        assert angle[2] == "angle" and tip[2:4] == ["tip", "acc"]
        assert float(angle[3]) == pytest.approx(row.nrmse["joint_angle"], rel=5e-3)
        assert float(tip[4]) == pytest.approx(row.nrmse["tip_acceleration"], rel=5e-3)
        assert float(frf[2]) == pytest.approx(row.frf_nrmse, rel=5e-3)
        assert float(frf[-1]) == pytest.approx(row.noise_floor["frf"], rel=5e-3)
    assert "input power within 30 dB" in text  # the FRF masking is stated
    assert f"{right.resonances_hz[0]:.2f} Hz" in text
    assert str(right) == text


def test_a_table_without_noise_floors_has_no_floor_columns(right):
    import dataclasses

    bare = dataclasses.replace(right, rows=tuple(dataclasses.replace(r, noise_floor={})
                                                 for r in right.rows), noise={})
    assert "floor" not in bare.table()


def test_to_dict_is_strict_json(right, records):
    data = right.to_dict()
    again = json.loads(json.dumps(data, allow_nan=False))
    assert [r["name"] for r in again["records"]] == list(records.names)
    assert again["records"][1]["role"] == "held-out"
    assert again["params"]["E"] == pytest.approx(5.7002e10)
    assert again["settings"]["noise"] == NOISE
    assert "versions" in again["provenance"]
    # a metric that cannot be computed is null, not NaN
    nan_row = compare(records["pulse"], Model(), reference_parameters(),
                      frf=FRFSettings(f_max=0.1))
    assert (
        json.loads(json.dumps(nan_row.to_dict(), allow_nan=False))["records"][0][
            "frf_nrmse_percent"
        ]
        is None
    )


def test_prediction_and_lookup(right, records):
    pred = right.prediction("pulse")
    assert pred.name == "pulse_model"
    np.testing.assert_array_equal(pred.torque, records["pulse"].torque)
    np.testing.assert_array_equal(pred.tip_acceleration, right.outputs(1).tip_acceleration)
    assert "tip_deflection" in pred.extras
    assert right[-1].name == "half_sine" and right.record("half_sine") is records["half_sine"]
    with pytest.raises(KeyError, match="no record named 'pluse'"):
        right["pluse"]


def test_input_errors_name_the_problem(records):
    model, ref = Model(), reference_parameters()
    with pytest.raises(ValueError, match=r"fit_names \['tri'\]"):
        compare(records, model, ref, fit_names=["tri"])
    with pytest.raises(ValueError, match="missing for \\['beta'\\]"):
        compare(records, model, {k: v for k, v in ref.items() if k != "beta"})
    with pytest.raises(ValueError, match="t_end"):
        compare(records, model, ref, t_end=-1.0)
    with pytest.raises(ValueError, match="at least one record"):
        compare([], model, ref)
    with pytest.raises(ValueError, match="min_input_db"):
        FRFSettings(min_input_db=10.0)
    with pytest.raises(ValueError, match="f_max"):
        FRFSettings(f_max=0.0)


class _StubFit:
    """Stands in for a Fit: the reference values, as if identified on ``record_names``."""

    def __init__(self, record_names):
        self.params = {k: float(v) for k, v in reference_parameters().items()}
        self.record_names = record_names
        self.model = Model()


def test_fit_and_validate_fits_only_the_named_records(monkeypatch, records):
    calls = []

    def fake_identify(fit_records, **kwargs):
        calls.append((fit_records.names, kwargs))
        return _StubFit(fit_records.names)

    identification = importlib.import_module("jaxflex.identification")
    monkeypatch.setattr(identification, "identify", fake_identify)
    fit, c = fit_and_validate(records, "triangular", ["pulse"], generations=3, seed=5, **NOISE)
    assert calls == [(("triangular",), {"generations": 3, "seed": 5})]
    assert c.names == ("triangular", "pulse") and [r.role for r in c.rows] == ["fit", "held-out"]
    assert c.noise == NOISE and c.params == fit.params
    # validate_names defaults to every other record
    _, c_all = fit_and_validate(records, ["triangular"])
    assert c_all.names == records.names
    with pytest.raises(ValueError, match=r"\['pulse'\] are both fitted and held out"):
        fit_and_validate(records, ["pulse"], ["pulse", "half_sine"])
    with pytest.raises(ValueError, match="at least one record"):
        fit_and_validate(records, [])
    with pytest.raises(KeyError, match="no record named 'pluse'"):
        fit_and_validate(records, "pluse")


@pytest.mark.slow
def test_fit_on_triangular_validate_on_pulse_and_half_sine(records):
    fit, c = fit_and_validate(
        records, "triangular", population=24, generations=12, seed=0, intervals=False, **NOISE
    )
    assert fit.record_names == ("triangular",)
    for name in ("E", "J_h", "tau_c"):
        assert fit.params[name] == pytest.approx(float(reference_parameters()[name]), rel=5e-3)
    for name in ("pulse", "half_sine"):
        row = c[name]
        assert row.role == "held-out"
        for out in OUTPUTS:
            assert row.nrmse[out] <= 1.3 * row.noise_floor[out], (name, out)
        assert row.frf_nrmse <= 2.0 * row.noise_floor["frf"]
    assert "held-out" in c.table()


def test_the_records_come_first_in_every_function_that_takes_them(records):
    """One convention: records, then the model; the old order fails in one line that says so."""
    from jaxflex.discovery import refit
    from jaxflex.kalman import predict
    from jaxflex.measured import validate

    for function in (compare, validate, predict, refit):
        with pytest.raises(TypeError, match="the records come first, then the model"):
            function(Model(), reference_parameters(), records)
