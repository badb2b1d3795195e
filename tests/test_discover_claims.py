"""Discovery reports never claim what their own statistics do not support.

Each scenario runs the loop (synthetic records with a hidden delay, clean records, and the real
ROTFLEX square wave where its data are present) and :func:`discovery_cases.check_claims` checks
every claim of the text, the JSON and the diagnosis figures against the evidence the report
gives for it: only an effect added and kept "explains", rankings follow their stated criterion,
a cited resonance shift exceeds the frequency resolution, a cited lag has the sign a late
torque leaves, and a figure calls a channel consistent with the noise only when its own test
says so. test_discover's hidden-payload run is checked the same way.
"""

from __future__ import annotations

import pytest
from discovery_cases import NOISE, START, check_claims, hidden, one, rotflex_report

from jaxflex.discovery import RULES, discover
from jaxflex.discovery.explain import noise_claim
from jaxflex.effects import get_effect
from jaxflex.plots.diagnose import plot_diagnosis


def _holdout(name, value):
    return one(name, value, seed=9, inputs=("pulse",), amplitudes={"pulse": 0.2})[0]


@pytest.mark.slow  # a discovery run; the fast set checks test_discover's payload run
def test_a_hidden_delay_cites_the_lag_it_leaves():
    records, _, _ = one("delay", 0.008, seed=3)
    report = discover(records, holdout=_holdout("delay", 0.008), initial=START, noise=NOISE,
                      max_steps=2)
    assert report.added[:1] in (("delay",), ("motor_lag",)), report.table()
    data = check_claims(report)
    top = data["ranking"][0][0]
    assert top["status"] == "explains"
    assert any(c["rule"] == "lag" for c in top["claims"]), top["explanation"]
    assert "ms before it (" in top["explanation"] and "as a late response leaves it" in (
        top["explanation"])


def test_clean_records_explain_nothing_and_say_noise():
    records, _, _ = hidden({}, seed=4)
    report = discover(records, initial=START, noise=NOISE, max_steps=2)
    assert report.added == () and report.unexplained is None, report.table()
    check_claims(report)
    assert not any("explains" in line for line in report.explanations())
    for channel in report.final.diagnosis.channels.values():
        ok, verdict, _ = noise_claim(channel, report.final.diagnosis.alpha)
        assert ok and verdict == "consistent with noise"


def test_a_quantised_channel_is_judged_by_its_own_test():
    """An encoder's residual is quantisation error, not white: its title states the quantisation
    test, and its Ljung-Box panel says that it is not the channel's noise test."""
    records, model, params = hidden({}, seed=4)
    from jaxflex.diagnosis import diagnose
    from jaxflex.simulation import simulate

    preds = [simulate(model, params, r.torque) for r in records]
    diag = diagnose(records, preds, noise=NOISE)
    angle = diag.channels["joint_angle"]
    ok, verdict, statistic = noise_claim(angle, diag.alpha)
    assert ok and "steps RMS beyond ±q/2 ≤ 0.25" in statistic and "Ljung" not in statistic
    assert angle.whiteness.p_value < diag.alpha  # what the title must not hide
    titles = [ax.get_title() for ax in plot_diagnosis(diag).axes]
    lines = statistic.replace("; ", "\n")  # the page puts one test a line
    assert f"joint angle: {verdict}\n{lines}" in titles
    assert any(t.startswith("joint angle: whiteness\nLjung-Box")
               and "quantised: not its noise test" in t for t in titles)
    assert not any(t.startswith("tip acceleration: whiteness") and "not its" in t
                   for t in titles)


def test_every_rule_is_listed_in_the_docs_table():
    from pathlib import Path

    docs = (Path(__file__).resolve().parents[1] / "docs" / "effects.md").read_text()
    assert "<!-- generated: claim_rules -->" in docs
    for rule in RULES.values():
        assert rule.when and rule.says and rule.name.isidentifier()
        assert f"| `{rule.name}` |" in docs  # written into the page, as GitHub shows it
    assert get_effect("torque_offset").parameters[0].unit != "s"  # not a lag effect


@pytest.mark.slow  # DE 10 x 20, one step, 60 s held out
def test_rotflex_claims_match_their_statistics():
    report = rotflex_report()
    data = check_claims(report)
    offset = next(e for e in data["ranking"][0] if e["effect"] == "torque_offset")
    assert offset["evidence"]["lag"] is None and "ms" not in offset["explanation"]
