"""The missing hub torque against independent references: records integrated by SciPy Radau on
the FEM equations (``reference_solver``) with a hidden hub torque, logged as an encoder and an
accelerometer would (quantised angle; white noise, 7 significant digits), and the model WITHOUT
that torque at the true base parameters; the smoother against a Gaussian conditioning of all the
samples at once on the linear arm."""

from __future__ import annotations

import functools
import json

import numpy as np
import pytest
from reference_solver import radau_states
from test_figure_layout import _legends_off_the_data, assert_readable
from test_kalman import _linear_system

from jaxflex import Model
from jaxflex.data import Record
from jaxflex.missing_torque import estimate_missing_torque
from jaxflex.noise import NoiseLevel
from jaxflex.plots.missing_torque import plot_missing_torque
from jaxflex.synthetic import ACCELEROMETER_SIGMA, ENCODER_STEP, quantise_angle
from jaxflex.testbed import Testbed
from jaxflex.torque_regression import MAP_RULES, term_function, torque_map

DT, N, HOLD = 2e-3, 1000, 2
NOISE = {"joint_angle": NoiseLevel.quantised(ENCODER_STEP),
         "tip_acceleration": NoiseLevel(ACCELEROMETER_SIGMA)}
COGGING = (0.05, 8)
"""Cogging amplitude (N m) and order: the hidden torque ``a·sin(kθ)``."""
DEAD_ZONE = 0.04
"""Half-width (N m) of the amplifier's dead zone: the hub gets ``u − clip(u, −c, c)``."""
EDGE = 50
"""Samples left out at each end when comparing torques: the smoother's start (the torque's
prior) and end (no later samples)."""


def _model():
    model = Model(testbed=Testbed(n_elements=3))
    return model, model.space.reference()


def _input() -> np.ndarray:
    """A smooth input sweeping the arm through a turn or so and back, crossing zero while the
    arm moves: two sines, 0.4 N m peak, held over 2 samples (a 250 Hz command; the Radau
    reference restarts at each change)."""
    t = np.repeat(np.arange(0, N, HOLD) * DT, HOLD)[:N]
    u = 0.3 * np.sin(2 * np.pi * 0.6 * t) + 0.1 * np.sin(2 * np.pi * 2.3 * t + 0.4)
    return 0.4 * u / np.max(np.abs(u))


@functools.cache
def _logged(hidden: str, seed: int = 0):
    """A Radau record of the arm with the ``hidden`` torque ("cogging", "dead_zone", "none")
    and the true missing torque at the samples."""
    model, params = _model()
    u = _input()
    a, k = COGGING
    cogging = (lambda th, om: (a * np.sin(k * th), a * k * np.cos(k * th), 0.0)) if (
        hidden == "cogging") else None
    applied = u - np.clip(u, -DEAD_ZONE, DEAD_ZONE) if hidden == "dead_zone" else u
    q, _, acc = radau_states(model, params, applied, DT, rtol=1e-7, atol=1e-10,
                             hub_torque=cogging)
    theta = q[:, 0]
    tip = model.testbed.length * acc[:, 0] + acc @ np.asarray(model.structure(params).tip)
    rng = np.random.default_rng(seed)
    noisy = tip + ACCELEROMETER_SIGMA * rng.standard_normal(N)
    columns = {"time": np.arange(N) * DT, "torque": u, "joint_angle": quantise_angle(theta),
               "tip_acceleration": np.array([float(f"{v:.7g}") for v in noisy])}
    missing = (a * np.sin(k * theta) if hidden == "cogging" else applied - u)
    return Record.from_columns(columns, name=hidden), missing


@functools.cache
def _estimated(hidden: str):
    model, params = _model()
    record, missing = _logged(hidden)
    estimate = estimate_missing_torque(record, model, params, noise=NOISE)
    return estimate, missing


def _relative_rms(estimate, missing) -> float:
    [r] = estimate.records
    span = slice(EDGE, -EDGE)
    return float(np.sqrt(np.mean((r.torque - missing)[span] ** 2))
                 / np.sqrt(np.mean(missing[span] ** 2)))


def test_cogging_is_estimated_and_its_shape_found():
    """A hidden cogging torque a·sin(kθ): d̂ is it within 10 % RMS, and the map's largest term
    is sin(kθ) of the right order, its coefficient within 10 % of a, included in > 80 % of the
    subsamples, the map explaining the torque."""
    estimate, missing = _estimated("cogging")
    assert _relative_rms(estimate, missing) < 0.10
    found = torque_map(estimate, bootstrap=20)
    a, k = COGGING
    term = f"sin({k}*theta)"
    assert term in found.selected
    assert found.coefficients[term] == pytest.approx(a, rel=0.10)
    low, high = found.intervals[term]
    assert low < found.coefficients[term] < high
    assert found.inclusion[term] > 0.8
    assert max(found.coefficients, key=lambda s: abs(found.coefficients[s])) == term
    assert found.verdict == "explained"
    [r] = estimate.records
    assert json.loads(json.dumps(found.to_dict()))["intervals"][term] == list(found.intervals[term])
    value = term_function(found.expression)(r.theta, r.omega, r.u, r.time)
    assert np.allclose(value, found.evaluate(r.theta, r.omega, r.u, r.time), atol=1e-3 * a)


def test_dead_zone_is_estimated_and_named():
    """An amplifier dead zone of half-width c: d̂ is the withheld torque −clip(u, −c, c) within
    10 % RMS, and the map's largest term is a dead zone, one of c's width."""
    estimate, missing = _estimated("dead_zone")
    assert _relative_rms(estimate, missing) < 0.10
    found = torque_map(estimate, bootstrap=20)
    largest = max(found.coefficients, key=lambda s: abs(found.coefficients[s]))
    assert largest == f"Max(Min(u, {DEAD_ZONE:g}), -{DEAD_ZONE:g})"
    assert found.coefficients[largest] == pytest.approx(-1.0, rel=0.10)
    assert found.verdict == "explained"


def test_no_missing_torque_is_at_noise_level():
    """Without a hidden torque, d̂ stays within its own uncertainty: the map says so and
    selects nothing; the figure is readable."""
    estimate, _ = _estimated("none")
    found = torque_map(estimate, bootstrap=10)
    assert found.verdict == "noise"
    assert found.words == MAP_RULES["noise"][1]
    assert found.selected == () and found.expression == "0"
    fig = plot_missing_torque(estimate, found)
    assert_readable(fig, "missing_torque_none")


def test_missing_torque_figure_is_readable():
    estimate, _ = _estimated("cogging")
    found = torque_map(estimate, bootstrap=10)
    fig = plot_missing_torque(estimate, found)
    assert_readable(fig, "missing_torque")
    assert not _legends_off_the_data(fig)
    labels = {ax.get_xlabel() for ax in fig.axes}
    assert {"time (s)", "hub velocity ω̂ (rad/s)", "hub angle θ̂ (rad)", "input u (N m)"} <= labels


def _walk_covariance(n, intensity, prior, dt, integrated):
    """The prior covariance of the torque samples: a random walk (variance ``prior²`` at the
    start, ``intensity²·dt`` a step) or an integrated one (``[d, ḋ]`` stepped by
    ``[[1, dt], [0, 1]]``, the exact noise of a white jerk of intensity ``intensity``, the rate's
    start variance ``(prior / (100 dt))²``)."""
    if not integrated:
        walk = np.tril(np.ones((n, n)))
        return walk @ np.diag(np.r_[prior**2, np.full(n - 1, intensity**2 * dt)]) @ walk.T
    step = np.array([[1.0, dt], [0.0, 1.0]])
    noise = intensity**2 * np.array([[dt**3 / 3, dt**2 / 2], [dt**2 / 2, dt]])
    covariances = [np.diag([prior**2, (prior / (100 * dt)) ** 2])]
    for _ in range(n - 1):
        covariances.append(step @ covariances[-1] @ step.T + noise)
    out = np.zeros((n, n))
    for j in range(n):
        ahead = covariances[j]
        for k in range(j, n):  # Cov(s_k, s_j) = A^(k−j) P_j
            out[k, j] = out[j, k] = ahead[0, 0]
            ahead = step @ ahead
    return out


def _batch_smoother(a, b, c, d, torque, y, sigma_y, prior_cov):
    """The smoothed torque without any Kalman recursion: on the linear arm from rest the
    readings are ``y = y_u + G·τ + v`` for the hidden torque samples ``τ`` (``G`` from the
    Markov parameters ``C Aʲ B`` and ``D``), ``τ`` of covariance ``prior_cov``
    (:func:`_walk_covariance`), so the posterior is one Gaussian conditioning. Returns
    the torque's posterior mean and standard deviation, the hub angle's mean and the evidence
    ``log N(y; y_u, G Σ Gᵀ + R)``."""
    n, channels = torque.shape[0], c.shape[0]
    markov, x = [], b.copy()
    for _ in range(n):
        markov.append(c @ x)
        x = a @ x
    g = np.zeros((channels * n, n))
    for t in range(n):
        g[t * channels:(t + 1) * channels, t] = d
        for s in range(t):
            g[t * channels:(t + 1) * channels, s] = markov[t - s - 1]
    free = g @ torque
    e = y.T.ravel() - free
    s_cov = g @ prior_cov @ g.T + np.diag(np.tile(sigma_y**2, n))
    gain = np.linalg.solve(s_cov, g @ prior_cov).T
    mean = gain @ e
    cov = prior_cov - gain @ g @ prior_cov
    _, log_det = np.linalg.slogdet(2 * np.pi * s_cov)
    evidence = -0.5 * (e @ np.linalg.solve(s_cov, e) + log_det)
    angle = g[0::channels] @ (torque + mean)
    return mean, np.sqrt(np.diag(cov)), angle, evidence


@pytest.mark.parametrize("integrated", [False, True])
def test_linear_smoother_equals_a_gaussian_conditioning(integrated):
    """Without joint friction the arm is linear: the smoothed missing torque, its standard
    deviation, the hub angle and the innovations' likelihood (the torque a random walk or an
    integrated one) are those of a
    Gaussian conditioning of all the samples at once (no recursion) on the exact
    zero-order-hold system from the FEM matrices."""
    model = Model(testbed=Testbed(n_elements=3))
    params = model.space.reference() | {"tau_c": 1e-12, "b_v": 1e-12, "alpha": 1e-12}
    dt, n = 2e-3, 240
    t = np.arange(n) * dt
    u = 0.05 * np.sign(np.sin(2 * np.pi * 2.0 * t + 0.3))
    a, b, c, d = _linear_system(model, params, dt)
    x, y = np.zeros(a.shape[0]), []
    rng = np.random.default_rng(4)
    sigma = np.array([2e-4, 0.05])
    for k in range(n):  # the arm under u plus a slow hidden torque
        hidden = 0.02 * np.sin(2 * np.pi * 1.5 * t[k])
        y.append(c @ x + d * (u[k] + hidden) + sigma * rng.standard_normal(2))
        x = a @ x + b * (u[k] + hidden)
    y = np.array(y).T
    record = Record.from_columns({"time": t, "torque": u, "joint_angle": y[0],
                                  "tip_acceleration": y[1]}, name="linear")
    noise = {"joint_angle": float(sigma[0]), "tip_acceleration": float(sigma[1])}
    intensity = 20.0 if integrated else 0.5
    estimate = estimate_missing_torque(record, model, params, noise=noise, intensity=intensity,
                                       prior=0.05, integrated=integrated)
    prior_cov = _walk_covariance(n, intensity, 0.05, dt, integrated)
    torque, std, angle, evidence = _batch_smoother(a, b, c, d, u, y, sigma, prior_cov)
    [r] = estimate.records
    np.testing.assert_allclose(r.torque, torque, atol=1e-5 * 0.02)
    np.testing.assert_allclose(r.std, std, rtol=1e-5)
    np.testing.assert_allclose(r.theta, angle, atol=1e-9)
    assert estimate.log_likelihood == pytest.approx(evidence, abs=1e-3)
    # the smoothed torque follows the hidden one: the smoother sees it
    hidden = 0.02 * np.sin(2 * np.pi * 1.5 * t)
    assert np.sqrt(np.mean((r.torque - hidden)[20:-20] ** 2)) < 0.2 * 0.02 * np.sqrt(0.5)


def test_bad_settings_are_refused():
    model, params = _model()
    record, _ = _logged("none")
    with pytest.raises(ValueError, match="intensity=-1"):
        estimate_missing_torque(record, model, params, intensity=-1.0)
    with pytest.raises(ValueError, match="prior=0"):
        estimate_missing_torque(record, model, params, prior=0.0)
    estimate, _ = _estimated("none")
    with pytest.raises(ValueError, match="term 'sin\\(x\\)' uses \\['x'\\]"):
        torque_map(estimate, terms=["sin(x)"])
    with pytest.raises(ValueError, match="bootstrap=1"):
        torque_map(estimate, bootstrap=1)


def test_a_torque_of_no_state_or_input_points_at_a_sensor():
    """The map's words by its rules, on the smoothed motion of a record: a torque well above
    its uncertainty that is a random signal of time, smooth over a few samples (none of the
    terms), points at a sensor; half cogging and half that signal is partly a function of state
    and input."""
    estimate, _ = _estimated("none")
    [r] = estimate.records
    rng = np.random.default_rng(5)
    kernel = np.exp(-0.5 * (np.arange(-60, 61) / 3.0) ** 2)
    wander = np.convolve(rng.standard_normal(N + 120), kernel, "valid")[:N]
    wander *= 0.02 / np.std(wander)
    std = np.full(N, 1e-3)
    for torque, verdict in ((wander, "sensor"),
                            (wander + 0.02 * np.sqrt(2) * np.sin(8 * r.theta), "partly")):
        changed = estimate._replace(records=(r._replace(torque=torque, std=std),))
        found = torque_map(changed, bootstrap=10)
        assert found.verdict == verdict, (found.explained, found.expression)
        assert found.words == MAP_RULES[verdict][1]


def test_the_command_writes_the_map_and_the_figure(tmp_path, capsys):
    """``jaxflex torque-map`` on a cogging record and a fit at the true parameters of the model
    without it: the map found is the cogging, in the JSON and on the screen; a second run
    without --overwrite is refused in one line."""
    from test_cli_validate import write_fit

    from jaxflex.cli import main
    from jaxflex.data import save_record

    model, params = _model()
    record, _ = _logged("cogging")
    data = save_record(record, tmp_path / "cogging.csv")
    fit = write_fit(tmp_path / "fit.json", params=params, record_names=("cogging",), model=model)
    out = tmp_path / "map"
    args = ["torque-map", str(data), "--fit", str(fit), "--out", str(out), "--bootstrap", "10",
            "--quiet"]
    assert main(args) == 0
    printed = capsys.readouterr().out
    found = json.loads((out / "torque_map.json").read_text())["map"]
    a, k = COGGING
    assert found["coefficients"][f"sin({k}*theta)"] == pytest.approx(a, rel=0.1)
    assert found["expression"] in printed and MAP_RULES["explained"][1] in printed
    assert (out / "missing_torque.png").stat().st_size > 0
    assert main(args) == 2
    assert "torque_map.json" in capsys.readouterr().err
