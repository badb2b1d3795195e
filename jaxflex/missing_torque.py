"""The missing hub torque: estimated by a Kalman smoother, its shape found by sparse regression.

When no library effect explains a fit's misfit, what the model lacks can often be written as one
unmodelled torque ``d(t)`` at the hub. :func:`estimate_missing_torque` augments the state of the
model's extended Kalman filter (:mod:`jaxflex.kalman`: the same sampled step, linearisation and
measurement update) with ``d``, a random walk (``d_{k+1} = d_k + w_k``, ``var w = q·Δt``) or,
with ``integrated=True``, an integrated random walk (``ḋ`` the random walk, ``d`` its
integral). ``d_k`` is added to the logged torque over the interval after sample ``k``, and to the
torque the readings see at the sample (an accelerometer feels it at once). Its intensity ``√q``
(N m/√s; N m/s/√s integrated) is the one value that maximises the innovations' likelihood over
the records (a bounded 1-D search in ``log √q``). A Rauch–Tung–Striebel pass then gives, on
each record, the smoothed ``d̂(t)``, its standard deviation, the hub angle ``θ̂`` and velocity
``ω̂`` (the simulator's joint angle and velocity of the smoothed state).

:func:`jaxflex.torque_regression.torque_map` regresses ``d̂`` on a library of candidate terms
of ``θ̂, ω̂, u, t`` (:func:`~jaxflex.torque_regression.default_terms`; each term's name is a
formula in those variables): the lasso path with the Bayesian information criterion on
standardised columns (scikit-learn's ``LassoLarsIC``), stability selection by a moving-block
bootstrap (samples of ``d̂`` are correlated), then an ordinary least-squares refit on the
stable terms with block-bootstrap 95 % intervals. Its words follow
:data:`~jaxflex.torque_regression.MAP_RULES`.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import scipy.optimize
from jaxtyping import Array, ArrayLike, Float, Scalar

from jaxflex.data import Record
from jaxflex.kalman import (
    check_per_sample,
    measurement_noise,
    measurement_update,
    record_arrays,
    step_and_output,
    value_and_jacobian,
)
from jaxflex.model import Model
from jaxflex.noise import Noise
from jaxflex.objective import check_channels, check_records, fitted_channels, record_tuple
from jaxflex.parameters import Params
from jaxflex.simulation import Outputs, model_dynamics

INTENSITY_RANGE = (1e-5, 1e3)
"""Range of the random walk's intensity ``√q`` searched by maximum likelihood (N m/√s, or
N m/s/√s for the integrated random walk)."""


class Smoothed(NamedTuple):
    """The augmented filter and smoother over one record (JAX arrays): the innovations'
    log-likelihood, the smoothed states (samples × augmented state) and their variances."""

    log_likelihood: Scalar
    states: Float[Array, "n d"]
    variance: Float[Array, "n d"]
    hub: Float[Array, "2 n"]


def smoother_core(
    model: Model,
    params: Params,
    torque: Float[Array, " n"],
    measured: Float[Array, "C n"],
    present: Float[Array, " C"],
    dt: float,
    channels: Sequence[str],
    sigma_y: Float[Array, " C"],
    intensity: Scalar,
    prior: Scalar,
    integrated: bool = False,
    smooth: bool = True,
) -> Smoothed:
    """The extended Kalman filter of :func:`jaxflex.kalman.filter_core` on the state augmented
    with the missing torque (and its rate, ``integrated``), then the Rauch–Tung–Striebel pass
    (unless not ``smooth``: the likelihood alone). ``prior`` is the standard deviation of the
    torque at the start (N m; the arm's own state starts known, at rest); pure and traceable."""
    step, output, x0, fine_torque = step_and_output(model, params, dt, channels)
    dynamics = model_dynamics(model, params, dt)
    fine = fine_torque(torque)
    dim = x0.shape[0]
    extra = 2 if integrated else 1
    noise = jnp.diag(jnp.where(present > 0, sigma_y**2, 1.0))
    q = intensity**2
    if integrated:  # the continuous white-noise jerk model over one interval
        q_d = q * jnp.array([[dt**3 / 3.0, dt**2 / 2.0], [dt**2 / 2.0, dt]])
        p0_d = jnp.diag(jnp.array([prior**2, (prior / (100.0 * dt)) ** 2]))
    else:
        q_d = q * dt * jnp.ones((1, 1))
        p0_d = prior**2 * jnp.ones((1, 1))
    q_full = jnp.zeros((dim + extra, dim + extra)).at[dim:, dim:].set(q_d)

    def advance(z, taus):
        x_next = step(z[:dim], taus + z[dim])
        d_next = z[dim:] + (jnp.array([dt * z[dim + 1], 0.0]) if integrated else 0.0)
        return jnp.concatenate([x_next, d_next])

    def sample(carry, inputs):
        z, p_cov = carry
        taus, y = inputs
        update = measurement_update(
            z, p_cov, lambda z: output(z[:dim], taus[0] + z[dim]), y, present, noise)
        z_next, f_mat = value_and_jacobian(lambda z: advance(z, taus), update.x)
        p_next = f_mat @ update.p_cov @ f_mat.T + q_full
        return (z_next, 0.5 * (p_next + p_next.T)), (z, p_cov, update, f_mat)

    z0 = jnp.concatenate([x0, jnp.zeros(extra)])
    p0 = jnp.zeros((dim + extra, dim + extra)).at[dim:, dim:].set(p0_d)
    _, (z_prior, p_prior, updates, f_mats) = jax.lax.scan(sample, (z0, p0), (fine, measured.T))
    log_likelihood = -jnp.sum(updates.nll)
    if not smooth:
        return Smoothed(log_likelihood, updates.x, jax.vmap(jnp.diag)(updates.p_cov),
                        jnp.zeros((2, 0)))

    def back(carry, inputs):
        """Bierman's modified Bryson–Frazier form of the RTS smoother: adjoints instead of the
        inverse of the predicted covariance (singular here: the arm's state starts known)."""
        lam_next, big_next = carry  # λ̃, Λ̃ of the next sample
        z, p_cov, h_rows, chol, e, f_mat = inputs
        lam, big = f_mat.T @ lam_next, f_mat.T @ big_next @ f_mat
        s_inv_h = jax.scipy.linalg.cho_solve((chol, True), h_rows)
        keep = jnp.eye(z.shape[0]) - p_cov @ s_inv_h.T @ h_rows
        lam = -s_inv_h.T @ e + keep.T @ lam
        big = h_rows.T @ s_inv_h + keep.T @ big @ keep
        return (lam, big), (z - p_cov @ lam, jnp.diag(p_cov - p_cov @ big @ p_cov))

    size = dim + extra
    _, (z_s, var_s) = jax.lax.scan(
        back, (jnp.zeros(size), jnp.zeros((size, size))),
        (z_prior, p_prior, updates.h_rows, updates.chol, updates.innovations, f_mats),
        reverse=True)

    def hub(z, tau):
        out = Outputs(*dynamics.observe(dynamics.from_vector(z[:dim]), tau + z[dim]))
        return jnp.stack([out.joint_angle, out.joint_velocity])

    angles = jax.vmap(hub)(z_s, fine[:, 0]).T
    return Smoothed(log_likelihood, z_s, var_s, angles)


_smoother_jit = eqx.filter_jit(smoother_core)


class TorqueRecord(NamedTuple):
    """One record's missing torque (float64 NumPy arrays over its samples): ``torque`` is
    ``d̂`` (N m) and ``std`` its smoothed standard deviation, ``theta`` and ``omega`` the
    smoothed hub angle (rad) and velocity (rad/s), ``u`` the logged input."""

    name: str
    time: np.ndarray
    torque: np.ndarray
    std: np.ndarray
    theta: np.ndarray
    omega: np.ndarray
    u: np.ndarray


class MissingTorque(NamedTuple):
    """:func:`estimate_missing_torque`'s result: per record a :class:`TorqueRecord`; the random
    walk's maximum-likelihood ``intensity`` (N m/√s; N m/s/√s when ``integrated``), the
    innovations' log-likelihood there, and the measurement noise used per channel."""

    records: tuple[TorqueRecord, ...]
    intensity: float
    integrated: bool
    log_likelihood: float
    sigma_y: dict[str, float]


def estimate_missing_torque(
    records: Record | Sequence[Record],
    model: Model,
    params: Mapping[str, ArrayLike],
    *,
    channels: Sequence[str] | None = None,
    noise: Noise | None = None,
    intensity: float | None = None,
    integrated: bool = False,
    prior: float | None = None,
) -> MissingTorque:
    """The unmodelled hub torque of ``model`` at ``params`` on each record, smoothed (see the
    module doc). ``channels`` default to the fitted ones, their noise to
    :func:`jaxflex.kalman.measurement_noise` (``noise`` where given); ``intensity`` fixes the
    random walk's (else fitted by maximum likelihood in :data:`INTENSITY_RANGE`); ``prior`` is
    the torque's standard deviation at the start (N m; default the largest hub torque the logged
    input makes; integrated, its rate's is ``prior/(100·dt)``)."""
    check_records(records, "estimate_missing_torque")
    records = list(record_tuple(records))
    channels = fitted_channels(records, model) if channels is None else check_channels(
        channels, model)
    values = {k: jnp.asarray(v, dtype=jnp.float64) for k, v in params.items()}
    model.space.validate(values)
    check_per_sample(model, values, channels)
    lower, upper = INTENSITY_RANGE
    if intensity is not None and not (
            isinstance(intensity, (int, float)) and lower <= intensity <= upper):
        raise ValueError(f"intensity={intensity!r}: expected a random-walk intensity from "
                         f"{lower:g} to {upper:g}")
    if prior is None:  # the largest hub torque the input makes (through the rig's drive)
        prior = max(max(float(jnp.max(jnp.abs(step_and_output(model, values, r.dt, channels)[3](
            jnp.asarray(r.input))))) for r in records), 1e-6)
    elif not (isinstance(prior, (int, float)) and math.isfinite(prior) and prior > 0):
        raise ValueError(f"prior={prior!r}: expected a positive torque (N m)")
    levels = measurement_noise(records, model, channels, noise)
    sigma_y = jnp.asarray([levels[c] for c in channels])
    arrays = [record_arrays(r, channels) for r in records]

    def run(r, a, level, smooth):
        return _smoother_jit(model, values, *a, r.dt, tuple(channels), sigma_y,
                             jnp.asarray(level), jnp.asarray(float(prior)), integrated, smooth)

    def negative(log_level):
        total = sum(float(run(r, a, math.exp(log_level), False).log_likelihood)
                    for r, a in zip(records, arrays, strict=True))
        return -total if math.isfinite(total) else math.inf

    if intensity is None:
        best = scipy.optimize.minimize_scalar(
            negative, bounds=(math.log(lower), math.log(upper)), method="bounded",
            options={"xatol": 0.05})
        intensity = math.exp(float(best.x))
    out, total = [], 0.0
    for r, a in zip(records, arrays, strict=True):
        s = run(r, a, intensity, True)
        total += float(s.log_likelihood)
        dim = s.states.shape[1] - (2 if integrated else 1)
        hub = np.asarray(s.hub, dtype=np.float64)
        out.append(TorqueRecord(
            name=r.name, time=np.asarray(r.time, dtype=np.float64),
            torque=np.asarray(s.states[:, dim], dtype=np.float64),
            std=np.sqrt(np.maximum(np.asarray(s.variance[:, dim], dtype=np.float64), 0.0)),
            theta=hub[0], omega=hub[1], u=np.asarray(r.input, dtype=np.float64)))
    return MissingTorque(tuple(out), float(intensity), integrated, total, dict(levels))


__all__ = ["INTENSITY_RANGE", "MissingTorque", "Smoothed", "TorqueRecord",
           "estimate_missing_torque", "smoother_core"]
