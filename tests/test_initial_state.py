"""Records that do not start at rest: an estimated or periodic initial state (jaxflex.initial).

The references are SciPy Radau runs on the full FEM equations (``reference_solver``) from rest,
logged from mid-run: a moving, deflected arm at the record's start; and runs under a periodic
input long enough to reach the cyclic steady state, logged over their last periods.
"""

import json

import numpy as np
import pytest
from reference_solver import designed_torque, logged_mid_run

from jaxflex import Model, identify
from jaxflex.cli import _options, main
from jaxflex.comparison import compare
from jaxflex.data import Record, load_record, save_record
from jaxflex.frequency_response import natural_frequencies
from jaxflex.identification import Fit
from jaxflex.initial import (
    DEFAULT_MODES,
    INITIAL_STATES,
    input_period,
    lead_in,
    record_states,
    why_not_still,
)
from jaxflex.synthetic import (
    ENCODER_STEP,
    add_noise,
    make_records,
    simulated_record,
)

MODEL = Model()
TRUTH = {k: float(v) for k, v in MODEL.space.reference().items()}
DT = 1e-3
CUT = 350  # samples run from rest before the record starts: the joint at -0.64 rad/s


def _torque() -> np.ndarray:
    """The designed input held over 10 samples (the reference restarts at every change)."""
    return np.repeat(designed_torque()[::10], 10)


def _record(name: str, outputs: np.ndarray, torque: np.ndarray, seed: int | None) -> Record:
    """A record of joint angle and tip acceleration, with the testbed's sensor noise."""
    record = Record(time=DT * np.arange(torque.size), torque=torque, joint_angle=outputs[0],
                    tip_acceleration=outputs[1], name=name)
    return record if seed is None else add_noise(record, seed)


@pytest.fixture(scope="module")
def mid_run():
    torque = _torque()
    outputs, state = logged_mid_run(MODEL, TRUTH, torque, DT, CUT)
    return torque[CUT:], outputs, state


# ------------------------------------------------------------------------------ input checks


def test_the_period_of_a_repeating_input_is_found():
    t = DT * np.arange(2000)
    u = 0.2 * np.sin(2 * np.pi * 4.0 * t) + 0.1 * np.sin(2 * np.pi * 12.0 * t)  # 250 samples
    logged = np.float32(u).astype(float)  # as a logger writes it
    assert input_period(Record(time=t, torque=logged, joint_angle=t, name="sine")) == 250
    # one whole period of a multisine: its end joins its start
    one = Record(time=t[:250], torque=u[:250], joint_angle=t[:250], name="one period")
    assert input_period(one) == 250


def test_a_non_periodic_input_is_refused_naming_the_record():
    t = DT * np.arange(1000)
    step = Record(time=t, torque=np.where(t < 0.2, 0.0, 0.3), joint_angle=t, name="step")
    with pytest.raises(ValueError, match=r"record 'step': initial_state 'periodic' needs a "
                                         r"periodic input, but its 'torque' repeats nowhere"):
        input_period(step)


def test_a_record_too_short_for_an_estimate_is_refused():
    (record,) = make_records(inputs=["pulse"], duration=0.05)
    with pytest.raises(ValueError, match=r"record 'pulse' \(0.051 s\) is too short for "
                                         r"initial_state 'estimate' with 2 modes: it must span "
                                         r"one period of the lowest mode \(0.1192 s"):
        identify([record], MODEL, initial_state="estimate", generations=1, population=4)
    with pytest.raises(ValueError, match="initial_state must be one of rest, estimate, periodic"):
        identify([record], MODEL, initial_state="moving")


def test_the_command_line_offers_the_library_s_initial_states():
    assert _options.INITIAL_STATES == INITIAL_STATES
    assert _options.INITIAL_MODES == DEFAULT_MODES


def test_the_cli_refuses_an_initial_state_that_cannot_apply(tmp_path, capsys):
    t = DT * np.arange(600)
    record = simulated_record(MODEL, TRUTH, "step", t, np.where(t < 0.1, 0.0, 0.3), DT)
    path = save_record(record, tmp_path / "step.csv")
    status = main(["identify", str(path), "--initial-state", "periodic", "--generations", "1",
                   "--population", "4", "--out", str(tmp_path / "fit.json"), "--quiet"])
    err = capsys.readouterr().err.strip().splitlines()
    assert status == 2
    assert len(err) == 1 and "record 'step': initial_state 'periodic' needs a periodic" in err[0]
    short = save_record(record.trim(0.05, 0.13), tmp_path / "short.csv")
    status = main(["identify", str(short), "--initial-state", "estimate", "--generations", "1",
                   "--population", "4", "--out", str(tmp_path / "fit.json"), "--quiet"])
    err = capsys.readouterr().err.strip().splitlines()
    assert status == 2
    assert len(err) == 1 and "record 'short' (0.081 s) is too short for initial_state " in err[0]
    assert not (tmp_path / "fit.json").exists()


# ------------------------------------------------------------------------------ a moving start


def test_a_record_not_at_rest_is_named_with_what_moved(mid_run):
    torque, outputs, _ = mid_run
    record = _record("mid", outputs, torque, seed=1)
    moved = why_not_still(record, MODEL, ("joint_angle", "tip_acceleration"))
    assert moved.startswith("record 'mid' does not start at rest (joint_angle starts at -0.02")
    assert "initial_state 'estimate'" in moved
    # records from rest, with their noise, say nothing
    for r in make_records(seed=3):
        assert why_not_still(r, MODEL, ("joint_angle", "tip_acceleration")) is None


def test_the_estimated_state_at_the_truth_is_the_reference_state(mid_run):
    """The start estimated at the true parameters is Radau's state at the cut: angle, velocity
    and the two lowest modes' coordinates."""
    torque, outputs, (angle, velocity, modal, modal_velocity) = mid_run
    record = _record("mid", outputs, torque, seed=None)
    z = record_states(MODEL, TRUTH, [record], None, "estimate")["mid"]
    assert z[0] == pytest.approx(angle, abs=1e-4)
    assert z[1] == pytest.approx(velocity, rel=1e-2)
    np.testing.assert_allclose(z[2:4], modal[:2], rtol=0.03, atol=2e-6)
    np.testing.assert_allclose(z[4:6], modal_velocity[:2], rtol=0.03, atol=1e-4)
    # a held-out record compared from its own estimated start, and from rest
    scores = compare([record], MODEL, TRUTH, t_end=None, initial_state="estimate").rows[0].nrmse
    assert max(scores.values()) < 1.0, scores
    at_rest = compare([record], MODEL, TRUTH, t_end=None).rows[0].nrmse
    assert min(at_rest.values()) > 20.0, at_rest


@pytest.mark.slow  # about 2 min on the 2-core machine: three DE 10 x 16 fits, refinement
def test_a_held_out_record_starts_from_the_state_of_its_lead_in_alone(mid_run):
    """Held out, a record's state is estimated from its first two periods of the lowest mode
    only: what follows may change without moving it, the state is near Radau's, the rest is
    predicted to the noise, and the comparison says how long the lead-in was and keeps the
    state in its JSON."""
    torque, outputs, (angle, velocity, _, _) = mid_run
    record = _record("mid", outputs, torque, seed=1)
    span = lead_in(MODEL, TRUTH, record, 2)
    period = 1.0 / float(natural_frequencies(MODEL, TRUTH)[0])
    assert span == pytest.approx(max(2.0 * period, 0.2), rel=1e-12) and span < record.duration / 2
    c = compare([record], MODEL, TRUTH, t_end=None, initial_state="estimate")
    assert c.lead_ins == {"mid": span}
    z = c.initial_states["mid"]
    assert z["angle"] == pytest.approx(angle, abs=1e-3)
    assert z["velocity"] == pytest.approx(velocity, rel=0.05)
    assert max(c[0].nrmse.values()) < 5.0, c[0].nrmse
    # the samples after the lead-in take no part in the state
    late = record.time > span + record.dt
    changed = record.with_outputs(joint_angle=np.where(late, record.joint_angle + 0.3,
                                                       record.joint_angle))
    again = compare([changed], MODEL, TRUTH, t_end=None, initial_state="estimate")
    assert again.initial_states == c.initial_states
    data = json.loads(json.dumps(c.to_dict()))
    assert data["lead_in_s"] == {"mid": span} and data["initial_states"]["mid"] == z
    assert f"mid {span:.3g} s" in " ".join(c.table().split())


def test_parameters_and_state_of_a_record_logged_mid_run_are_recovered(mid_run, tmp_path):
    torque, outputs, state = mid_run
    save_record(_record("mid", outputs, torque, seed=1), tmp_path / "mid.csv")
    record = load_record(tmp_path / "mid.csv")  # as logged: 9 significant digits
    assert main(["identify", str(tmp_path / "mid.csv"), "--initial-state", "estimate",
                 "--initial-modes", "3", "--generations", "10", "--population", "16",
                 "--out", str(tmp_path / "fit.json"), "--quiet"]) == 0
    fit = Fit.from_json(tmp_path / "fit.json")
    assert fit.initial_state == "estimate" and fit.settings["initial_modes"] == 3
    assert not any("does not start at rest" in w for w in fit.warnings)
    for name in fit.names:
        lo, hi = fit.intervals[name]
        if name == "beta":  # biased by the simulator against Radau, from rest alike (below)
            assert fit.params[name] == pytest.approx(TRUTH[name], rel=0.02)
            continue
        assert lo <= TRUTH[name] <= hi, (name, fit.params[name], lo, hi)
    start = fit.initial_state_intervals["mid"]
    for name, truth in (("angle", state[0]), ("velocity", state[1]),
                        ("modal_1", state[2][0]), ("modal_velocity_1", state[3][0])):
        assert start[name][0] <= truth <= start[name][1], (name, truth, start[name])
    # the same run logged from t = 0, at rest, gives the same parameters
    full = logged_mid_run(MODEL, TRUTH, _torque(), DT, 0)[0]
    at_rest = identify([_record("from rest", full, _torque(), seed=1)], MODEL, generations=10,
                       population=16, init_population=fit)
    for name in fit.names:
        lo, hi = fit.intervals[name]
        assert lo <= at_rest.params[name] <= hi, (name, at_rest.params[name], lo, hi)
    # validate starts the fitted record where the fit found it
    assert main(["validate", str(tmp_path / "mid.csv"), "--fit", str(tmp_path / "fit.json"),
                 "--t-end", "0.6", "--json", str(tmp_path / "scores.json"), "--quiet"]) == 0
    scores = json.loads((tmp_path / "scores.json").read_text())["records"][0]["nrmse"]
    assert scores["joint_angle"] < 2.0 and scores["tip_acceleration"] < 2.0, scores
    from_rest = compare([record], MODEL, fit.params, t_end=0.6).rows[0].nrmse
    assert from_rest["joint_angle"] > 20.0 and from_rest["tip_acceleration"] > 20.0, from_rest
    # fitted from rest, the record logged mid-run is named in a warning
    wrong = identify([record], MODEL, generations=2, population=8, refine=False,
                     intervals=False)
    assert any(w.startswith("record 'mid' does not start at rest") for w in wrong.warnings)


@pytest.mark.slow  # a few minutes on the 2-core machine: a fit with an estimated state
def test_identify_plots_each_record_from_the_state_the_fit_estimated(mid_run, tmp_path,
                                                                     monkeypatch):
    """``identify --initial-state estimate --plot`` draws the record from its estimated start:
    the figure's NRMSE is the one ``validate`` gives for the same fit, not the fit from rest."""
    import jaxflex.plots.compare as figures

    torque, outputs, _ = mid_run
    path = save_record(_record("mid", outputs, torque, seed=1), tmp_path / "mid.csv")
    drawn = []
    plot_time = figures.plot_time
    monkeypatch.setattr(figures, "plot_time", lambda c, i, **kw: (
        drawn.append(dict(c[i].nrmse)), plot_time(c, i, **kw))[1])
    fit = tmp_path / "fit.json"
    assert main(["identify", str(path), "--initial-state", "estimate", "--initial-modes", "2",
                 "--generations", "2", "--population", "8", "--no-refine", "--out", str(fit),
                 "--plot", str(tmp_path / "fig.png"), "--quiet"]) == 0
    assert (tmp_path / "fig_mid.png").stat().st_size > 10_000
    assert main(["validate", str(path), "--fit", str(fit), "--t-end", "100", "--json",
                 str(tmp_path / "scores.json"), "--quiet"]) == 0
    scores = json.loads((tmp_path / "scores.json").read_text())["records"][0]["nrmse"]
    (plotted,) = drawn
    assert plotted == pytest.approx(scores, rel=1e-9), (plotted, scores)
    saved = Fit.from_json(fit)
    from_rest = compare([load_record(path)], MODEL, saved.params, t_end=None).rows[0].nrmse
    assert from_rest["joint_angle"] > 2 * plotted["joint_angle"], (from_rest, plotted)


STEADY = TRUTH | {"alpha": 3.0, "beta": 1.5e-4}  # damped enough to reach steady state in 3 s
STEADY_CUT = 3100  # in the thirteenth period, where the joint slides


@pytest.fixture(scope="module")
def steady():
    """A piecewise-constant input of period 0.25 s, run from rest for 3.1 s (the transient
    decayed to below 1e-3), logged from there over two periods."""
    levels = np.random.default_rng(1).standard_normal(10)
    period = np.repeat(0.35 * (levels - levels.mean()) / np.max(np.abs(levels)), 25)
    torque = np.tile(period, 15)[: STEADY_CUT + 500]
    outputs, state = logged_mid_run(MODEL, STEADY, torque, DT, STEADY_CUT)
    return torque[STEADY_CUT:], outputs, state


@pytest.mark.slow  # about 1 min on the 2-core machine: a 3.6 s Radau run, the periodic solve
def test_the_periodic_state_at_the_truth_is_the_reference_steady_state(steady):
    torque, outputs, (_, velocity, modal, modal_velocity) = steady
    record = _record("steady", outputs, torque, seed=None)
    assert input_period(record) == 250
    z = record_states(MODEL, STEADY, [record], None, "periodic")["steady"]
    assert z[0] == pytest.approx(outputs[0][0], abs=2e-3)  # the angle, by least squares
    assert z[1] == pytest.approx(velocity, rel=0.01)
    np.testing.assert_allclose(z[2:4], modal[:2], rtol=0.03)
    np.testing.assert_allclose(z[4:6], modal_velocity[:2], rtol=0.03)


@pytest.mark.slow  # about 1 min on the 2-core machine: DE 10 x 16 and refinement
def test_parameters_and_state_of_a_record_in_periodic_steady_state_are_recovered(steady):
    """Seeded near the truth (unseeded, this budget stops with alpha and beta on their
    bounds); E is biased by the simulator against Radau by 0.04 %, as from rest."""
    torque, outputs, state = steady
    record = _record("steady", outputs, torque, seed=2)
    start = {k: v * f for (k, v), f in zip(STEADY.items(), (1.04, 0.96, 1.2, 0.97, 1.1, 0.9),
                                           strict=True)}
    fit = identify([record], MODEL, initial_state="periodic", generations=10, population=16,
                   init_population=start)
    for name in fit.names:
        lo, hi = fit.intervals[name]
        if name == "E":
            assert fit.params[name] == pytest.approx(STEADY[name], rel=1e-3)
            continue
        assert lo <= STEADY[name] <= hi, (name, fit.params[name], lo, hi)
    found = fit.initial_state_intervals["steady"]
    # the angle within half an encoder step (the record's quantisation)
    assert fit.initial_states["steady"]["angle"] == pytest.approx(state[0], abs=ENCODER_STEP / 2)
    for name, truth in (("velocity", state[1]), ("modal_1", state[2][0]),
                        ("modal_2", state[2][1]), ("modal_velocity_1", state[3][0]),
                        ("modal_velocity_2", state[3][1])):
        assert found[name][0] <= truth <= found[name][1], (name, truth, found[name])


def test_a_fit_file_keeps_the_initial_states(tmp_path):
    """Written and read back, and a file of before the initial states loads at rest."""
    path = tmp_path / "fit.json"
    data = _small_fit_dict()
    path.write_text(json.dumps(data))
    old = Fit.from_json(path)
    assert old.initial_state == "rest" and old.initial_states == {}
    data |= {"initial_state": "estimate", "initial_states": {"mid": {"angle": 0.1}},
             "initial_state_intervals": {"mid": {"angle": [0.09, 0.11]}}}
    new = Fit.from_dict(data)
    assert new.initial_states == {"mid": {"angle": 0.1}}
    assert new.initial_state_intervals == {"mid": {"angle": (0.09, 0.11)}}
    assert Fit.from_dict(json.loads(json.dumps(new.to_dict()))).initial_states == (
        new.initial_states)


def _small_fit_dict() -> dict:
    """The contents of a fit file as written before initial states existed."""
    fit = identify(make_records(inputs=["pulse"], duration=0.3, seed=0), MODEL,
                   generations=1, population=4, refine=False, intervals=False)
    data = fit.to_dict()
    for key in ("initial_state", "initial_states", "initial_state_intervals"):
        data.pop(key)
    return data



@pytest.mark.slow  # a base refit with every record's state profiled out, and the score tests
def test_discover_on_a_record_logged_mid_run_finds_nothing_missing_from_its_own_start(mid_run):
    """The clean model on a record that starts moving: from rest the base fit cannot follow
    the start and the misfit looks like a missing effect; with its state estimated it fits to
    the noise and nothing is added."""
    from jaxflex.discovery import discover

    torque, outputs, _ = mid_run
    record = _record("mid", outputs, torque, seed=4)
    moving = discover([record], initial=TRUTH, initial_state="estimate", initial_modes=3,
                      max_steps=1, candidates=["payload", "stribeck", "torque_offset"])
    assert moving.added == () and moving.unexplained is None
    assert moving.settings["initial_state"] == "estimate"
    final = moving.steps[-1].nrmse
    assert final["tip_acceleration"] < 1.3 * moving.noise_floor["tip_acceleration"]
    still = discover([record], initial=TRUTH, max_steps=0)
    assert still.steps[-1].nrmse["joint_angle"] > 10 * final["joint_angle"]
