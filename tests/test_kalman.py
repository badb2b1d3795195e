"""The model's Kalman filter against an independent NumPy Kalman filter, and its innovations on
records of the model itself."""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np
import pytest
import scipy.linalg

from jaxflex import Model
from jaxflex.data import Record
from jaxflex.diagnosis import autocorrelation
from jaxflex.effects import AbstractEffect
from jaxflex.kalman import predict
from jaxflex.simulation import simulate
from jaxflex.testbed import Testbed

SIGMA = {"joint_angle": 2e-4, "tip_acceleration": 0.05}
"""Measurement noise of the records (rad, m/s²)."""


def _record(model, params, n, disturbance, seed, dt=None) -> Record:
    """A record of ``model`` under a square wave plus a white torque disturbance, logged with
    white noise of :data:`SIGMA` as float32 values."""
    dt = model.testbed.dt if dt is None else dt
    rng = np.random.default_rng(seed)
    t = np.arange(n) * dt
    torque = 0.05 * np.sign(np.sin(2 * np.pi * 2.0 * t + 0.3))
    out = simulate(model, params, torque + disturbance * rng.standard_normal(n), dt)
    columns = {"time": t, "torque": torque}
    for c, s in SIGMA.items():
        columns[c] = (np.asarray(out.channel(c)) + s * rng.standard_normal(n)).astype(np.float32)
    return Record.from_columns({k: np.asarray(v, dtype=np.float64) for k, v in columns.items()},
                               name="simulated")


def _linear_system(model, params, dt):
    """Zero-order-hold ``A, B, C, D`` of the linear arm (no joint friction, stiffness-
    proportional damping) on ``[q, q']``, from the FEM matrices with ``expm``; outputs joint
    angle and tip acceleration."""
    structure = model.structure(params)
    mass, stiffness = np.asarray(structure.mass), np.asarray(structure.stiffness)
    n = mass.shape[0]
    damping = float(params["beta"]) * stiffness
    inv_mass = np.linalg.inv(mass)
    hub = np.eye(n)[0]
    a = np.block([[np.zeros((n, n)), np.eye(n)], [-inv_mass @ stiffness, -inv_mass @ damping]])
    b = np.concatenate([np.zeros(n), inv_mass @ hub])
    augmented = np.zeros((2 * n + 1, 2 * n + 1))
    augmented[: 2 * n, : 2 * n], augmented[: 2 * n, 2 * n] = a, b
    step = scipy.linalg.expm(augmented * dt)
    a_d, b_d = step[: 2 * n, : 2 * n], step[: 2 * n, 2 * n]
    radius = model.testbed.clamp_offset + model.testbed.length
    acc_row = radius * hub + np.asarray(structure.tip)
    c = np.stack([np.concatenate([hub, np.zeros(n)]), acc_row @ a[n:]])
    d = np.array([0.0, acc_row @ inv_mass @ hub])
    return a_d, b_d, c, d


def _numpy_kalman(a, b, c, d, torque, y, sigma_y, sigma_tau, horizons):
    """Textbook Kalman filter from rest (``P_0 = 0``): innovations, their variances and the
    ``k``-step predictions ``ŷ_{t|t−k}`` (the first ``k`` samples simulated from rest)."""
    n, dim = torque.shape[0], a.shape[0]
    r_cov, q_cov = np.diag(sigma_y**2), sigma_tau**2 * np.outer(b, b)
    x, p = np.zeros(dim), np.zeros((dim, dim))
    innovations, variances, filtered = [], [], []
    for t in range(n):
        e = y[:, t] - (c @ x + d * torque[t])
        s = c @ p @ c.T + r_cov
        gain = p @ c.T @ np.linalg.inv(s)
        x, p = x + gain @ e, (np.eye(dim) - gain @ c) @ p
        innovations.append(e)
        variances.append(np.diag(s))
        filtered.append(x)
        x, p = a @ x + b * torque[t], a @ p @ a.T + q_cov
    predictions = {}
    for k in horizons:
        out = np.zeros((c.shape[0], n))
        free = np.zeros(dim)
        for t in range(k):
            out[:, t] = c @ free + d * torque[t]
            free = a @ free + b * torque[t]
        for t in range(n - k):
            x = filtered[t]
            for j in range(k):
                x = a @ x + b * torque[t + j]
            out[:, t + k] = c @ x + d * torque[t + k]
        predictions[k] = out
    return np.array(innovations).T, np.array(variances).T, predictions


def test_linear_filter_equals_a_numpy_kalman_filter():
    """Without joint friction the model is linear: its filter's innovations, their variances
    and its 1-, 4- and 15-step predictions are those of a NumPy Kalman filter on the exact
    zero-order-hold system built from the FEM matrices."""
    model = Model(testbed=Testbed(n_elements=3))
    # joint friction and mass damping negligible (the parameter space wants them positive)
    params = model.space.reference() | {"tau_c": 1e-12, "b_v": 1e-12, "alpha": 1e-12}
    dt = 2e-3
    record = _record(model, params, 240, 0.004, seed=1, dt=dt)
    horizons = (1, 4, 15)
    [run] = predict(record, model, params, [k * dt for k in horizons], noise=SIGMA,
                    disturbance=0.004)
    y = np.stack([record.channel(c) for c in SIGMA])
    sigma_y = np.array(list(SIGMA.values()))
    innovations, variances, predictions = _numpy_kalman(
        *_linear_system(model, params, dt), record.input, y, sigma_y, 0.004, horizons)
    scale = np.sqrt(np.mean(y**2, axis=1))[:, None]
    np.testing.assert_allclose(run.innovations / scale, innovations / scale, atol=1e-8)
    np.testing.assert_allclose(run.variance, variances, rtol=1e-6)
    for k in horizons:
        np.testing.assert_allclose(run.predicted[k * dt] / scale, predictions[k] / scale,
                                   atol=1e-8)
    assert run.predicted[dt] == pytest.approx(run.one_step, abs=1e-12)


def test_innovations_are_white_on_records_of_the_model():
    """On a record of the model itself (Coulomb friction on: the extended filter), under a
    white torque disturbance, the normalised innovations have unit variance and pass the
    Ljung–Box test, and maximum likelihood finds the disturbance level."""
    model = Model(testbed=Testbed(n_elements=3))
    params = model.space.reference()
    record = _record(model, params, 1500, 0.01, seed=2)
    [run] = predict(record, model, params, noise=SIGMA)
    assert run.disturbance == pytest.approx(0.01, rel=0.2)
    for i, c in enumerate(run.channels):
        normalised = run.innovations[i] / np.sqrt(run.variance[i])
        assert np.std(normalised) == pytest.approx(1.0, abs=0.06), c
        assert autocorrelation(normalised, max_lag=20).p_value > 0.01, c


def test_bad_horizons_and_cross_sample_effects_are_refused():
    model = Model(testbed=Testbed(n_elements=2))
    params = model.space.reference()
    record = _record(model, params, 50, 0.0, seed=3)
    for horizon, message in ((0.0, "horizon 0.0 must be a positive"),
                             (-0.1, "horizon -0.1 must be a positive"),
                             (1e-4, "shorter than one sample"),
                             (0.06, "longer than record 'simulated'")):
        with pytest.raises(ValueError, match=message):
            predict(record, model, params, [horizon], noise=SIGMA, disturbance=0.01)

    class RunningMean(AbstractEffect):  # a sensor that averages its readings so far
        name = "running_mean"

        def readings(self, params, readings):
            y = readings["joint_angle"]
            return dict(readings) | {"joint_angle": jnp.cumsum(y) / jnp.arange(1, y.size + 1)}

    smeared = model.with_effects(RunningMean())
    with pytest.raises(ValueError, match="effect running_mean changes channel 'joint_angle'"):
        predict(record, smeared, params, noise=SIGMA, disturbance=0.01)
