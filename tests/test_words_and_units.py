"""What jaxflex prints says what it means, in the right unit: intervals that narrow are said to
narrow, no "-0 %", no negative likelihood ratio, a profile's start named as a start, a lag in
milliseconds beside the refit's own time, a sensor's or a drive's own unit wherever its channel
is printed or written, a sub-command's own usage for its bad options, and a record that logs a
command and the current it drew read through the rig's drive."""

from __future__ import annotations

import tomllib
import warnings

import numpy as np
import pytest

from jaxflex.arm import arm_from_dict
from jaxflex.cli import main
from jaxflex.comparison import (
    FRF,
    Comparison,
    FRFSettings,
    RecordComparison,
    channel_units,
)
from jaxflex.data import KNOWN_UNITS, Record, RecordError, load_record
from jaxflex.diagnosis import NoiseLevel, diagnose
from jaxflex.discovery.candidates import candidate_set
from jaxflex.discovery.explain import claims, collect_evidence, percent, sentence
from jaxflex.discovery.report import Confirmation
from jaxflex.discovery.scores import ScoreResult
from jaxflex.effects import get_effect
from jaxflex.intervals import widening_span
from jaxflex.parameters import ParameterSpace, ParameterSpec
from jaxflex.records import RecordWarning
from jaxflex.sensors import StrainGauge

RIG = """name = "bench"
[link]
length = 0.35
width = 0.025
thickness = 0.002
density = 7850.0
[simulation]
n_elements = 4
[parameters]
E = { reference = 2e11, fixed = true }
J_h = { reference = 0.003, lower = 0.001, upper = 0.01 }
b_v = { reference = 0.002, fixed = true }
tau_c = { reference = 0.01, fixed = true }
alpha = { reference = 1.0, fixed = true }
beta = { reference = 5e-5, fixed = true }
[drive]
type = "command"
unit = "{unit}"
torque_per_unit = 0.05
[[sensors]]
type = "encoder"
counts_per_revolution = 2048
[[sensors]]
type = "accelerometer"
x = 0.3
channel = "acc"
reading_unit = "counts"
gain = 40.0
"""
"""A 0.35 m steel strip driven by a command in ``unit`` (an amplifier's input), an encoder and
an accelerometer in ADC counts part-way along the link."""


def _rig(unit: str = "V") -> dict:
    return tomllib.loads(RIG.replace("{unit}", unit))


# --- words ----------------------------------------------------------------------------------


def test_robust_intervals_are_said_to_narrow_or_widen():
    assert widening_span(1.2, 6.85) == "1.2-6.85 x wider"
    assert widening_span(0.827, 6.85) == "1.21 x narrower to 6.85 x wider"
    assert widening_span(0.5, 0.8) == "1.25-2 x narrower"
    assert widening_span(18.71, 18.74) == "18.7 x wider"  # not "18.7-18.7"


def test_a_share_is_never_minus_zero_percent():
    assert percent(-0.004) == "0 %" and percent(0.004) == "0 %"
    assert percent(-0.02) == "-2 %" and percent(0.126) == "13 %"


def _result(effect, setting: str = "") -> ScoreResult:
    spec = effect.parameters[0]
    return ScoreResult(effect=effect.name, parameters=(spec.name,), statistic=40.0, dof=1,
                       p_value=1e-9, one_sided=True, z=6.3, estimate={spec.name: 0.01},
                       units={spec.name: spec.unit}, setting=setting, significant=True)


def _claims(result, effect, refit, status):
    ev = collect_evidence(result, effect, None, refit, level=0.01)
    result = result.__class__(**{**result.__dict__, "evidence": ev})
    result = result.__class__(**{**result.__dict__, "status": status,
                                 "claims": tuple(claims(result, status))})
    return sentence(result)


def test_a_refit_that_ended_worse_is_said_so_never_as_a_negative_lr():
    gravity = get_effect("gravity")
    name = gravity.parameters[0].name
    refit = Confirmation(effect="gravity", lr=-1.7e4, p_value=1.0, delta_bic=1.7e4 + 9.2,
                         explained=-0.004, confirmed=False, params={name: 0.02}, level=0.002)
    text = _claims(_result(gravity), gravity, refit, "not_confirmed")
    assert text.startswith("gravity: not added, not confirmed: its refit (")
    assert "ended worse than the model without it: −2 log L rose by 1.7e+04" in text
    assert "LR" not in text and "-0 %" not in text and "BIC" not in text


def test_a_profiled_setting_is_named_as_the_start_and_the_fitted_value_is_printed():
    (stribeck,) = candidate_set(["stribeck"])
    member = next(i for i, e in enumerate(stribeck.effects) if e.v_s == 0.03)
    assert stribeck.label(member) == "v_s started at 0.03"
    effect = stribeck.effects[member]
    refit = Confirmation(effect="stribeck", lr=900.0, p_value=1e-12, delta_bic=-880.0,
                         explained=0.97, confirmed=True,
                         params={"delta_tau_s": 0.0399, "v_s": 0.0999, "J_h": 0.006},
                         level=0.002)
    text = _claims(_result(effect, stribeck.label(member)), effect, refit, "explains")
    assert text.startswith("stribeck (v_s started at 0.03): added and kept: the refit "
                           "(delta_tau_s = 0.0399 N m, v_s = 0.0999 rad/s) explains 97 %")
    assert "(LR = 900, p = 1e-12)" in text


def test_the_lag_is_stated_in_milliseconds_beside_the_refits_own_time():
    delay = get_effect("delay")
    name = delay.parameters[0].name
    refit = Confirmation(effect="delay", lr=50.0, p_value=1e-10, delta_bic=-40.0,
                         explained=0.95, confirmed=True, params={name: 0.00096}, level=0.002)
    result = _result(delay)
    ev = collect_evidence(result, delay, None, refit, level=0.01)
    ev["lag"] = {"channel": "tip_acceleration", "lag_s": 0.058, "value": -0.31, "band": 0.05,
                 "rate_value": 0.62, "rate_peak": 0.7, "cited": True,
                 "fitted_s": {name: 0.00096}}
    result = result.__class__(**{**result.__dict__, "evidence": ev})
    (lag,) = [c["text"] for c in claims(result, "explains") if c["rule"] == "lag"]
    assert lag.startswith("tip_acceleration residual correlates most with the torque 58 ms "
                          "before it (-0.31, band ±0.05)")
    assert lag.endswith(f"as a late response leaves it; the refit's {name} is 0.96 ms, a late "
                        "response of any size leaves this sign")


def test_a_wrong_option_is_answered_under_the_sub_commands_usage(capsys):
    assert main(["identify", "run.csv", "--out", "fit.json", "--populaton", "8"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("usage: jaxflex identify ")
    assert err.rstrip().endswith("jaxflex identify: error: unrecognized arguments: "
                                 "--populaton 8")
    assert main(["datasets", "list", "--bogus"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("usage: jaxflex datasets list ")
    assert err.rstrip().endswith("jaxflex datasets list: error: unrecognized arguments: --bogus")


def test_negative_bounds_of_a_linear_parameter_map_without_a_numpy_warning():
    space = ParameterSpace([
        ParameterSpec("g", "counts per m/s^2", lower=-60.0, upper=-20.0, reference=-40.0,
                      log_scale=False),
        ParameterSpec("E", "Pa", lower=1e10, upper=1e12, reference=1e11),
    ])
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # "invalid value encountered in log" was one
        unit = np.asarray(space.to_unit({"g": np.float64(-40.0), "E": np.float64(1e11)}))
    np.testing.assert_allclose(unit, [0.5, 0.5])


# --- units ----------------------------------------------------------------------------------


def test_a_strain_is_in_m_per_m():
    assert StrainGauge(x=0.05).unit == "m/m" and KNOWN_UNITS["root_strain"] == "m/m"
    assert StrainGauge(x=0.05, calibration="deflection_angle").unit == "rad"


def test_channel_units_name_the_drives_unit():
    arm = arm_from_dict(_rig("V"))
    assert channel_units(arm, ("command", "joint_angle", "acc")) == {
        "command": "V", "joint_angle": "rad", "acc": "counts"}


def test_simulate_with_an_arm_writes_the_drives_unit(tmp_path):
    rig = tmp_path / "bench.toml"
    rig.write_text(RIG.replace("{unit}", "V"))
    out = tmp_path / "log.csv"
    assert main(["simulate", "--arm", str(rig), "--input", "pulse", "--duration", "0.3",
                 "--rest", "0.05", "--out", str(out)]) == 0
    first = out.read_text().splitlines()[0]
    assert first == "# units = time s, joint_angle rad, command V, acc counts"
    assert load_record(out).input_name == "command"


def test_a_diagnosis_states_its_levels_in_the_sensors_unit():
    t = 1e-3 * np.arange(2000)
    u = np.sin(2 * np.pi * 2.0 * t)
    rng = np.random.default_rng(4)
    measured = 30.0 * np.sin(2 * np.pi * 9.0 * t) + rng.normal(0.0, 0.5, t.size)
    record = Record(time=t, extras={"command": u, "acc": measured}, name="run")
    model = {"acc": np.zeros_like(t), "joint_angle": 0.1 * t}  # the model's angle localises
    diag = diagnose([record], [model], noise={"acc": NoiseLevel(0.5)},
                    channels=("acc",), units={"acc": "counts"})
    assert "  noise level σ = 0.5 counts (given)" in diag.summary()
    message = diag.unexplained()["message"]
    rms = np.sqrt(np.mean(measured**2))
    assert f"(RMS {rms:.3g} counts, {rms / 0.5:.2g}x noise)" in message


def test_a_record_with_a_command_and_its_current_is_read_through_the_drive(tmp_path):
    t = 1e-3 * np.arange(400)
    command = np.where(t > 0.05, 2.0, 0.0)
    path = tmp_path / "both.csv"
    rows = "\n".join(f"{a!r},{b!r},{0.3 * b!r},0.0" for a, b in zip(t.tolist(), command.tolist(),
                                                                   strict=True))
    path.write_text("time,command,current,joint_angle\n" + rows + "\n")
    with pytest.raises(RecordError, match=r"exactly one input column of .*found \['current', "
                                          r"'command'\]"):
        load_record(path, unit_check=False)
    with pytest.warns(RecordWarning, match=r"both.csv: column\(s\) \['current'\] ignored: the "
                                            r"rig's drive reads column 'command'$"):
        record = load_record(path, unit_check=False, drive="command")
    assert record.input_name == "command" and "current" not in record.columns
    np.testing.assert_array_equal(record.input, command)


# --- the FRF -------------------------------------------------------------------------------


def test_the_frf_names_the_drives_unit_and_marks_the_resonance_as_fitted():
    """A model whose hub is held by friction rings at 2.9 Hz, below its free-hub mode at
    4.35 Hz: the figure and the table mark the resonance of the model as fitted."""
    from jaxflex.plots.compare import plot_frf

    freqs = np.linspace(0.0, 20.0, 201)
    s = 2j * np.pi * freqs

    def peak(f0):
        w = 2 * np.pi * f0
        return s**2 / (s**2 + 2 * 0.02 * w * s + w**2)

    frf = FRF(freqs=freqs, measured=peak(2.95), model=peak(2.9), coherence=np.ones(201),
              compared=freqs > 0, f_max=15.0)
    row = RecordComparison(
        name="run", role="fit", nrmse={"acc": 5.0}, relative_error={"acc": 0.05},
        frf_nrmse=3.0, frf_nrmse_raw=3.0, frf_bins=(150, 150), noise_floor={},
        measured_peaks_hz=(2.95,), model_peaks_hz=(2.9,), frf=frf)
    record = Record(time=1e-2 * np.arange(50), extras={"command": np.ones(50),
                                                     "acc": np.ones(50)}, name="run")
    comparison = Comparison(
        rows=(row,), records=(record,), simulated=(None,), params={}, effects=(),
        resonances_hz=(4.35,), t_end=None, frf_settings=FRFSettings(), channels=("acc",),
        units={"acc": "counts", "command": "V"}, link="acc", input_name="command")
    fig = plot_frf(comparison)
    mag = fig.axes[0]
    assert mag.get_ylabel() == "|H| (dB re 1 counts / V)"
    dashed = [ln.get_xdata()[0] for ln in mag.get_lines() if ln.get_linestyle() == "--"]
    assert dashed == [2.9]
    assert "model resonance (as fitted)" in [t.get_text() for t in mag.get_legend().get_texts()]
    assert ("Model resonances as fitted (its FRF's peaks): 2.90 Hz; free-hub modes: 4.35 Hz."
            in comparison.table())


# --- a withdrawn effect's steps ---------------------------------------------------------------


def _scored(name: str, lr: float | None, explained: float = 0.0) -> ScoreResult:
    """A scored candidate with its evidence; refitted (and confirmed) where ``lr`` is given."""
    effect = get_effect(name)
    result = _result(effect)
    refit = None if lr is None else Confirmation(
        effect=name, lr=lr, p_value=1e-9, delta_bic=-lr + 7.0, explained=explained,
        confirmed=True, params={effect.parameters[0].name: 0.01}, level=0.002)
    if lr is None:
        result = result.__class__(**{**result.__dict__, "p_value": 0.4, "significant": False,
                                     "statistic": 0.7})
    ev = collect_evidence(result, effect, None, refit, level=0.002)
    return result.__class__(**{**result.__dict__, "evidence": ev})


def test_a_withdrawn_effects_steps_keep_their_rankings_and_say_what_it_removed():
    """gravity, confirmed after 'base', removes 20 % of the misfit, does not lower a held-out
    error: its step is cut, and the JSON still holds both steps' rankings."""
    import types

    from jaxflex.discovery.explain import annotate
    from jaxflex.discovery.loop import MIN_EXPLAINED, _withdraw, withdrawn_note
    from jaxflex.discovery.report import DiscoveryFit, DiscoveryReport, Step

    misfit = types.SimpleNamespace(consistent_with_noise=False)

    def step(added, ranking, explained=None):
        fit = DiscoveryFit(model=None, params={"J_h": 0.006}, cost=900.0, n_params=1,
                           n_samples=1000, noise={}, intervals={"J_h": (0.0059, 0.0061)})
        label = "base" if added is None else f"base + {added}"
        return Step(added=added, fit=fit, nrmse={"acc": 4.0}, frf_nrmse=2.0, holdout=None,
                    diagnosis=misfit, ranking=tuple(ranking), explained=explained, label=label)

    steps = [step(None, [_scored("gravity", 180.0, 0.2), _scored("payload", None)]),
             step("gravity", [_scored("payload", None)], explained=0.2)]
    kept, cut = _withdraw(steps)
    assert [s.structure for s in kept] == ["base"] and [s.added for s in cut] == ["gravity"]
    every = annotate([*kept, *cut], ["gravity"], MIN_EXPLAINED)
    report = DiscoveryReport(
        steps=tuple(every[:1]), unexplained=None, withdrawn=("gravity",), alpha=0.01,
        candidates=("gravity", "payload"), records=(), holdout=None, settings={},
        wall_time=1.0, noise_floor={}, withdrawn_steps=tuple(every[1:]))
    data = report.to_dict()
    assert [[(e["after"], e["effect"], e["status"]) for e in r] for r in data["ranking"]] == [
        [("base", "gravity", "withdrawn"), ("base", "payload", "not_significant")],
        [("base + gravity", "payload", "not_significant")]]
    assert [s["added"] for s in data["withdrawn_steps"]] == ["gravity"]
    assert data["steps"][0]["intervals"] == {"J_h": [0.0059, 0.0061]}
    assert withdrawn_note(cut, held_out=True) == (
        "gravity removed 20 % of the misfit above the noise, less than 90 % and did not lower "
        "the held-out error; withdrawn")
