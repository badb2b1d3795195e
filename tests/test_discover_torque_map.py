"""``discover`` maps the missing torque where the library explains nothing: records integrated by
SciPy Radau on the FEM equations (``reference_solver``) with a hidden cogging torque
``a·sin(kθ)`` that no library effect states, logged as an encoder and an accelerometer would;
the run starts from the true base parameters. The map's formula is refitted, added only when
the held-out record's error falls, and the report's words follow the ``"torque_map"`` rule."""

from __future__ import annotations

import functools
import json
import re

import numpy as np
import pytest
from discovery_cases import check_claims
from reference_solver import radau_states
from test_cli import command_parser

from jaxflex import Model, testbed
from jaxflex.data import Record
from jaxflex.discovery import discover
from jaxflex.discovery.torque_proposal import BOOTSTRAP, claim, formula_of
from jaxflex.missing_torque import estimate_missing_torque
from jaxflex.noise import NoiseLevel
from jaxflex.synthetic import ACCELEROMETER_SIGMA, ENCODER_STEP, quantise_angle
from jaxflex.torque_regression import MAP_RULES, torque_map

DT, N, HOLD = 2e-3, 1000, 2
NOISE = {"joint_angle": NoiseLevel.quantised(ENCODER_STEP),
         "tip_acceleration": NoiseLevel(ACCELEROMETER_SIGMA)}
COGGING = (0.05, 8)
"""Cogging amplitude (N m) and order of the hidden torque ``a·sin(kθ)``."""
CANDIDATES = ("gravity",)
"""The library effect tested: a load of the angle, yet no cogging torque."""
STRUCTURE = ("E", "alpha", "beta")
"""The link's parameters held at their true values."""


def _model():
    model = Model(testbed=testbed.Testbed(n_elements=3))
    return model, model.space.reference()


def _input(frequency: float, phase: float) -> np.ndarray:
    """Two sines sweeping the arm through a turn or so and back, 0.4 N m peak, held over 2
    samples (the Radau reference restarts at each change)."""
    t = np.repeat(np.arange(0, N, HOLD) * DT, HOLD)[:N]
    u = 0.3 * np.sin(2 * np.pi * frequency * t) + 0.1 * np.sin(2 * np.pi * 2.3 * t + phase)
    return 0.4 * u / np.max(np.abs(u))


@functools.cache
def _record(cogging: bool, frequency: float, phase: float, seed: int) -> Record:
    """A Radau record of the arm, with the hidden cogging torque or without."""
    model, params = _model()
    a, k = COGGING
    hub = (lambda th, om: (a * np.sin(k * th), a * k * np.cos(k * th), 0.0)) if cogging else None
    u = _input(frequency, phase)
    q, _, acc = radau_states(model, params, u, DT, rtol=1e-7, atol=1e-10, hub_torque=hub)
    tip = model.testbed.length * acc[:, 0] + acc @ np.asarray(model.structure(params).tip)
    noisy = tip + ACCELEROMETER_SIGMA * np.random.default_rng(seed).standard_normal(N)
    columns = {"time": np.arange(N) * DT, "torque": u, "joint_angle": quantise_angle(q[:, 0]),
               "tip_acceleration": np.array([float(f"{v:.7g}") for v in noisy])}
    return Record.from_columns(columns, name=f"f{frequency:g}")


def _discover(cogging: bool, **kwargs):
    """The run from the true parameters, the link's stiffness and damping known (held fixed):
    a refit of them would bend the link to absorb part of the cogging."""
    model, params = _model()
    fixed = {k: float(params[k]) for k in STRUCTURE}
    return discover([_record(cogging, 0.6, 0.4, 0)], holdout=[_record(cogging, 0.5, 1.3, 1)],
                    model=model, initial=params, noise=NOISE, candidates=CANDIDATES,
                    max_steps=2, fixed=fixed, **kwargs)


@functools.cache
def _cogging_report():
    return _discover(True)


def test_discover_proposes_the_cogging_formula_and_it_predicts_better():
    """No library effect is added; the map's formula holds sin(8θ) with the amplitude within
    10 % (the refit's within 5 %), it is added, the held-out error falls, and every claim
    holds."""
    report = _cogging_report()
    mapped = report.torque_map
    assert mapped is not None and mapped["added"], mapped["claim"]
    a, k = COGGING
    term = f"sin({k}*theta)"
    assert term in mapped["map"]["coefficients"]
    assert mapped["map"]["coefficients"][term] == pytest.approx(a, rel=0.1)
    assert mapped["map"]["inclusion"][term] >= 0.6
    c = next(n for n, v in mapped["refit"]["params"].items()
             if f"{n}*{term}" in mapped["formula"])
    assert mapped["refit"]["params"][c] == pytest.approx(a, rel=0.05)
    assert report.added == ("missing_torque",)  # the library's candidates: none
    before, after = mapped["error_before"], mapped["error_after"]
    assert after["held_out"] < before["held_out"] and after["fitted"] < before["fitted"]
    assert mapped["claim"].startswith("the missing torque looks like ")
    assert f"held-out error {before['held_out']:.3g} % before" in mapped["claim"]
    assert f"held-out error {after['held_out']:.3g} % after" in mapped["claim"]
    assert f"torque map: {mapped['claim']}" in report.table()
    data = check_claims(report)
    step = data["steps"][-1]
    assert step["added"] == "missing_torque" and step["torque_map"]["formula"]
    assert "missing_torque" in step["effects"]
    # the fit file rebuilds the formula effect
    from jaxflex.fit import Fit
    fit = report.to_fit()
    again = Fit.from_dict(json.loads(json.dumps(fit.to_dict())))
    assert again.model.effect_names == ("missing_torque",)
    assert again.model.effects[-1].expression == mapped["formula"]


def test_clean_records_propose_nothing():
    """Without a hidden torque the run ends with nothing missing or the map at noise level."""
    report = _discover(False)
    assert report.added == ()
    if report.torque_map is not None:
        assert not report.torque_map["added"]
        assert report.torque_map["map"]["verdict"] == "noise"
        assert "at noise level" in report.torque_map["claim"]
    else:
        assert report.unexplained is None


def test_the_switch_turns_it_off():
    """``torque_map=False`` (the CLI's ``--no-torque-map``): the cogging stays unexplained."""
    report = _discover(True, torque_map=False)
    assert report.torque_map is None and report.added == ()
    assert report.unexplained is not None
    assert re.search("torque map", report.table()) is None
    assert command_parser("discover").parse_args(["x.csv"]).torque_map is True
    assert command_parser("discover").parse_args(["x.csv", "--no-torque-map"]).torque_map is False


def test_the_json_carries_the_proposal():
    """What ``discover --json`` writes: the map (expression, verdict, inclusion probabilities)
    and the claim, at the top and on the step that adds the formula."""
    data = json.loads(json.dumps(_cogging_report().to_dict()))
    mapped = data["torque_map"]
    assert mapped["map"]["verdict"] == "explained" and mapped["added"]
    assert mapped["map"]["inclusion"]["sin(8*theta)"] >= 0.6
    assert data["steps"][-1]["torque_map"] == mapped
    assert data["settings"]["torque_map"] is True
    assert "torque_map" in data["claim_rules"]


def test_a_map_at_noise_level_proposes_nothing_and_says_so():
    """The clean record's missing torque at the true parameters: the map is at noise level, no
    formula is made of it, and the claim quotes the map's rule."""
    model, params = _model()
    estimate = estimate_missing_torque(_record(False, 0.6, 0.4, 0), model, params, noise=NOISE)
    tmap = torque_map(estimate, bootstrap=BOOTSTRAP)
    assert tmap.verdict == "noise" and formula_of(tmap) is None
    words = claim({"map": tmap.to_dict(), "effect": None})
    assert words == f"the torque map is {MAP_RULES['noise'][1]}; no formula is proposed"
