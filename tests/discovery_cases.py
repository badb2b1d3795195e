"""Synthetic discovery scenarios shared by the discovery tests: records of an arm whose base
parameters lie away from the reference values, with hidden effects and the spec's noise, and
where the loop starts (near, not at, the true base parameters); and the check of every claim a
report makes against the statistics it gives for it (:func:`check_claims`)."""

from __future__ import annotations

import functools
import json
import re

from helpers import ARMS, REAL_DATA_DIR, or_skip

from jaxflex.diagnosis import NoiseLevel
from jaxflex.discovery import RULES
from jaxflex.discovery.explain import LOWERS_FREQUENCIES, noise_claim
from jaxflex.effects import get_effect
from jaxflex.model import Model
from jaxflex.plots.diagnose import _label, plot_diagnosis
from jaxflex.synthetic import ACCELEROMETER_SIGMA, ENCODER_STEP, make_records

#: Base parameters of the "real" arm: every one away from the paper's value.
TRUTH = {"E": 5.2e10, "J_h": 0.0062, "b_v": 1.2e-3, "tau_c": 0.09, "alpha": 1.3, "beta": 9e-5}
#: Where the loop starts: 3 % off the truth (a fit of the base model would be near there).
START = {k: v * (1.03 if i % 2 else 0.97) for i, (k, v) in enumerate(TRUTH.items())}
NOISE = {"joint_angle": NoiseLevel.quantised(ENCODER_STEP),
         "tip_acceleration": NoiseLevel(ACCELEROMETER_SIGMA)}


def hidden(effects: dict, seed: int = 0, inputs=("triangular", "pulse", "half_sine"),
           amplitudes=None):
    """Noisy records of the truth with ``effects`` (effect or name → {param: value}), the true
    model and parameters."""
    instances = [get_effect(e) if isinstance(e, str) else e for e in effects]
    model = Model().with_effects(*instances)
    # a shape parameter (a Stribeck velocity) where the effect instance puts it
    params = {**{s.name: s.reference for s in model.space.specs if s.null is None}, **TRUTH}
    for values in effects.values():
        params.update(values)
    records = make_records(model, params, inputs=inputs, seed=seed, amplitudes=amplitudes)
    return records, model, params


def one(name: str, value: float, **kwargs):
    """:func:`hidden` with one library effect, its first parameter at ``value``."""
    effect = get_effect(name)
    return hidden({effect: {effect.parameters[0].name: value}}, **kwargs)


@functools.cache
def rotflex_report():
    """``discover`` on the real ROTFLEX square wave, held out on run 985, through the rig's
    sensors (DE 10 × 20, one step); computed once per process (the test skips without data)."""
    from jaxflex import datasets
    from jaxflex.arm import load_arm
    from jaxflex.discovery import discover
    from jaxflex.measured import fit_noise, model_record

    runs = or_skip(datasets.load, "quanser_rotflex", REAL_DATA_DIR)
    arm = load_arm(ARMS / "quanser_rotflex.toml")
    square = runs["square_wave"]
    return discover(
        [model_record(arm, square)], holdout=[model_record(arm, runs["random_985"])],
        model=arm, noise=fit_noise(arm, square), t_end=None, budget=(10, 20), max_steps=1,
        seed=0,
    )


LAG_EFFECTS = {"delay", "motor_lag"}


def _key(entry):
    """The stated ranking criterion, recomputed from the JSON."""
    refit = entry["evidence"]["refit"]
    if refit is not None and refit["confirmed"]:
        return (0, -refit["lr"], 0.0)
    return (1, entry["p_value"], -(entry["statistic"] - entry["dof"]))


def check_claims(report):
    """Every sentence of ``report`` against the statistics it is derived from."""
    data = json.loads(json.dumps(report.to_dict()))
    assert set(data["claim_rules"]) == set(RULES)
    steps = data["steps"]
    ranked = [s for s in (*report.steps, *report.withdrawn_steps) if s.ranking]
    kept = set(report.added)
    table = report.table()
    for step, entries in zip(ranked, data["ranking"], strict=True):
        every = [*report.steps, *report.withdrawn_steps]
        i = every.index(step)
        added_next = every[i + 1].added if i + 1 < len(every) else None
        added_next = None if added_next in report.withdrawn else added_next
        assert {e["after"] for e in entries} == {step.structure}
        # the ranking: monotone in the stated criterion, printed in that order
        keys = [_key(e) for e in entries]
        assert keys == sorted(keys), [(e["effect"], k) for e, k in zip(entries, keys, strict=True)]
        assert [e["rank"] for e in entries] == list(range(1, len(entries) + 1))
        line = next(x for x in table.splitlines() if x.startswith(f"after '{step.structure}',"))
        assert "ranked by refit LR among the confirmed, then by score p-value" in line
        printed = re.findall(r"([\w:]+) \((?:LR|p)=", line)
        assert printed == [e["effect"] for e in entries[:3]], line
        for e in entries:
            ev, status, text = e["evidence"], e["status"], e["explanation"]
            rules = [c["rule"] for c in e["claims"]]
            assert set(rules) <= set(RULES) and rules[0] == status
            assert all(c["text"] in text for c in e["claims"])
            # only an effect added and kept explains
            assert ("explain" in text) == (status == "explains"), text
            if status == "explains":
                assert e["effect"] == added_next and e["effect"] in kept
                assert ev["refit"]["confirmed"] and e["rank"] == 1
            else:
                assert e["effect"] != added_next
            if status == "withdrawn":
                assert e["effect"] in report.withdrawn and ev["refit"]["confirmed"]
            if status == "lower":
                assert ev["refit"]["confirmed"] and ev["refit"]["lr"] <= -keys[0][1]
            if status == "not_confirmed":
                r = ev["refit"]
                assert not r["confirmed"]
                assert r["p_value"] >= r["level"] or r["delta_bic"] >= 0 or r["at_null"]
            if status == "on_bound":
                r = ev["refit"]
                assert not r["confirmed"] and r["on_bound"] and not r["at_null"]
                assert "not an explanation" in text
                for name, side in r["on_bound"].items():
                    bound = r["bounds"][name][side == "upper"]
                    assert abs(r["params"][name] - bound) <= 1e-3 * abs(bound) or not r[
                        "bounds"][name][0] > 0
            if status == "not_significant":
                s = ev["score"]
                assert s["p_value"] >= s["level"] and not s["significant"]
            # every refitted candidate states its refit gain, the others the first-order one
            if ev["refit"] is not None and ev["refit"]["lr"] < 0:  # never a negative LR
                assert f"−2 log L rose by {-ev['refit']['lr']:.3g}" in text
                assert "LR = -" not in text and "LR = −" not in text
            elif ev["refit"] is not None:
                assert f"LR = {ev['refit']['lr']:.3g}" in text
            else:
                assert f"S = {ev['score']['S']:.3g}" in text
            # evidence only where it points to the effect
            res = ev["resonance"]
            assert ("resonance" in rules) == bool(res and res["cited"])
            if "resonance" in rules:
                assert abs(res["shift_hz"]) > res["resolution_hz"] > 0
                if e["effect"] in LOWERS_FREQUENCIES:
                    assert res["shift_hz"] > 0 and "too high" in text
            lag = ev["lag"]
            assert ("lag" in rules) == bool(lag and lag["cited"])
            if lag is not None:
                assert e["effect"] in LAG_EFFECTS  # never for a torque offset or a gain
            if "lag" in rules:
                assert lag["lag_s"] > 0 and abs(lag["value"]) > lag["band"]
                assert lag["value"] * lag["rate_value"] < 0
                assert abs(lag["rate_value"]) >= 0.5 * lag["rate_peak"]
            if "ms" in text and "correlat" in text:
                assert "lag" in rules
    # every step's added effect explained somewhere, and nothing else
    explained = {e["effect"] for entries in data["ranking"] for e in entries
                 if e["status"] == "explains"}
    assert explained == {s["added"] for s in steps if s["added"]}
    for line in report.explanations():
        assert "Signature" not in line
    check_titles(report)
    return data


def check_titles(report):
    """A diagnosis figure calls a channel consistent with the noise only when its test says so."""
    for step in (report.base, report.final):
        diag = step.diagnosis
        fig = plot_diagnosis(diag)
        titles = [ax.get_title() for ax in fig.axes]
        for name, channel in diag.channels.items():
            ok, verdict, statistic = noise_claim(channel, diag.alpha)
            assert ok == channel.consistent(diag.alpha)
            label = _label(name)
            lines = statistic.replace("; ", "\n")  # the page puts one test a line
            assert f"{label}: {verdict}\n{lines}" in titles, (verdict, titles)
            if channel.noise.kind == "white":
                assert (verdict == "consistent with noise") == (
                    channel.whiteness.p_value >= diag.alpha
                    and channel.rms_ratio <= 1.3)
            # a rejecting Ljung-Box beside "consistent": only where it is not the channel's test
            acf = next(t for t in titles if t.startswith(f"{label}: whiteness\nLjung-Box"))
            if ok and channel.whiteness.p_value < diag.alpha:
                assert channel.noise.kind == "quantised" and "not its noise test" in acf
