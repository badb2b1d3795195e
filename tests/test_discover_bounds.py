"""Discovery: a fit that ends on a bound explains nothing, and candidates that fit about equally
well are named together with what tells them apart.

The records hide a payload (30 g at the tip of the reference strip, simulated with the spec's
noise as in ``test_discover``). A compliant clamp mimics it in part (both lower the first
resonance); held in a narrow box its refit ends on the box's edge, which the report must call no
explanation. The payload among the candidates is named instead, its mass within 10 %. A base
parameter held in a box that excludes its true value is reported on its bound; two refits whose
likelihood ratios differ by less than the χ²₁ 95 % quantile are named as alternatives.
"""

from __future__ import annotations

import json
from typing import ClassVar

import pytest
from discovery_cases import START, TRUTH, check_claims, one

from jaxflex.discovery import discover
from jaxflex.discovery._confirm import ON_BOUND, on_bound
from jaxflex.discovery.explain import (
    ALTERNATIVE_LR,
    TELLS_APART,
    alternatives,
    annotate,
    collect_evidence,
)
from jaxflex.discovery.report import Confirmation, DiscoveryFit, DiscoveryReport, Step
from jaxflex.discovery.scores import ScoreResult
from jaxflex.effects import RootCompliance, get_effect
from jaxflex.effects.payload import LINK_MASSES
from jaxflex.effects.root_compliance import LINK_COMPLIANCES
from jaxflex.parameters import ParameterSpec
from jaxflex.testbed import Testbed as Strip  # not collected as a test class

PAYLOAD = 0.03  # kg, hidden
NARROW = (3e-3, 0.01)  # rad/(N m): a clamp box too narrow to mimic the payload


@pytest.fixture(scope="module")
def payload_case():
    return one("payload", PAYLOAD)


@pytest.fixture(scope="module")
def clamp_only(payload_case):
    """The payload's records with a compliant clamp the only candidate, its box narrow."""
    records, _, _ = payload_case
    return discover(records, initial=START, candidates=["root_compliance"],
                    bounds={"c_r": NARROW}, max_steps=1)


def _entry(data, effect):
    return next(e for e in data["ranking"][0] if e["effect"] == effect)


def test_a_refit_on_its_bound_is_not_an_explanation(clamp_only):
    """The clamp's refit ends on c_r's upper bound: not added, said in words, marked in the
    JSON; a given bound is the user's and is not widened."""
    report = clamp_only
    data = check_claims(report)
    entry = _entry(data, "root_compliance")
    refit = entry["evidence"]["refit"]
    assert refit["params"]["c_r"] == pytest.approx(NARROW[1], rel=ON_BOUND), report.table()
    assert refit["on_bound"] == {"c_r": "upper"} and refit["widened"] == {}
    assert not refit["confirmed"] and refit["lr"] > 0  # it lowers the misfit, yet explains none
    assert entry["status"] == "on_bound"
    assert ("its refit ends on the upper bound of c_r (0.01 rad/(N m)): not an explanation"
            in entry["explanation"])
    assert report.added == () and report.unexplained is not None
    assert "no candidate effect explains it" in report.unexplained["message"]
    assert not any(e["status"] == "explains" for r in data["ranking"] for e in r)


def test_the_payload_is_named_when_the_clamp_ends_on_its_bound(payload_case):
    records, _, _ = payload_case
    report = discover(records, initial=START, candidates=["root_compliance", "payload"],
                      bounds={"c_r": NARROW}, max_steps=1)
    assert report.added == ("payload",), report.table()
    assert report.params["m_p"] == pytest.approx(PAYLOAD, rel=0.1)
    data = check_claims(report)
    clamp = _entry(data, "root_compliance")
    if clamp["evidence"]["refit"] is not None:  # refitted: refused on its bound
        assert clamp["status"] == "on_bound" and "not an explanation" in clamp["explanation"]
    assert _entry(data, "payload")["status"] == "explains"


class SmallClamp(RootCompliance):
    """A compliant clamp whose search box stops at 0.01 rad/(N m), its physical limit stated
    as a class attribute (``limit``)."""

    limit: ClassVar[float] = 0.05
    parameters: ClassVar[tuple[ParameterSpec, ...]] = (
        RootCompliance.parameters[0].with_bounds(3e-3, 0.01),)

    def physical_limits(self, testbed, params):
        return {"c_r": (0.0, self.limit)}


class StiffLimitClamp(SmallClamp):
    limit: ClassVar[float] = 0.012


CLAMP = 0.02  # rad/(N m): a hidden compliant clamp, beyond SmallClamp's box


@pytest.mark.parametrize("clamp", [SmallClamp(), StiffLimitClamp()],
                         ids=["limit-beyond", "limit-short"])
def test_a_bound_is_widened_once_to_the_physical_limit(clamp):
    """A hidden clamp of 0.02 rad/(N m) beyond the candidate's box (up to 0.01): its bound
    moves out to the effect's physical limit and the clamp is refitted. With the limit beyond
    the truth the clamp is named, within 10 %; with the limit short of it (0.012) the refit
    ends on the limit and is refused, in words naming the limit. The JSON keeps the bound it
    had before."""
    records, _, _ = one("root_compliance", CLAMP)
    report = discover(records, initial=START, candidates=[clamp], max_steps=1)
    data = check_claims(report)
    entry = _entry(data, "root_compliance")
    refit = entry["evidence"]["refit"]
    assert refit["widened"] == {"c_r": [3e-3, 0.01]}, report.table()
    assert refit["bounds"]["c_r"] == [3e-3, clamp.limit]
    if isinstance(clamp, StiffLimitClamp):
        assert refit["on_bound"] == {"c_r": "upper"}
        assert refit["params"]["c_r"] == pytest.approx(clamp.limit, rel=ON_BOUND)
        assert entry["status"] == "on_bound" and report.added == ()
        assert ("its refit ends on the upper bound of c_r (0.012 rad/(N m)), its physical "
                "limit (the bound 0.01 rad/(N m) was moved out to it and the effect refitted): "
                "not an explanation") in entry["explanation"]
    else:
        assert refit["on_bound"] == {} and entry["status"] == "explains"
        assert report.added == ("root_compliance",), report.table()
        assert report.params["c_r"] == pytest.approx(CLAMP, rel=0.1)


def test_the_stated_physical_limits_follow_the_link():
    """The payload's limit is LINK_MASSES link masses; the clamp's LINK_COMPLIANCES times the
    link's bending compliance L/(E I); both lie beyond their default boxes."""
    strip = Strip()
    link = strip.density * strip.width * strip.thickness * strip.length
    payload = get_effect("payload").physical_limits(strip, TRUTH)
    assert payload["m_p"] == pytest.approx((0.0, LINK_MASSES * link))
    clamp = get_effect("root_compliance").physical_limits(strip, TRUTH)
    bending = TRUTH["E"] * strip.width * strip.thickness**3 / 12
    assert clamp["c_r"] == pytest.approx((0.0, LINK_COMPLIANCES * strip.length / bending))
    assert payload["m_p"][1] > 0.2 and clamp["c_r"][1] > 0.4
    assert get_effect("delay").physical_limits(strip, TRUTH) == {"d": (0.0, 0.5)}


def test_a_base_parameter_on_its_bound_is_reported_in_its_step(payload_case):
    """Viscous friction held below its true value (1.2e-3 N m s/rad) ends on the box's upper
    bound: the step says so in the table, the explanations and the JSON."""
    records, _, _ = payload_case
    report = discover(records, initial=START, bounds={"b_v": (1e-5, 5e-4)}, max_steps=0)
    base = report.base
    assert base.fit.params["b_v"] == pytest.approx(5e-4, rel=ON_BOUND)  # the truth: 1.2e-3
    assert base.on_bound["b_v"] == "upper"
    data = json.loads(json.dumps(report.to_dict()))
    step = data["steps"][[s.label for s in report.steps].index(base.label)]
    assert step["on_bound"] == base.on_bound
    for name, side in base.on_bound.items():  # each one named lies on its bound
        bound = data["settings"]["bounds"][name][side == "upper"]
        assert base.fit.params[name] == pytest.approx(bound, rel=ON_BOUND)
    note = ("after 'base': b_v ends on the upper bound of b_v (0.0005 N m s/rad): the bound, "
            "not the records, set it")
    assert note in report.table() and f"{note}." in report.explanations()
    assert data["steps"][0]["on_bound"] == {}  # the rigid-body rung has no bounds


def test_on_bound_tolerance_and_the_null_side():
    spec = ParameterSpec("c_r", "rad/(N m)", 3e-3, 0.4, 0.03, null=0.0)
    offset = ParameterSpec("tau_0", "N m", -0.05, 0.05, 0.0, log_scale=False, null=0.0)
    assert on_bound({"c_r": 0.4 * (1 - 0.5 * ON_BOUND)}, [spec]) == {"c_r": "upper"}
    assert on_bound({"c_r": 0.4 * (1 - 2 * ON_BOUND)}, [spec]) == {}
    assert on_bound({"c_r": 3e-3}, [spec]) == {"c_r": "lower"}
    assert on_bound({"c_r": 3e-3}, [spec], null_side=False) == {}  # where it vanishes
    # a linear, two-sided parameter: within ON_BOUND of its range, either side counts
    assert on_bound({"tau_0": -0.05 + 0.05 * ON_BOUND}, [offset], null_side=False) == {
        "tau_0": "lower"}


# --- alternatives: the rule on constructed refits -----------------------------------------------


def _scored(name: str, lr: float) -> ScoreResult:
    """A candidate refitted and confirmed with likelihood ratio ``lr``."""
    effect = get_effect(name)
    spec = effect.parameters[0]
    result = ScoreResult(effect=name, parameters=(spec.name,), statistic=lr, dof=1,
                         p_value=1e-9, one_sided=True, z=lr**0.5, estimate={spec.name: 0.01},
                         units={spec.name: spec.unit}, significant=True)
    refit = Confirmation(effect=name, lr=lr, p_value=1e-9, delta_bic=-lr + 7.0, explained=0.95,
                         confirmed=True, params={spec.name: 0.01}, level=0.002)
    ev = collect_evidence(result, effect, None, refit, level=0.002)
    return ScoreResult(**{**result.__dict__, "evidence": ev})


def _annotated(ranking, added):
    fit = DiscoveryFit(model=None, params={"J_h": 0.006}, cost=900.0, n_params=1,
                       n_samples=1000, noise={})
    steps = [Step(added=None, fit=fit, nrmse={}, frf_nrmse=1.0, holdout=None, diagnosis=None,
                  ranking=tuple(ranking), label="base"),
             Step(added=added, fit=fit, nrmse={}, frf_nrmse=1.0, holdout=None, diagnosis=None,
                  label=f"base + {added}")]
    return annotate(steps, (), 0.9)


@pytest.mark.parametrize(("second", "named"), [(ALTERNATIVE_LR - 0.1, True),
                                                (ALTERNATIVE_LR + 0.1, False)])
def test_refits_within_the_lr_threshold_are_alternatives(second, named):
    ranking = [_scored("payload", 400.0), _scored("root_compliance", 400.0 - second)]
    steps = _annotated(ranking, "payload")
    close = steps[0].alternatives
    assert bool(close) == named
    first, other = steps[0].ranking
    assert first.status == "explains" and other.status == "lower"
    if not named:
        assert alternatives(ranking) == []
        return
    apart = TELLS_APART[frozenset({"payload", "root_compliance"})]
    assert close[0]["effects"] == ["payload", "root_compliance"]
    assert close[0]["difference"] == pytest.approx(second)
    assert close[0]["tells_apart"] == apart
    assert "accelerometer at the tip" in apart and "slow sweep" in apart
    for r in (first, other):  # both named, with what tells them apart
        assert any(c["rule"] == "alternative" for c in r.claims) and apart in r.explanation
    assert "explain" not in other.explanation  # the alternative explains nothing itself
    report = DiscoveryReport(steps=tuple(steps), unexplained=None, withdrawn=(), alpha=0.01,
                             candidates=("payload", "root_compliance"), records=(),
                             holdout=None, settings={}, wall_time=1.0, noise_floor={})
    data = json.loads(json.dumps(report.to_dict()))
    assert data["steps"][0]["alternatives"][0]["effects"] == ["payload", "root_compliance"]
    assert "alternative" in data["claim_rules"] and "on_bound" in data["claim_rules"]
    assert "after 'base', alternatives: payload and root_compliance fit about equally well" in (
        report.table())


def test_a_pair_outside_the_table_is_told_apart_by_the_hooks():
    ranking = [_scored("gravity", 50.0), _scored("delay", 49.0)]
    text = alternatives(ranking)[0]["tells_apart"]
    assert text.startswith("gravity depends on the angle")
    assert "delay changes the torque's timing" in text


def test_a_sub_sample_delay_names_the_lag_as_its_alternative():
    """A hidden delay of a quarter sample (0.25 ms at 1 kHz): a delay and a first-order lag
    agree to first order in their time constant, and at this size their refits' likelihood
    ratios differ by less than the χ²₁ 95 % quantile. Whichever is added, both are named, with
    what tells them apart, in the table, the explanations and the JSON."""
    records, _, _ = one("delay", 2.5e-4, seed=3)
    report = discover(records, initial=START, candidates=["delay", "motor_lag"], max_steps=1)
    data = check_claims(report)
    assert set(report.added) <= {"delay", "motor_lag"} and len(report.added) == 1
    step = data["steps"][[s.structure for s in report.steps].index("base")]
    (close,) = step["alternatives"]
    lrs = {e["effect"]: e["evidence"]["refit"]["lr"] for e in data["ranking"][0]}
    assert set(close["effects"]) == {"delay", "motor_lag"} and close["effects"][0] == (
        report.added[0])
    assert min(lrs.values()) > 100 and abs(lrs["delay"] - lrs["motor_lag"]) < ALTERNATIVE_LR
    apart = TELLS_APART[frozenset({"delay", "motor_lag"})]
    assert close["tells_apart"] == apart and "chirp" in apart
    for entry in data["ranking"][0]:
        assert apart in entry["explanation"]
    assert f"after 'base', alternatives: {close['text']}" in report.table()
