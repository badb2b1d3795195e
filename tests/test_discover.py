"""Discovery: score tests, add-and-refit and the loop on synthetic records with hidden effects.

Every scenario simulates "measured" records with the spec's noise from base parameters away from
the reference values plus hidden effects, and starts the loop near (not at) the true base
parameters, skipping the evolutionary search; one slow test starts from scratch. All tests share
one candidate set and record layout, so the compiled Jacobian is reused across them.
"""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path
from typing import ClassVar

import jax.numpy as jnp
import numpy as np
import pytest
import scipy.stats as st
from discovery_cases import NOISE, START, TRUTH, check_claims, hidden, one, rotflex_report

from jaxflex._progress import ENVIRONMENT_SWITCH
from jaxflex.cli import main
from jaxflex.data import save_record
from jaxflex.diagnosis import NoiseLevel
from jaxflex.discovery import (
    Candidate,
    DiscoveryFit,
    add_effect,
    candidate_set,
    discover,
    refit,
    score_tests,
)
from jaxflex.discovery._engine import Engine
from jaxflex.discovery._universe import Slot
from jaxflex.discovery.loop import _initial_params, _rigid
from jaxflex.discovery.scores import score_statistic
from jaxflex.effects import AbstractEffect, Stribeck, get_effect
from jaxflex.evolve import get_strategy
from jaxflex.metrics import nrmse
from jaxflex.model import Model
from jaxflex.parameters import ParameterSpec
from jaxflex.sensors import Encoder, StrainGauge
from jaxflex.simulation import simulate
from jaxflex.synthetic import ACCELEROMETER_SIGMA, make_records

MODERATE = {"payload": 0.025, "delay": 0.004, "motor_lag": 0.006, "gravity": 0.06,
            "root_compliance": 0.02, "stribeck": 0.04}


class QuadraticDamping(AbstractEffect):
    """Air drag on the link: a joint torque ``c_q θ'|θ'|`` — not in the library."""

    name: ClassVar[str] = "quadratic_damping"
    parameters: ClassVar[tuple[ParameterSpec, ...]] = (
        ParameterSpec("c_q", "N m s^2", 1e-4, 0.1, 0.01, "drag coefficient", null=0.0),
    )

    def friction(self, params, velocity, omega_s):
        return params["c_q"] * velocity * jnp.abs(velocity)


class StickyPatch(AbstractEffect):
    """A second friction regime: extra Coulomb friction beyond 45° (a worn bearing race)."""

    name: ClassVar[str] = "sticky_patch"
    parameters: ClassVar[tuple[ParameterSpec, ...]] = (
        ParameterSpec("tau_p", "N m", 1e-3, 0.1, 0.03, "extra friction beyond 45 deg", null=0.0),
    )

    def loads(self, structure, params):
        return jnp.zeros((1, structure.mass.shape[0])).at[0, 0].set(1.0)

    def load_amplitudes(self, params, angle, velocity):
        inside = 0.5 * (1.0 + jnp.tanh((angle - math.radians(45.0)) / 0.02))
        return (-params["tau_p"] * inside * jnp.tanh(velocity / 0.01))[None]


def noise_floor(records, model, params) -> dict[str, float]:
    """NRMSE (%) of the true model: what the noise alone leaves, mean over the records."""
    out = [simulate(model, params, r.torque) for r in records]
    return {c: float(np.mean([nrmse(r.channel(c), np.asarray(o.channel(c)))
                              for r, o in zip(records, out, strict=True)]))
            for c in ("joint_angle", "tip_acceleration")}


def assert_at_noise_floor(report, floor, factor=1.3):
    for channel, value in report.final.nrmse.items():
        assert value <= factor * floor[channel], (channel, value, floor[channel], report.table())


# --- the statistics ------------------------------------------------------------------------------


def _slot(spec):
    return Slot(0, 0, get_effect("payload"), (spec.name,), (spec.name,))


@pytest.mark.parametrize("z", [0.5, 1.7, 3.2])
def test_one_sided_score_is_the_chi_bar_square_mixture(z):
    spec = get_effect("payload").parameters[0]
    cand = Candidate("payload", (get_effect("payload"),))
    g, v = np.array([z * 2.0]), np.array([[4.0]])  # z = g/√V
    res = score_statistic(cand, _slot(spec), [spec], g, v)
    assert res.one_sided and res.statistic == pytest.approx(z**2)
    assert res.p_value == pytest.approx(st.norm.sf(z), rel=1e-9)
    assert res.estimate["m_p"] == pytest.approx(z * 2.0 / 4.0)
    wrong_way = score_statistic(cand, _slot(spec), [spec], -g, v)
    assert wrong_way.statistic == 0.0 and wrong_way.p_value == 1.0


def test_two_sided_score_for_an_interior_null():
    spec = ParameterSpec("k", "1", 0.5, 1.5, 1.0, null=1.0, log_scale=False)
    cand = Candidate("gain", (get_effect("payload"),))
    g, v = np.array([3.0]), np.array([[2.0]])
    res = score_statistic(cand, _slot(spec), [spec], g, v)
    assert not res.one_sided and res.statistic == pytest.approx(4.5)
    assert res.p_value == pytest.approx(st.chi2.sf(4.5, 1), rel=1e-9)


def test_candidates_by_name_profile_stribeck_and_validate():
    cands = candidate_set()
    physical = {"payload", "delay", "motor_lag", "gravity", "root_compliance", "stribeck",
                "torque_offset"}
    # no sensor offset unless named (records are re-zeroed at rest), no gain on the encoder
    assert {c.name for c in cands} == physical | {
        f"sensor_gain:{c}" for c in ("tip_acceleration", "root_strain")
    }
    fitted = {c.name for c in candidate_set(None, ["joint_angle", "root_strain"])}
    assert fitted == physical | {"sensor_gain:root_strain"}
    # a rig's encoder is known by its sensor, whatever its channel; other sensors keep a gain
    rig = Model(sensors=(Encoder(channel="angle"), StrainGauge(channel="joint_angle")))
    fitted = {c.name for c in candidate_set(None, ["angle", "joint_angle"], rig)}
    assert fitted == physical | {"sensor_gain:joint_angle"}
    named = candidate_set(["sensor_gain:joint_angle"], ["joint_angle"])  # named: tested
    assert [c.name for c in named] == ["sensor_gain:joint_angle"]
    stribeck = next(c for c in cands if c.name == "stribeck")
    assert len(stribeck.effects) == len(Stribeck.grid())
    assert stribeck.label(0) == f"v_s started at {Stribeck.grid()[0].v_s:g}"
    assert len(candidate_set([Stribeck(v_s=0.2)])[0].effects) == 1
    with pytest.raises(ValueError, match="unknown effect 'paylod'"):
        candidate_set(["paylod"])
    with pytest.raises(ValueError, match="appears twice"):
        candidate_set(["delay", "delay"])

    class NoNull(AbstractEffect):
        name: ClassVar[str] = "no_null"
        parameters: ClassVar[tuple[ParameterSpec, ...]] = (
            ParameterSpec("k", "1", 0.1, 1.0, 0.5),)

    with pytest.raises(ValueError, match="no null value"):
        candidate_set([NoNull()])


@pytest.fixture(scope="module")
def payload_case():
    return one("payload", 0.03)


def test_score_statistic_is_the_gauss_newton_cost_drop(payload_case):
    """S equals ‖P_[Jn Jc] r‖² − ‖P_Jn r‖² (independent least squares), and the candidate
    columns match finite differences of the simulation."""
    records, _, _ = payload_case
    cands = candidate_set(["payload", "gravity", "root_compliance"])
    engine = Engine.build(Model(), cands, records, START, NOISE)
    u = engine.universe
    x = u.vector(START)
    base = list(range(u.n_base))
    slots = [s for s in u.slots if u.candidates[s.candidate].name in ("payload", "gravity",
                                                                        "root_compliance")]
    assert len(slots) == 3
    cols = [int(u.index(s.names)[0]) for s in slots]
    pred, jac = engine.evaluate(x, np.zeros(x.size, bool), base + cols)
    _, r = engine.whitened(pred)
    jn = jac[:, : len(base)] / np.linalg.norm(jac[:, : len(base)], axis=0)

    def explained(a):
        coef, *_ = np.linalg.lstsq(a, r, rcond=None)
        return float(np.sum((a @ coef) ** 2))

    results = {t.effect: t for t in engine.score_tests(x, (), 0.01)}
    assert set(results) == {"payload", "gravity", "root_compliance"}
    for k, slot in enumerate(slots):
        jc = jac[:, len(base) + k][:, None]
        drop = explained(np.hstack([jn, jc / np.linalg.norm(jc)])) - explained(jn)
        res = results[u.candidates[slot.candidate].name]
        assert res.statistic == pytest.approx(drop if res.z > 0 else 0.0, rel=1e-6, abs=1e-6)
        step = 1e-6 * u.space[slot.names[0]].upper  # one-sided: the null is a bound
        xp = x.copy()
        xp[cols[k]] = step
        fd = (engine.evaluate(xp, np.zeros(x.size, bool), [])[0] - pred) / step
        column = jac[:, len(base) + k]
        assert np.linalg.norm(fd - column) < 1e-3 * np.linalg.norm(column)


def test_profiles_side_by_side_reach_the_payload_each_as_it_would_alone(payload_case):
    """The profiles of several candidates (every member of the Stribeck grid too) taken side by
    side, one batched simulation per level, are each the very bytes of the profile taken alone;
    the hidden payload's reaches its mass to first order (the base parameters 3 % off) and the
    lowest cost by far."""
    records, _, _ = payload_case
    engine = Engine.build(Model(), candidate_set(["payload", "gravity", "stribeck"]), records,
                          START, NOISE)
    u = engine.universe
    x = u.vector(START)
    names = [u.candidates[s.candidate].name for s in u.slots]
    slots = [i for i, n in enumerate(names) if n in ("payload", "gravity", "stribeck")]
    assert len(slots) == 2 + len(Stribeck.grid())
    requests = [(x, (), i, {}) for i in slots]
    together = engine.profile_starts(requests)
    for request, (start, cost) in zip(requests, together, strict=True):
        ((alone, alone_cost),) = engine.profile_starts([request])
        assert alone.tobytes() == start.tobytes() and alone_cost == cost
    costs = {names[i]: cost for i, (_, cost) in zip(slots, together, strict=True)}
    assert min(costs, key=costs.get) == "payload"
    payload = names.index("payload")
    start, cost = together[slots.index(payload)]
    assert u.params(start, [payload])["m_p"] == pytest.approx(0.03, rel=0.15)
    assert cost < 0.1 * engine.forward_cost(x)


@pytest.mark.parametrize("name", [
    n if n in ("payload", "delay", "stribeck") else pytest.param(n, marks=pytest.mark.slow)
    for n in sorted(MODERATE)
])
def test_hidden_effect_scores_among_the_contenders(name):
    """At a fit of the base model the hidden effect is significant and among the candidates the
    loop refits; usually it scores highest.

    The fitted base parameters partly compensate the missing effect (a softer root shows as a
    smaller E), so a related candidate may score alike; and a delay and a first-order lag have
    the same derivative at their null (a small lag is a small delay), so their scores tie. The
    refits of the loop tell them apart (slow tests)."""
    records, _, _ = one(name, MODERATE[name], seed=3)
    base = refit(records, Model(), START, noise=NOISE)
    ranking = score_tests(records, base.model, base.params, noise=NOISE)
    contenders = [r.effect for r in ranking if r.significant][:3]
    assert name in contenders, [(r.effect, r.statistic) for r in ranking]
    hit = next(r for r in ranking if r.effect == name)
    assert hit.p_value < 1e-6
    assert hit.estimate[get_effect(name).parameters[0].name] > 0
    if name in ("delay", "motor_lag"):
        assert {r.effect for r in ranking[:2]} == {"delay", "motor_lag"}
        assert ranking[0].statistic == pytest.approx(ranking[1].statistic, rel=1e-9)


def test_clean_records_have_no_significant_candidate():
    records, _, _ = hidden({}, seed=4)
    ranking = score_tests(records, Model(), TRUTH, noise=NOISE)
    assert not any(r.significant for r in ranking), [(r.effect, r.p_value) for r in ranking]
    assert {r.effect for r in ranking} == {
        c.name for c in candidate_set(None, ["joint_angle", "tip_acceleration"])
    }


def test_given_noise_levels_are_used_and_the_rest_estimated(payload_case):
    records, _, _ = payload_case
    fit = refit(records, Model(), START, noise={"joint_angle": 1e-3})
    assert fit.noise["joint_angle"] == NoiseLevel(1e-3) and fit.noise["joint_angle"].describe() == (
        "given")
    assert fit.noise["tip_acceleration"].source == "estimated"
    assert fit.noise["tip_acceleration"].sigma == pytest.approx(ACCELEROMETER_SIGMA, rel=0.1)
    with pytest.raises(ValueError, match=r"^noise given for unknown channel 'torque'"):
        refit(records, Model(), START, noise={"torque": 1.0})


def test_add_effect_recovers_the_payload(payload_case):
    records, _, _ = payload_case
    base = DiscoveryFit(Model(), dict(START), math.nan, 6, 0, NOISE)
    fit = add_effect(records, base, "payload")
    assert fit.effects == ("payload",)
    assert fit.params["m_p"] == pytest.approx(0.03, rel=0.03)
    assert fit.params["E"] == pytest.approx(TRUTH["E"], rel=0.02)
    with pytest.raises(ValueError, match="already in the model"):
        add_effect(records, fit, "payload")


# --- the loop ------------------------------------------------------------------------------------


def test_discover_adds_the_hidden_payload(payload_case):
    records, model, params = payload_case
    holdout, _, _ = one("payload", 0.03, seed=9, inputs=("pulse",), amplitudes={"pulse": 0.2})
    report = discover(records, holdout=holdout, initial=START)
    assert report.added == ("payload",)
    assert [s.label for s in report.steps][0] == "rigid"
    assert report.final.fit.params["m_p"] == pytest.approx(0.03, rel=0.03)
    assert report.unexplained is None
    assert_at_noise_floor(report, noise_floor(records, model, params))
    base, final = report.base, report.final
    assert final.bic < base.bic and final.holdout["relative_error"]["tip_acceleration"] < 0.05
    assert base.ranking[0].effect == "payload" and "m_p = 30 g" in base.ranking[0].explanation
    assert base.ranking[0].status == "explains" and "explains" in base.ranking[0].explanation
    shift = base.ranking[0].evidence["resonance"]  # cited only beyond the frequency resolution
    assert ("Hz too high" in base.ranking[0].explanation) == (
        shift["shift_hz"] > shift["resolution_hz"]), base.ranking[0].explanation

    data = check_claims(report)  # every sentence against its own statistics
    assert [s["added"] for s in data["steps"]] == [None, None, "payload"]
    for step in data["steps"]:
        assert set(step) >= {"added", "effects", "params", "nrmse", "frf_nrmse", "holdout", "bic"}
        assert set(step["nrmse"]) == {"joint_angle", "tip_acceleration"}
    assert data["steps"][2]["effects"] == ["payload"]
    assert data["ranking"][0][0]["effect"] == "payload"
    for e in data["ranking"][0][1:]:  # refitted, not added: say why, never "explains"
        if e["evidence"]["refit"] is not None:
            assert e["status"] in ("lower", "not_confirmed") and "not added" in e["explanation"]
    assert set(data["ranking"][0][0]) >= {"effect", "statistic", "p_value"}
    assert data["unexplained"] is None
    assert "payload" in report.table()


def test_cli_discover_prints_the_final_model_with_its_intervals(payload_case, tmp_path,
                                                                 capsys):
    """The final model as `identify` prints a fit: each parameter, its 95 % interval and unit,
    the same numbers as the JSON; every step's ranking in the JSON, named by its step."""
    records, _, _ = payload_case
    files, initial = saved_case(records, tmp_path)
    out = tmp_path / "out.json"
    assert main(["discover", *files, "--initial", str(initial), "--candidates", "payload",
                 "--max-steps", "1", "--json", str(out), "--quiet"]) == 0
    said = capsys.readouterr().out
    data = json.loads(out.read_text())
    final = data["steps"][-1]
    assert final["structure"] == "base + payload"
    assert "final model: base + payload (−2 log L = " in said
    assert "\nparameter         value                 95 % interval       ±%  unit\n" in said
    value, (lo, hi) = final["params"]["m_p"], final["intervals"]["m_p"]
    assert lo < value < hi and value == pytest.approx(0.03, rel=0.05)
    assert f"m_p        {value:>12.6g} [{lo:>12.6g}, {hi:>12.6g}]" in said
    line = next(ln for ln in said.splitlines() if ln.startswith("m_p "))
    assert line.split()[-1] == "kg"
    assert set(final["intervals"]) == set(final["params"])  # none fixed: every one fitted
    assert "noise level tip_acceleration: σ = " in said and " m/s^2 (" in said
    # one ranking per step that tested candidates, each entry naming its step
    assert [{e["after"] for e in r} for r in data["ranking"]] == [{"base"}]
    assert data["withdrawn_steps"] == []


def test_discover_validates_its_arguments(payload_case):
    records, _, _ = payload_case
    with pytest.raises(ValueError, match="max_steps"):
        discover(records, initial=START, max_steps=-1)
    with pytest.raises(ValueError, match="alpha"):
        discover(records, initial=START, alpha=1.5)
    with pytest.raises(ValueError, match="missing"):
        discover(records, initial={"E": 5e10})
    with pytest.raises(ValueError, match="unknown effect"):
        discover(records, initial=START, candidates=["gravityy"])
    name = records[0].name
    with pytest.raises(ValueError, match=f"record '{name}' has no 'root_strain' column to fit"):
        discover(records, initial=START, channels=("joint_angle", "root_strain"))
    with pytest.raises(ValueError, match="channel 'deflection_angle' is not a simulated output"):
        discover(records, initial=START, channels=("deflection_angle",))


def saved_case(records, tmp_path) -> tuple[list[str], Path]:
    """The records written as CSV files and the start parameters as a JSON file, for the CLI."""
    files = []
    for r in records:
        files.append(str(tmp_path / f"{r.name}.csv"))
        save_record(r, files[-1])
    initial = tmp_path / "start.json"
    initial.write_text(json.dumps(START))
    return files, initial


def test_cli_discover_writes_the_json_contract(payload_case, tmp_path, capsys, monkeypatch):
    records, _, _ = payload_case
    monkeypatch.setenv(ENVIRONMENT_SWITCH, "1")  # a bar, though stderr is not a terminal
    files, initial = saved_case(records, tmp_path)
    out = tmp_path / "out.json"
    code = main(["discover", *files, "--initial", str(initial), "--candidates",
                 "payload,delay,gravity", "--max-steps", "0", "--json", str(out),
                 "--report", str(tmp_path / "report")])
    assert code == 0
    from jaxflex.plots.discover import report_paths

    written = report_paths([r.name for r in records], tmp_path / "report")
    assert all(p.stat().st_size > 0 for p in written)
    assert (tmp_path / "report" / "error_falling.png").stat().st_size > 10_000
    data = json.loads(out.read_text())  # max-steps 0: the rigid and the base model only
    assert [s["structure"] for s in data["steps"]] == ["rigid", "base"]
    assert data["ranking"] == [] and data["unexplained"]["frequency_hz"]
    assert data["settings"]["max_steps"] == 0
    said = capsys.readouterr()
    assert "UNEXPLAINED" in said.out
    assert "\rdiscover: 100%|" in said.err and "| 1/1 [" in said.err
    assert main(["discover", *files, "--candidates", "nope"]) == 2
    assert "unknown effect 'nope'" in capsys.readouterr().err
    assert main(["discover", *files, "--initial", str(initial), "--json", str(out)]) == 2
    assert "exists" in capsys.readouterr().err
    assert main(["discover", *files, "--initial", str(tmp_path / "none.json")]) == 2
    assert "fit file not found" in capsys.readouterr().err


# --- identify's fitting options: bounds, fixed values, channel weights -------------------------


HELD = {"beta": 9e-5}  # the truth, not START's value: a held parameter keeps the given one
BOX = (0.004, 0.006)  # J_h: the truth and the start lie above, so the fit ends on the box


@pytest.mark.slow  # the CLI test of the fitting options runs in the fast suite
def test_discover_holds_fixed_parameters_and_respects_bounds(payload_case):
    records, _, _ = payload_case
    report = discover(records, initial=START, fixed=HELD, bounds={"J_h": BOX}, max_steps=0)
    assert len(report.steps) == 2 and report.steps[0].label == "rigid"
    fit = report.final.fit
    assert fit.params["beta"] == HELD["beta"] and fit.n_params == 5
    assert BOX[0] <= fit.params["J_h"] <= BOX[1]
    assert fit.params["J_h"] == pytest.approx(BOX[1], rel=1e-6)  # pressed against the box
    settings = report.to_dict()["settings"]
    assert settings["fixed"] == HELD and settings["bounds"]["J_h"] == list(BOX)
    assert "beta" not in settings["bounds"]


@pytest.mark.slow  # a discovery run; the fast set keeps one of its kind
def test_discover_holds_effect_bounds_when_the_effect_is_refitted(payload_case):
    """A given bound holds in the refit and is not widened: the payload's refit ends on it (the
    truth, 0.03 kg, lies above), so the bound, not the records, set its mass: not added."""
    records, _, _ = payload_case
    report = discover(records, initial=START, fixed=HELD, bounds={"m_p": (0.01, 0.028)},
                      max_steps=1, candidates=["payload"])
    assert report.added == (), report.table()
    for step in report.steps[1:]:
        assert step.fit.params["beta"] == HELD["beta"]
    payload = report.base.ranking[0]
    refit = payload.evidence["refit"]
    assert refit["params"]["m_p"] == pytest.approx(0.028)
    assert refit["on_bound"] == {"m_p": "upper"} and refit["widened"] == {}
    assert payload.status == "on_bound"
    assert "its refit ends on the upper bound of m_p (28 g): not an explanation" in (
        payload.explanation)


@pytest.mark.parametrize(("keyword", "value", "message"), [
    ("fixed", {"gamma": 1.0}, "fixed names unknown parameter(s) ['gamma']; known parameters: "),
    ("bounds", {"m_q": (0.0, 1.0)}, "bounds names unknown parameter(s) ['m_q']; known "),
    ("bounds", {"J_h": (0.01, 0.001)}, "bounds for J_h: lower bound 0.01 must be below upper "),
    ("fixed", {"m_p": 0.01}, "fixed names effect parameter(s) ['m_p']; discover holds only "),
    ("weights", {"torque": 1.0}, "weights given for channel(s) ['torque'] not fitted"),
])
def test_discover_refuses_bad_fitting_options_in_one_line(payload_case, keyword, value, message):
    records, _, _ = payload_case
    with pytest.raises(ValueError) as info:
        discover(records, initial=START, max_steps=0, **{keyword: value})
    assert str(info.value).startswith(message) and "\n" not in str(info.value)


def test_discover_takes_the_base_search_once_and_as_a_strategy(payload_case):
    records, _, _ = payload_case
    with pytest.raises(ValueError, match="search= or budget=, not both"):
        discover(records, search=get_strategy("de", generations=1, population=4), budget=(1, 4))
    with pytest.raises(TypeError, match="search must be a strategy .* got str"):
        discover(records, search="de")


class _Searched(Exception):
    """Raised by the spy in place of the base model's search."""


@pytest.mark.parametrize(("noise", "weights", "expected"), [
    (NOISE, None, "noise"),  # every channel's level given: the search is noise-weighted
    (NOISE, {"tip_acceleration": 2.0}, "both"),  # ... times the user's weights
    ({"joint_angle": NOISE["joint_angle"]}, {"tip_acceleration": 2.0}, "user"),  # not all given
])
def test_the_base_search_uses_the_given_noise_levels(payload_case, monkeypatch, noise, weights,
                                                     expected):
    import jaxflex.identification
    from jaxflex.objective import noise_weights

    records, _, _ = payload_case
    seen = {}

    def spy(records, model, **kwargs):
        seen.update(kwargs)
        raise _Searched

    monkeypatch.setattr(jaxflex.identification, "identify", spy)
    with pytest.raises(_Searched):
        discover(records, noise=noise, weights=weights, fixed=HELD, budget=(1, 4))
    from_noise = noise_weights(records, NOISE)
    want = {"noise": from_noise, "user": weights,
            "both": {c: w * (weights or {}).get(c, 1.0) for c, w in from_noise.items()}}[expected]
    assert seen["weights"] == pytest.approx(want, rel=1e-12) and seen["fixed"] == HELD


@pytest.mark.slow  # a discovery run; the fast set keeps one of its kind
def test_cli_discover_takes_identify_fitting_options_and_reproduces(payload_case, tmp_path):
    records, _, _ = payload_case
    files, initial = saved_case(records, tmp_path)
    runs = []
    for name in ("a.json", "b.json"):
        assert main(["discover", *files, "--initial", str(initial), "--max-steps", "0",
                     "--fix", "beta=9e-5", "--bound", "J_h=0.004:0.006",
                     "--weight", "tip_acceleration=2", "--json", str(tmp_path / name)]) == 0
        runs.append(json.loads((tmp_path / name).read_text()))
    data = runs[0]
    assert data["settings"]["fixed"] == HELD and data["settings"]["bounds"]["J_h"] == list(BOX)
    assert data["settings"]["weights"] == {"joint_angle": 1.0, "tip_acceleration": 2.0}
    assert data["steps"][-1]["params"]["beta"] == HELD["beta"]
    assert BOX[0] <= data["steps"][-1]["params"]["J_h"] <= BOX[1]
    # timings only under "timing": the same command twice gives the same JSON elsewhere
    assert set(data["timing"]) == {"wall_time_s"} and "wall_time_s" not in data
    assert [{k: v for k, v in r.items() if k != "timing"} for r in runs[1:]] == [
        {k: v for k, v in data.items() if k != "timing"}]


# --- slow: every effect, clean seeds, non-library effects, two effects, from scratch -----------


CASES = [("payload", 0.015), ("payload", 0.05), ("delay", 0.002), ("delay", 0.008),
         ("motor_lag", 0.003), ("motor_lag", 0.01), ("gravity", 0.03), ("gravity", 0.1),
         ("root_compliance", 0.025), ("root_compliance", 0.04), ("root_compliance", 0.08),
         ("stribeck", 0.025),
         ("stribeck", 0.06)]


@pytest.mark.slow
@pytest.mark.parametrize(("name", "value"), CASES)
def test_each_hidden_effect_is_found(name, value):
    records, model, params = one(name, value, seed=hash((name, value)) % 1000)
    report = discover(records, initial=START)
    assert report.added[:1] == (name,), report.table()
    assert report.base.ranking[0].effect == name
    assert report.unexplained is None, report.table()
    assert_at_noise_floor(report, noise_floor(records, model, params))
    key = get_effect(name).parameters[0].name
    assert report.params[key] == pytest.approx(value, rel=0.1)


@pytest.mark.slow
def test_stribeck_with_another_velocity_is_profiled():
    records, model, params = hidden({Stribeck(v_s=0.03): {"delta_tau_s": 0.04}}, seed=12)
    report = discover(records, initial=START)
    assert report.added == ("stribeck",)
    assert report.params["v_s"] == pytest.approx(0.03, rel=0.05)  # fitted from its start
    assert_at_noise_floor(report, noise_floor(records, model, params))


@pytest.mark.slow
def test_clean_records_over_seeds_add_nothing():
    """No effect is added on clean records; score-test false positives stay near alpha."""
    p_values = []
    for seed in range(5):
        records, model, params = hidden({}, seed=100 + seed)
        report = discover(records, initial=START)
        assert report.added == () and report.unexplained is None, report.table()
        assert_at_noise_floor(report, noise_floor(records, model, params))
        p_values += [r.p_value for r in report.base.ranking]
    assert sum(p < 0.01 / 6 for p in p_values) <= 1


@pytest.mark.slow
@pytest.mark.parametrize("effect", [QuadraticDamping(), StickyPatch()], ids=lambda e: e.name)
def test_an_effect_outside_the_library_is_reported_unexplained(effect):
    value = {"quadratic_damping": {"c_q": 0.02}, "sticky_patch": {"tau_p": 0.04}}[effect.name]
    records, model, params = hidden({effect: value}, seed=21)
    report = discover(records, initial=START)
    floor = noise_floor(records, model, params)
    assert report.unexplained is not None, report.table()
    assert report.unexplained["frequency_hz"] or report.unexplained["time_s"]
    assert "no candidate effect explains it" in report.unexplained["message"]
    # any effect it keeps must not be claimed as the explanation: the error stays flagged
    worst = max(report.final.nrmse[c] / floor[c] for c in floor)
    assert worst > 1.3


@pytest.mark.slow
@pytest.mark.parametrize("pair", [("payload", "delay"), ("stribeck", "gravity")])
def test_two_hidden_effects_are_both_found(pair):
    values = {"payload": 0.03, "delay": 0.004, "stribeck": 0.04, "gravity": 0.06}
    effects = {get_effect(n): {get_effect(n).parameters[0].name: values[n]} for n in pair}
    records, model, params = hidden(effects, seed=31)
    report = discover(records, initial=START)
    assert set(report.added) == set(pair), report.table()
    assert report.unexplained is None
    assert_at_noise_floor(report, noise_floor(records, model, params))


@pytest.mark.slow
def test_discover_from_scratch_finds_the_payload():
    records, model, params = one("payload", 0.03, seed=41)
    report = discover(records, seed=0)
    assert report.settings["initial"] == "identified"
    assert report.added == ("payload",)
    assert_at_noise_floor(report, noise_floor(records, model, params))


def test_bundled_example_is_reproducible_and_hides_a_payload():
    import runpy
    from pathlib import Path

    from jaxflex.discovery import load_example

    script = Path(__file__).resolve().parents[1] / "benchmarks" / "make_example_data.py"
    assert runpy.run_path(str(script))["main"](["--check"]) == 0
    fit, held = load_example()
    assert len(fit) == 3 and len(held) == 1
    assert "payload" in fit[0].metadata["answer"]


@pytest.mark.slow
def test_a_rigid_estimate_beyond_a_bound_seeds_the_search_on_it():
    """The warm start of a rigid-body b_v above its bound round-trips through the log map to
    the bound itself (it ended one ulp past it, and identify refused the seed)."""
    records = make_records(inputs=("pulse", "half_sine"), duration=1.0)
    above = dataclasses.replace(_rigid(records, Model(), ("joint_angle", "tip_acceleration")),
                                b_v=0.5, active=())
    params = _initial_params(records, Model(), None,
                             get_strategy("de", generations=2, population=8), 0, False, above,
                             {"bounds": None, "fixed": None, "weights": None, "noise": None,
                              "channels": ("joint_angle", "tip_acceleration"),
                              "initial_state": "rest", "initial_modes": 2})
    assert 1e-5 <= params["b_v"] <= 0.3


@pytest.mark.slow  # DE 10 x 20, one step, 60 s held out
def test_discover_on_the_rotflex_square_wave_names_the_torque_offset():
    """The real ROTFLEX square wave, held out on run 985, through the rig's sensors (encoder and
    root strain gauge in their own units, their quanta as noise model): torque_offset ranks first
    (gravity second), its refit puts tau_0 near -0.007 N m, cuts the fit's angle error at least
    four-fold and the held-out angle's drift more than six-fold."""
    report = rotflex_report()
    assert report.channels == ("joint_angle", "deflection_angle")
    assert report.added == ("torque_offset",)
    assert [r.effect for r in report.rankings[0][:2]] == ["torque_offset", "gravity"]
    base, offset = report.steps
    assert -0.0085 < offset.fit.params["tau_0"] < -0.0055
    assert offset.nrmse["joint_angle"] < 0.25 * base.nrmse["joint_angle"]
    assert offset.nrmse["deflection_angle"] < 0.9 * base.nrmse["deflection_angle"]
    held_base, held = (s.holdout["relative_error"]["joint_angle"] for s in report.steps)
    assert held < 0.15 * held_base


def test_discover_on_a_rig_whose_channels_are_its_own():
    """An accelerometer ``acc_mid`` part-way along and a tip laser: every rung, the rigid one
    first, is scored on the rig's own channels (a rigid link reads ``x·θ''`` and no
    deflection), and the flexible model follows all three."""
    from jaxflex.data import Dataset
    from jaxflex.measured import logged_record
    from jaxflex.sensors import Accelerometer, DeflectionSensor
    from jaxflex.signals import reference_input
    from jaxflex.testbed import Testbed

    rig = Model(Testbed(length=0.42, width=0.02, thickness=0.0025, n_elements=2, duration=0.5),
                sensors=(Encoder(channel="joint_angle", counts_per_revolution=2048),
                         Accelerometer(channel="acc_mid", x=0.25, noise=0.05),
                         DeflectionSensor(channel="laser", x=0.42, noise=2e-5)), name="bench")
    truth = rig.space.reference()
    torque = np.concatenate([np.zeros(100), reference_input("triangular", duration=0.4)[1]])
    time = 1e-3 * np.arange(torque.size)
    records = Dataset([logged_record(rig, truth, time, torque, seed=0, name="triangular")])
    result = discover(records, model=rig, initial={k: 1.05 * float(v) for k, v in truth.items()},
                      candidates=["payload"], max_steps=0)
    rigid, base = result.steps
    assert rigid.label == "rigid" and set(rigid.nrmse) == {"joint_angle", "acc_mid", "laser"}
    assert rigid.nrmse["laser"] == pytest.approx(100.0) and rigid.nrmse["acc_mid"] < 50.0
    assert all(v < 5.0 for v in base.nrmse.values()), base.nrmse
