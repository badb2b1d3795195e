"""Residual diagnostics: calibrated whiteness tests, correlation lags, spectra, resonance
shifts, localisation, amplitude scaling, and no false alarm for a correct model with encoder
quantisation."""

from __future__ import annotations

import math

import jax.numpy as jnp
import numpy as np
import pytest
import scipy.stats as st

from jaxflex.data import Record
from jaxflex.diagnosis import (
    NoiseLevel,
    amplitude_scaling,
    autocorrelation,
    chi2_sf,
    cross_correlation,
    diagnose,
    estimate_noise,
    frf_error,
    localise,
    noise_levels,
    quantisation_step,
    residual_spectrum,
    resolution,
    white_noise_level,
)
from jaxflex.modal import free_hub_modes
from jaxflex.model import Model
from jaxflex.parameters import reference_parameters
from jaxflex.simulation import simulate
from jaxflex.synthetic import ENCODER_STEP, make_records

DT = 1e-3
#: Base parameters away from the paper's values, as a real arm would have.
TRUTH = {"E": 5.2e10, "J_h": 0.0062, "b_v": 1.2e-3, "tau_c": 0.09, "alpha": 1.3, "beta": 9e-5}


def predictions(model, params, records):
    return [simulate(model, params, r.torque) for r in records]


@pytest.mark.parametrize(("x", "k"), [(0.5, 1), (3.0, 2), (40.0, 40), (80.0, 40), (1e-3, 7)])
def test_chi2_survival_matches_scipy(x, k):
    assert chi2_sf(x, k) == pytest.approx(st.chi2.sf(x, k), rel=1e-10, abs=1e-300)
    assert chi2_sf(0.0, k) == 1.0
    with pytest.raises(ValueError, match="degrees of freedom"):
        chi2_sf(1.0, 0)


def test_autocorrelation_matches_direct_formula_and_band():
    rng = np.random.default_rng(1)
    r = rng.standard_normal(1500) + 3.0
    acf = autocorrelation(r, max_lag=20, dt=DT)
    x = r - r.mean()
    direct = np.array([x[k:] @ x[: x.size - k] for k in range(21)]) / (x @ x)
    np.testing.assert_allclose(acf.values, direct, rtol=1e-12, atol=1e-15)
    n = x.size
    q = n * (n + 2) * np.sum(direct[1:] ** 2 / (n - np.arange(1, 21)))
    assert acf.statistic == pytest.approx(q, rel=1e-12)
    assert acf.p_value == pytest.approx(st.chi2.sf(q, 20), rel=1e-9)
    assert acf.band == pytest.approx(1.959964 / math.sqrt(n), rel=1e-6)


def test_ljung_box_false_positive_rate_is_its_level():
    """White noise is rejected at about the nominal rate (binomial 99.9 % range)."""
    rng = np.random.default_rng(7)
    trials, alpha = 300, 0.05
    rejected = sum(not autocorrelation(rng.standard_normal(2001)).white(alpha)
                   for _ in range(trials))
    lo, hi = st.binom.ppf([0.0005, 0.9995], trials, alpha)
    assert lo <= rejected <= hi


def test_ljung_box_rejects_coloured_noise_and_pools_records():
    rng = np.random.default_rng(3)
    e = rng.standard_normal((3, 2001))
    ar = [np.asarray(np.frompyfunc(lambda a, b: 0.3 * a + b, 2, 1).accumulate(s, dtype=object),
                     dtype=float) for s in e]
    assert autocorrelation(ar).p_value < 1e-6
    assert autocorrelation(list(e)).white(0.01)
    pooled = autocorrelation(list(e), max_lag=10)
    assert pooled.band == pytest.approx(1.959964 / math.sqrt(3 * 2001), rel=1e-6)


def test_cross_correlation_finds_the_delay():
    rng = np.random.default_rng(0)
    u = rng.standard_normal(2000)
    delay = 25
    r = np.r_[np.zeros(delay), u[:-delay]] + 0.5 * rng.standard_normal(u.size)
    xc = cross_correlation(r, u, max_lag=60, dt=DT)
    assert xc.peak_lag_s == pytest.approx(delay * DT)
    assert xc.significant and xc.peak_value > 0.5
    # the sign convention: a residual that leads the input peaks at a negative lag
    assert cross_correlation(u, r, max_lag=60, dt=DT).peak_lag_s == pytest.approx(-delay * DT)
    with pytest.raises(ValueError, match="same number and lengths"):
        cross_correlation(r, u[:-1])


def test_residual_spectrum_finds_a_hidden_tone_and_not_noise():
    rng = np.random.default_rng(2)
    t = np.arange(2001) * DT
    noise = [0.05 * rng.standard_normal(t.size) for _ in range(3)]
    clean = residual_spectrum(noise, DT, noise_sigma=0.05)
    assert clean.peaks_hz == ()
    assert np.median(clean.psd[10:]) == pytest.approx(clean.noise_psd, rel=0.15)
    tone = [n + 0.03 * np.sin(2 * np.pi * 12.3 * t) for n in noise]
    spec = residual_spectrum(tone, DT)
    assert spec.peaks_hz[0] == pytest.approx(12.3, abs=0.5)


def test_noise_level_estimates():
    rng = np.random.default_rng(4)
    t = np.arange(4000) * DT
    r = 0.05 * rng.standard_normal(t.size) + 0.5 * np.sin(2 * np.pi * 8 * t)
    assert white_noise_level(r) == pytest.approx(0.05, rel=0.06)
    angle = ENCODER_STEP * np.round(np.cumsum(rng.uniform(0, 0.01, 500)) / ENCODER_STEP)
    assert quantisation_step(angle) == pytest.approx(ENCODER_STEP, rel=1e-9)
    assert quantisation_step(np.cumsum(rng.uniform(0, 0.01, 500))) is None


# --- the noise model on values written as loggers write them -----------------------------------

MOTION = 1.2 * np.sin(2 * np.pi * 0.7 * np.arange(3001) * DT) + 0.3 * np.arange(3001) * DT
WRITINGS = {
    "6 digits": lambda x: np.array([float(f"{v:.5e}") for v in x]),
    "7 digits": lambda x: np.array([float(f"{v:.6e}") for v in x]),
    "9 digits": lambda x: np.array([float(f"{v:.8e}") for v in x]),
    "17 digits": lambda x: np.array([float(f"{v:.16e}") for v in x]),
    "6 decimals": lambda x: np.array([float(f"{v:.6f}") for v in x]),
    "float32": lambda x: x.astype(np.float32).astype(np.float64),
    "float32 text": lambda x: np.array([float(str(np.float32(v))) for v in x]),
}
STEPS = {"1000": 2 * np.pi / 1000, "1024": 2 * np.pi / 1024, "2000": 2 * np.pi / 2000,
         "4096": 2 * np.pi / 4096, "10000": 2 * np.pi / 10000, "0.1deg": np.radians(0.1)}


def encoder(step: float, offset: float, motion=MOTION) -> np.ndarray:
    return offset + step * np.round((motion - offset) / step)


@pytest.mark.parametrize("writing", WRITINGS)
@pytest.mark.parametrize("resolution_name", STEPS)
@pytest.mark.parametrize("offset", [0.0, 0.37, 1.3], ids=["no offset", "0.37 counts", "1.3 rad"])
def test_quantisation_step_of_written_encoder_values(writing, resolution_name, offset):
    step = STEPS[resolution_name]
    shift = offset * step if offset < 1 else offset
    values = WRITINGS[writing](encoder(step, shift))
    assert quantisation_step(values) == pytest.approx(step, rel=1e-6)


@pytest.mark.parametrize("writing", WRITINGS)
def test_continuous_values_lie_on_no_grid(writing):
    rng = np.random.default_rng(3)
    write = WRITINGS[writing]
    assert quantisation_step(write(MOTION)) is None
    assert quantisation_step(write(MOTION + 1e-4 * rng.standard_normal(MOTION.size))) is None
    assert quantisation_step(write(0.05 * rng.standard_normal(MOTION.size))) is None


def channel_record(angle: np.ndarray, acceleration: np.ndarray) -> Record:
    t = np.arange(angle.size) * DT
    return Record(time=t, torque=np.sin(t), joint_angle=angle, tip_acceleration=acceleration)


def test_a_staircase_never_gets_a_vanishing_noise_level():
    rng = np.random.default_rng(5)
    acceleration = 0.05 * rng.standard_normal(MOTION.size)
    step = STEPS["2000"]
    slow = 0.2 + 0.2 * np.sin(2 * np.pi * 0.3 * np.arange(MOTION.size) * DT)  # ≤ 0.12 counts/ms
    # an eccentric encoder disc: counts 10 % uneven, so no grid, but a staircase all the same
    edges = np.cumsum(step * (1.0 + 0.1 * np.sin(np.arange(400))))
    uneven = edges[np.searchsorted(edges, slow + edges[0]) - 1] - edges[0]
    for angle, source in [(WRITINGS["9 digits"](encoder(step, 0.37 * step, slow)), "quantisation"),
                          (WRITINGS["9 digits"](uneven), "floor")]:
        residual = {"joint_angle": angle - slow, "tip_acceleration": acceleration}
        assert white_noise_level(residual["joint_angle"]) < 0.1 * step / math.sqrt(12)
        levels = estimate_noise([channel_record(angle, acceleration)], [residual])
        level = levels["joint_angle"]
        assert level.source == source and level.unsure == (source == "floor")
        assert level.sigma == pytest.approx(step / math.sqrt(12), rel=0.15)
        assert levels["tip_acceleration"].source == "estimated"
        assert levels["tip_acceleration"].sigma == pytest.approx(0.05, rel=0.1)
    assert levels["joint_angle"].describe().startswith("floor")
    given = estimate_noise([channel_record(angle, acceleration)], [residual],
                           given={"joint_angle": 1e-4})
    assert given["joint_angle"] == NoiseLevel(1e-4) and given["joint_angle"].describe() == "given"


def test_an_exact_fit_gets_the_resolution_of_the_written_values():
    """A noise-free channel fitted exactly: σ is the rounding of its 6 written digits, not 0."""
    written = WRITINGS["6 digits"](np.sin(np.arange(2000) * 0.01) + 2.0)
    levels = estimate_noise([channel_record(written, written)],
                            [{"joint_angle": np.zeros(2000), "tip_acceleration": np.zeros(2000)}])
    level = levels["tip_acceleration"]
    assert level.source == "floor" and level.sigma == pytest.approx(resolution(written))
    # 6 significant digits of values in [1, 3]: last place 1e-5, rounding RMS 1e-5/sqrt(12)
    assert level.sigma == pytest.approx(1e-5 / math.sqrt(12), rel=1e-6)


def test_noise_levels_are_validated_and_described():
    levels = noise_levels({"joint_angle": 1e-4, "tip_acceleration": NoiseLevel.quantised(0.01)})
    assert levels["joint_angle"] == NoiseLevel(1e-4, source="given")
    assert levels["tip_acceleration"].describe() == "given, quantisation step q=0.01"
    assert NoiseLevel.quantised(0.002, source="quantisation").describe() == (
        "quantisation step q=0.002")
    with pytest.raises(ValueError, match=r"^noise given for unknown channel 'torque'"):
        noise_levels({"torque": 1.0})
    with pytest.raises(ValueError, match=r"^noise level of joint_angle must be positive"):
        noise_levels({"joint_angle": 0.0})
    with pytest.raises(ValueError, match=r"^noise level of joint_angle must be a number"):
        noise_levels({"joint_angle": "small"})
    with pytest.raises(ValueError, match="noise source"):
        NoiseLevel(1.0, source="guessed")


@pytest.fixture(scope="module")
def model():
    return Model()


@pytest.fixture(scope="module")
def truth():
    values = dict(reference_parameters())
    values.update({k: jnp.asarray(v) for k, v in TRUTH.items()})
    return values


def test_correct_model_is_not_flagged(model, truth):
    """The correct model on noisy records (quantised angle) passes over many noise seeds."""
    flagged = []
    for seed in range(8):
        params = dict(truth) | {"tau_c": truth["tau_c"] * (1 + 0.02 * seed)}  # new rest angles
        records = make_records(model, params, seed=seed)
        d = diagnose(records, predictions(model, params, records))
        assert d.channels["joint_angle"].noise.kind == "quantised"
        assert d.channels["joint_angle"].noise.step == pytest.approx(ENCODER_STEP)
        assert d.channels["tip_acceleration"].noise.sigma == pytest.approx(0.05, rel=0.1)
        acc, angle = d.channels["tip_acceleration"], d.channels["joint_angle"]
        assert acc.nrmse == pytest.approx(acc.noise_floor_nrmse, rel=0.1)
        # a resting arm keeps one rounding error: between 0 and q/2 = sqrt(3) q/sqrt(12) RMS
        assert angle.nrmse <= math.sqrt(3) * angle.noise_floor_nrmse
        flagged.append(not d.consistent_with_noise)
        assert (d.unexplained() is None) == d.consistent_with_noise
    assert sum(flagged) <= 1  # alpha = 0.01 per test; one chance failure tolerated


def test_wrong_stiffness_is_located_in_frequency(model, truth):
    records = make_records(model, truth, seed=11)
    wrong = dict(truth) | {"E": truth["E"] * 1.08}
    d = diagnose(records, predictions(model, wrong, records))
    assert not d.consistent_with_noise
    acc = d.channels["tip_acceleration"]
    assert not acc.whiteness.white() and acc.rms_ratio > 3
    # every resonance moves up by about sqrt(1.08): the first free-hub mode in particular
    f_true = float(free_hub_modes(model.structure(truth)).frequencies_hz[0])
    first = min(d.frf.resonances, key=lambda r: abs(r.measured_hz - f_true))
    assert first.measured_hz == pytest.approx(f_true, rel=0.05)
    assert first.shift_hz == pytest.approx(f_true * (math.sqrt(1.08) - 1), rel=0.35)
    assert all(r.shift_hz > 0 for r in d.frf.resonances)
    lowest = d.frf.bands[0]
    assert lowest.nrmse > 5
    where = d.unexplained()
    assert where is not None and where["frequency_hz"]
    assert any(abs(f - r.measured_hz) < 1.5 for f in where["frequency_hz"][:3]
               for r in d.frf.resonances)
    assert any("resonance measured at" in line for line in d.summary())
    step = d.channels["joint_angle"].noise.step
    assert f"  noise level σ = {step / math.sqrt(12):.4g} rad (quantisation step q={step:.6g})" in (
        d.summary())
    json_ready = d.to_dict()
    assert json_ready["consistent_with_noise"] is False
    assert json_ready["channels"]["tip_acceleration"]["consistent"] is False


def test_a_strain_gauge_rig_is_diagnosed_on_its_own_channels(model, truth):
    """No accelerometer: the residuals, noise levels and the FRF (torque → root strain) are
    those of the channels measured, and a stiffer model shows in the strain's resonances."""
    records = make_records(model, truth, seed=11, extras=("root_strain",))
    wrong = dict(truth) | {"E": truth["E"] * 1.08}
    d = diagnose(records, predictions(model, wrong, records),
                 noise={"root_strain": 1e-7}, channels=("joint_angle", "root_strain"))
    assert list(d.channels) == ["joint_angle", "root_strain"]
    assert d.channels["root_strain"].noise.source == "given"
    assert d.frf.output == "root_strain" and d.to_dict()["frf"]["output"] == "root_strain"
    f_true = float(free_hub_modes(model.structure(truth)).frequencies_hz[0])
    first = min(d.frf.resonances, key=lambda r: abs(r.measured_hz - f_true))
    assert first.shift_hz == pytest.approx(f_true * (math.sqrt(1.08) - 1), rel=0.35)
    assert not d.channels["root_strain"].consistent()
    assert set(d.unexplained()["nrmse"]) <= {"joint_angle", "root_strain"}
    with pytest.raises(ValueError, match="noise given for unknown channel 'tip_acceleration'"):
        diagnose(records, predictions(model, truth, records), channels=("root_strain",),
                 noise={"tip_acceleration": 0.05})


def test_a_record_without_an_encoder_is_localised_along_the_model_angle(model, truth):
    """Acceleration only (no joint angle logged): the misfit is still placed in angle ranges,
    those of the model's joint angle."""
    full = make_records(model, truth, seed=3)
    bare = [Record(r.time, r.torque, None, r.tip_acceleration, name=r.name) for r in full]
    wrong = dict(truth) | {"J_h": truth["J_h"] * 1.2}
    preds = predictions(model, wrong, bare)
    d = diagnose(bare, preds, channels=("tip_acceleration",))
    assert list(d.channels) == ["tip_acceleration"] and d.frf.output == "tip_acceleration"
    angle = np.concatenate([np.asarray(p.joint_angle) for p in preds])
    edges = np.degrees(np.linspace(angle.min(), angle.max(), 5))
    names = [c.condition for c in d.localisation.conditions if c.condition.startswith("angle")]
    assert names == [f"angle {a:.0f} to {b:.0f} deg"
                     for a, b in zip(edges[:-1], edges[1:], strict=True)]
    assert not d.consistent_with_noise


def test_frf_error_is_zero_for_identical_predictions(model, truth):
    records = make_records(model, truth, noise=False)
    frf = frf_error(records, [r.to_dict() for r in records])
    assert frf.nrmse == pytest.approx(0.0, abs=1e-9)
    assert all(abs(r.shift_hz) < 1e-9 for r in frf.resonances)


def _record(n=2001, torque_until=0.3):
    t = np.arange(n) * DT
    torque = np.where(t < torque_until, 0.3, 0.0)
    angle = np.clip(t, 0, 1.0)  # moves for 1 s, then rests
    return Record(t, torque, angle, np.sin(40 * t), name="r")


def test_localise_finds_torque_on_and_rest_misfit():
    rec = _record()
    rng = np.random.default_rng(5)
    noise = {"joint_angle": NoiseLevel(0.01), "tip_acceleration": NoiseLevel(0.01)}
    base = {c: 0.01 * rng.standard_normal(rec.n_samples) for c in noise}
    on = rec.torque != 0
    res = dict(base) | {"tip_acceleration": base["tip_acceleration"] + 0.2 * on}
    velocity = np.where(rec.time < 1.0, 1.0, 0.0)
    loc = localise(rec, res, velocity=velocity, noise=noise)
    torque = loc.condition("torque on")
    assert torque.time_share == pytest.approx(0.15, abs=0.001)
    assert torque.share["tip_acceleration"] > 0.97
    assert torque.concentration > 6
    assert loc.condition("free vibration").share["tip_acceleration"] < 0.03
    assert loc.worst_window().condition == "0.00-0.20 s"
    rest = dict(base) | {"joint_angle": base["joint_angle"] + 0.2 * (velocity == 0)}
    loc = localise(rec, rest, velocity=velocity, noise=noise)
    assert loc.condition("near-zero velocity").share["joint_angle"] > 0.97
    # pure noise: nothing concentrates much
    loc = localise(rec, base, velocity=velocity, noise=noise)
    assert max(c.concentration for c in loc.conditions) < 3
    with pytest.raises(ValueError, match="expected"):
        localise(rec, {"joint_angle": np.zeros(5)}, velocity=velocity)


def test_localise_reversals_and_angle_ranges():
    rec = _record()
    t = rec.time
    velocity = np.cos(2 * np.pi * t)  # reverses at 0.25, 0.75, 1.25, 1.75 s
    reversal = np.zeros_like(t)
    for tr in (0.25, 0.75, 1.25, 1.75):
        reversal += np.abs(t - tr) < 0.01
    res = {"joint_angle": 0.1 * reversal, "tip_acceleration": np.zeros_like(t)}
    loc = localise(rec, res, velocity=velocity, reversal_s=0.02)
    assert loc.condition("velocity reversals").share["joint_angle"] == pytest.approx(1.0)
    names = [c.condition for c in loc.conditions]
    assert sum(n.startswith("angle ") for n in names) == 4


def test_amplitude_scaling_exponents():
    t = np.arange(1001) * DT
    records, residuals = [], []
    for i, a in enumerate((0.1, 0.2, 0.4)):
        torque = np.where(t < 0.3, a, 0.0)
        records.append(Record(t, torque, a * np.sin(t), a * np.cos(9 * t), name=f"r{i}"))
        residuals.append({"joint_angle": a * 1e-3 * np.sin(3 * t),
                          "tip_acceleration": 0.01 * np.cos(5 * t)})
    s = amplitude_scaling(records, residuals)
    assert s.exponent["joint_angle"] == pytest.approx(1.0, abs=1e-9)
    assert s.exponent["tip_acceleration"] == pytest.approx(0.0, abs=1e-9)
    np.testing.assert_allclose(s.amplitudes, [0.1, 0.2, 0.4])


def test_diagnose_validates_inputs(model, truth):
    records = make_records(model, truth, inputs=("pulse",), noise=False)
    with pytest.raises(ValueError, match="1 record.*2 prediction"):
        diagnose(records, [records[0], records[0]])
    with pytest.raises(ValueError, match="tip_acceleration"):
        diagnose(records, [{"joint_angle": records[0].joint_angle}])
    with pytest.raises(ValueError, match="shape"):
        diagnose(records, [{"joint_angle": np.zeros(3), "tip_acceleration": np.zeros(3)}])
    with pytest.raises(ValueError, match="unknown channel"):
        diagnose(records, [records[0]], noise={"torque": NoiseLevel(1.0)})
    with pytest.raises(ValueError, match="alpha"):
        diagnose(records, [records[0]], alpha=2.0)


def test_figures_draw(model, truth, tmp_path):
    from jaxflex.plots import save_figure
    from jaxflex.plots.diagnose import plot_diagnosis, plot_error_falling, plot_overlay

    records = make_records(model, truth, seed=1)
    wrong = dict(truth) | {"J_h": truth["J_h"] * 1.2}
    before = predictions(model, wrong, records)
    after = predictions(model, truth, records)
    fig = plot_diagnosis(diagnose(records, before))
    assert len(fig.axes) == 7
    save_figure(fig, tmp_path / "diag.png")
    fig = plot_error_falling(["base", "+ payload"], {"joint_angle": [3.0, 0.03],
                             "tip_acceleration": [20.0, 1.0]},
                             noise_floor={"tip_acceleration": 0.98}, frf_nrmse=[10.0, 0.2])
    save_figure(fig, tmp_path / "fall.png")
    fig = plot_overlay(records[0], before[0], after[0])
    save_figure(fig, tmp_path / "overlay.png")
    assert all((tmp_path / f).stat().st_size > 10_000 for f in ("diag.png", "fall.png",
                                                               "overlay.png"))
    with pytest.raises(ValueError, match="2 steps"):
        plot_error_falling(["a", "b"], {"joint_angle": [1.0]})
