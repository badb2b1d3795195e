"""A Kalman filter on the model: innovations, one-step and k-step-ahead predictions.

The state is the simulator's own, ``x = [θ_r, θ'_r, η, η']`` (rigid angle and velocity, the
advanced modes' coordinates and velocities: ``2 + 2·m`` for ``m`` advanced modes, so
``Model(n_modes=m)`` makes the filter cheaper too). The modal step is exact and linear; the
joint friction enters through the hub torque, so the filter is an *extended* one: each sample
interval is stepped by the simulator (:func:`jaxflex.simulation.model_dynamics`) and its
Jacobian ``F = ∂x_{k+1}/∂x_k`` taken by forward-mode differentiation (exact for the linear part;
the friction's slope through the implicit solve). The outputs are the rig's readings (sensor
readings after the model's calibration effects), linearised the same way (``H = ∂y/∂x``).

Noise: the process noise is an unmodelled hub torque, white, held over each sample interval,
of standard deviation ``σ_τ`` (N m): ``Q = σ_τ² g gᵀ`` with ``g = ∂x_{k+1}/∂τ``; the
measurement noise is white per channel, ``R = diag σ_c²`` (a sensor's :attr:`noise_std`, or a
level given or estimated by :mod:`jaxflex.diagnosis`). The filter starts where the simulation
does (at rest under the loads, known exactly: ``P_0 = 0``).

With ``x⁺_t`` the filtered state after the sample at ``t``, the ``k``-step-ahead prediction
``ŷ_{t+k|t}`` is the model stepped ``k`` times from ``x⁺_t`` under the logged input, without
further measurements (MATLAB's ``predict(sys, data, K)``); the first ``k`` samples, which no
measurement precedes by ``k``, are the simulation from the start. One scan carries the states
of every start time together (``k`` vectorised steps, not one scan per start), horizons in
increasing order continuing one another. Output-side effects must act sample by sample (a
calibration gain, an offset): one that mixes samples is refused.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Mapping, Sequence
from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import scipy.optimize
from jaxtyping import Array, ArrayLike, Float, Scalar

from jaxflex.data import Record
from jaxflex.diagnosis import estimate_noise
from jaxflex.model import Model
from jaxflex.noise import Noise, noise_levels
from jaxflex.objective import check_channels, check_records, fitted_channels, record_tuple
from jaxflex.parameters import Params
from jaxflex.simulation import Outputs, model_dynamics, read_channels, with_readings


class Filtered(NamedTuple):
    """What the filter gives for one record (leading axes: population, if batched).

    ``predicted`` holds the one-step predictions ``ŷ_{t|t−1}`` (channels × samples),
    ``innovations`` ``y_t − ŷ_{t|t−1}`` (zero where a channel is not logged), ``variance`` the
    innovations' predicted variances (diagonal of ``S_t``), ``states`` the filtered states
    ``x⁺_t`` (samples × state) and ``log_likelihood`` ``−½Σ(eᵀS⁻¹e + log det 2πS)``.
    """

    predicted: Float[Array, "*batch C n"]
    innovations: Float[Array, "*batch C n"]
    variance: Float[Array, "*batch C n"]
    states: Float[Array, "*batch n d"]
    log_likelihood: Scalar


def check_per_sample(model: Model, params: Mapping[str, ArrayLike],
                     channels: Sequence[str]) -> None:
    """A ValueError naming the effect unless every effect on the readings acts sample by
    sample (its Jacobian over a short series is diagonal): the filter applies them per sample."""
    values = {k: jnp.asarray(v, dtype=float) for k, v in params.items()}
    probe = jnp.linspace(0.1, 0.3, 3)
    for effect in model.effects:
        for channel in channels:
            def one(y, effect=effect, channel=channel):
                return effect.readings(values, {channel: y})[channel]

            jac = np.asarray(jax.jacfwd(one)(probe))
            if np.any(jac - np.diag(np.diag(jac)) != 0.0):
                raise ValueError(
                    f"effect {effect.name} changes channel {channel!r} across samples; the "
                    "Kalman filter applies the model's effects on the readings sample by "
                    "sample and cannot take it"
                )


def step_and_output(model: Model, params: Params, dt: float, channels: Sequence[str]):
    """The sampled dynamics on the flat state: ``step(x, taus)``, ``output(x, tau)`` (the fitted
    channels' readings), the start ``x_0`` and ``fine_torque``."""
    dynamics = model_dynamics(model, params, dt)

    def step(x, taus):
        return dynamics.to_vector(dynamics.advance(dynamics.from_vector(x), taus))

    def output(x, tau):
        out = with_readings(model, Outputs(*dynamics.observe(dynamics.from_vector(x), tau)))
        return read_channels(model, params, out, channels)

    x0 = dynamics.to_vector(dynamics.start(None))
    return step, output, x0, dynamics.fine_torque


def value_and_jacobian(fn, x: Array) -> tuple[Array, Array]:
    """``fn(x)`` and its Jacobian (forward mode, one primal evaluation)."""
    value, linear = jax.linearize(fn, x)
    return value, jax.vmap(linear, out_axes=-1)(jnp.eye(x.shape[0], dtype=x.dtype))


class Update(NamedTuple):
    """One measurement update: the posterior state and covariance, ``ŷ``, the innovations,
    their variances, the sample's negative log-likelihood, the linearised readings ``H`` and
    the Cholesky factor of the innovations' covariance ``S``."""

    x: Array
    p_cov: Array
    y_hat: Array
    innovations: Array
    variance: Array
    nll: Scalar
    h_rows: Array
    chol: Array


def measurement_update(x: Array, p_cov: Array, output, y: Array, present: Array,
                       noise: Array) -> Update:
    """One measurement update of the extended filter at the prior ``x, p_cov``: the readings
    ``output(x)`` linearised, the channels ``present`` (1/0) weighted by their ``noise``
    covariance, Joseph form."""
    y_hat, h_rows = value_and_jacobian(output, x)
    h_rows = h_rows * present[:, None]
    e = jnp.where(present > 0, y - y_hat, 0.0)
    s_cov = h_rows @ p_cov @ h_rows.T + noise
    chol = jnp.linalg.cholesky(s_cov)
    gain = jax.scipy.linalg.cho_solve((chol, True), h_rows @ p_cov).T
    joseph = jnp.eye(x.shape[0]) - gain @ h_rows
    p_post = joseph @ p_cov @ joseph.T + gain @ noise @ gain.T
    white = jax.scipy.linalg.solve_triangular(chol, e, lower=True)
    log_det = 2.0 * jnp.sum(jnp.log(jnp.diag(chol)) * present)
    nll = 0.5 * (white @ white + log_det + jnp.sum(present) * math.log(2.0 * math.pi))
    return Update(x + gain @ e, p_post, y_hat, e, jnp.diag(s_cov), nll, h_rows, chol)


def filter_core(
    model: Model,
    params: Params,
    torque: Float[Array, " n"],
    measured: Float[Array, "C n"],
    present: Float[Array, " C"],
    dt: float,
    channels: Sequence[str],
    sigma_y: Float[Array, " C"],
    sigma_tau: Scalar,
) -> Filtered:
    """The extended Kalman filter over one record; pure and traceable (see the module doc).

    ``present`` is 1 for each channel the record logs, 0 for one it lacks (no update from it).
    """
    step, output, x0, fine_torque = step_and_output(model, params, dt, channels)
    fine = fine_torque(torque)
    dim = x0.shape[0]
    noise = jnp.diag(jnp.where(present > 0, sigma_y**2, 1.0))

    def sample(carry, inputs):
        x, p_cov = carry
        taus, y = inputs
        x_post, p_post, y_hat, e, s_diag, nll, _, _ = measurement_update(
            x, p_cov, lambda x: output(x, taus[0]), y, present, noise)
        # the step and its Jacobian in the state and in a torque added over the interval
        x_next, jac = value_and_jacobian(
            lambda z: step(z[:dim], taus + z[dim]), jnp.concatenate([x_post, jnp.zeros(1)])
        )
        f_mat, g = jac[:, :dim], jac[:, dim]
        p_next = f_mat @ p_post @ f_mat.T + sigma_tau**2 * jnp.outer(g, g)
        return (x_next, 0.5 * (p_next + p_next.T)), (y_hat, e, s_diag, x_post, nll)

    p0 = jnp.zeros((dim, dim))
    _, (y_hat, e, s_diag, states, nll) = jax.lax.scan(sample, (x0, p0), (fine, measured.T))
    return Filtered(y_hat.T, e.T, s_diag.T, states, -jnp.sum(nll))


def predict_core(
    model: Model,
    params: Params,
    torque: Float[Array, " n"],
    states: Float[Array, "n d"],
    dt: float,
    channels: Sequence[str],
    horizons: Sequence[int],
) -> Float[Array, "K C n"]:
    """``ŷ_{t|t−k}`` for each ``k`` of ``horizons`` (samples, increasing, each >= 1) from the
    filtered ``states``; the first ``k`` samples are the simulation from the start. Pure and
    traceable."""
    step, output, x0, fine_torque = step_and_output(model, params, dt, channels)
    fine = fine_torque(torque)
    n = fine.shape[0]
    longest = max(horizons)
    padded = jnp.concatenate([fine, jnp.broadcast_to(fine[-1:], (longest, fine.shape[1]))])

    def free(x, taus):  # the simulation from the start, for the samples no measurement leads
        return step(x, taus), output(x, taus[0])

    _, simulated = jax.lax.scan(free, x0, padded[:longest])

    def ahead(xs, j):  # every start's state one step further: start t at sample t + j
        taus = jax.lax.dynamic_slice_in_dim(padded, j, n)
        return jax.vmap(step)(xs, taus), None

    predictions, done, xs = [], 0, states
    for k in horizons:
        xs, _ = jax.lax.scan(ahead, xs, jnp.arange(done, k))
        done = k
        taus = jax.lax.dynamic_slice_in_dim(padded, k, n)
        y = jax.vmap(output)(xs, taus[:, 0])  # (n, C): ŷ at t + k from the state at t
        predictions.append(jnp.concatenate([simulated[:k], y[: n - k]]).T)
    return jnp.stack(predictions)


_filter_jit = eqx.filter_jit(filter_core)
_predict_jit = eqx.filter_jit(predict_core)


def measurement_noise(records: Sequence[Record], model: Model, channels: Sequence[str],
                      noise: Noise | None = None) -> dict[str, float]:
    """Each channel's measurement-noise standard deviation for the filter: ``noise`` where given
    (channel → σ or :class:`~jaxflex.diagnosis.NoiseLevel`), else the rig's sensor's
    :attr:`~jaxflex.sensors.Sensor.noise_std`, else estimated from the records
    (:func:`jaxflex.diagnosis.estimate_noise` on the measured signals: a quantisation step, or
    white noise from their second differences, never below their resolution)."""
    given = noise_levels(noise, channels)
    sensors = {s.channel: s.noise_std for s in model.sensors if s.noise_std > 0}
    missing = [c for c in channels if c not in given and c not in sensors]
    logged = [r for r in records if all(c in r.columns for c in missing)]
    estimated = estimate_noise(
        logged, [{c: r.channel(c) for c in missing} for r in logged], channels=missing
    ) if missing else {}
    return {c: given[c].sigma if c in given else sensors[c] if c in sensors
            else estimated[c].sigma for c in channels}


def horizon_steps(horizons: Sequence[float], dt: float,
                  records: Sequence[Record]) -> tuple[int, ...]:
    """Each horizon (seconds) as a whole number of samples, checked: positive, at least one
    sample, shorter than every record (one-line ValueError naming the horizon)."""
    steps = []
    for h in horizons:
        if not (isinstance(h, (int, float)) and math.isfinite(h) and h > 0):
            raise ValueError(f"horizon {h!r} must be a positive number of seconds")
        k = int(round(h / dt))
        if k < 1:
            raise ValueError(f"horizon {h:g} s is shorter than one sample ({dt:g} s)")
        for r in records:
            if k >= r.n_samples:
                raise ValueError(f"horizon {h:g} s is longer than record {r.name!r} "
                                 f"({r.n_samples * r.dt:g} s)")
        steps.append(k)
    return tuple(steps)


class Prediction(NamedTuple):
    """One record's filter run: innovations and predictions per horizon (NumPy).

    ``predicted`` maps each horizon (seconds) to the predictions ``ŷ_{t|t−k}`` of every channel
    (channels × samples); ``one_step`` the one-step predictions, ``innovations`` and ``variance``
    those of :class:`Filtered`; ``sigma_y`` the measurement noise per channel and ``disturbance``
    the process noise ``σ_τ`` (N m) used.
    """

    name: str
    channels: tuple[str, ...]
    measured: np.ndarray
    one_step: np.ndarray
    innovations: np.ndarray
    variance: np.ndarray
    predicted: dict[float, np.ndarray]
    sigma_y: dict[str, float]
    disturbance: float
    log_likelihood: float


def record_arrays(record: Record, channels: Sequence[str]) -> tuple[Array, Array, Array]:
    """Torque, measured channels (zeros where not logged) and which channels are logged."""
    present = np.array([float(c in record.columns) for c in channels])
    measured = np.stack([record.channel(c) if c in record.columns else np.zeros(record.n_samples)
                         for c in channels])
    return jnp.asarray(record.input), jnp.asarray(measured), jnp.asarray(present)


def log_likelihood(records: Sequence[Record], model: Model, params: Params,
                   channels: Sequence[str], sigma_y: Float[Array, " C"],
                   disturbance: float) -> float:
    """The innovations' Gaussian log-likelihood summed over ``records``."""
    total = 0.0
    for r in records:
        torque, measured, present = record_arrays(r, channels)
        total += float(_filter_jit(model, params, torque, measured, present, r.dt,
                                   tuple(channels), sigma_y, jnp.asarray(disturbance))
                       .log_likelihood)
    return total


DISTURBANCE_RANGE = (1e-9, 10.0)
"""Range (N m) over which the process-noise torque level is fitted by maximum likelihood."""


def check_disturbance(disturbance: float | None) -> None:
    """Refuse a process-noise torque outside :data:`DISTURBANCE_RANGE` (None: fitted), before
    any work: squared in the filter, a huge one overflows to non-finite covariances."""
    lower, upper = DISTURBANCE_RANGE
    if disturbance is None:
        return
    if isinstance(disturbance, bool) or not isinstance(disturbance, (int, float)) or not (
            lower <= disturbance <= upper):
        raise ValueError(f"disturbance={disturbance!r}: expected a process-noise torque from "
                         f"{lower:g} to {upper:g} N m (the range a fitted one is searched in)")


def fit_noise(records: Sequence[Record], model: Model, params: Params,
              channels: Sequence[str], levels: Mapping[str, float],
              free: Sequence[str] = (), disturbance: float | None = None,
              ) -> tuple[dict[str, float], float]:
    """The noise levels that maximise the innovations' likelihood over ``records``: the
    process-noise torque ``σ_τ`` (N m) unless ``disturbance`` gives it, and the measurement
    noise of the ``free`` channels, never below their ``levels`` (the sensors' own: what the
    model misses adds to them); the other channels keep their ``levels``. Returns the levels
    by channel and ``σ_τ``. A search in the logarithms (bounded for ``σ_τ`` alone, else
    Nelder–Mead); one that does not converge is said in a warning, with where it ended."""
    floors = np.array([levels[c] for c in channels])
    index = [channels.index(c) for c in free]

    def unpack(z):
        sigma = floors.copy()
        sigma[index] = np.maximum(np.exp(z[len(z) - len(index):]), floors[index])
        tau = disturbance if disturbance is not None else math.exp(z[0])
        return sigma, tau

    def negative(z):
        sigma, tau = unpack(np.atleast_1d(z))
        value = log_likelihood(records, model, params, channels, jnp.asarray(sigma), tau)
        return -value if math.isfinite(value) else math.inf

    lower, upper = (math.log(v) for v in DISTURBANCE_RANGE)
    if not index and disturbance is not None:
        return dict(levels), disturbance
    if not index:
        best = scipy.optimize.minimize_scalar(negative, bounds=(lower, upper), method="bounded",
                                              options={"xatol": 0.02})
        z = np.atleast_1d(best.x)
    else:
        torque = np.concatenate([np.asarray(r.input) for r in records])
        start = [math.log(1e-2 * float(np.sqrt(np.mean(torque**2))) + 1e-9)] * (
            disturbance is None)
        spread = [float(np.std(np.concatenate([r.channel(c) for r in records if c in r.columns])))
                  for c in free]
        start += [math.log(max(1e-2 * s, floors[i])) for s, i in zip(spread, index, strict=True)]
        best = scipy.optimize.minimize(negative, np.array(start), method="Nelder-Mead",
                                       options={"xatol": 0.02, "fatol": 0.1,
                                                "initial_simplex": _simplex(start)})
        z = np.clip(best.x, lower, upper) if disturbance is None else best.x
    sigma, tau = unpack(z)
    levels = dict(zip(channels, map(float, sigma), strict=True))
    if not best.success:
        shown = ", ".join(f"{c} {levels[c]:.4g}" for c in free)
        warnings.warn(f"the noise levels' maximum-likelihood search did not converge "
                      f"({' '.join(str(best.message).split())}); the filter uses where it ended: "
                      f"σ_τ {tau:.4g} N m{', ' + shown if shown else ''}", stacklevel=2)
    return levels, float(tau)


def _simplex(start: Sequence[float]) -> np.ndarray:
    """A Nelder–Mead start around ``start``: each coordinate a factor 10 up in turn."""
    vertices = np.tile(np.asarray(start, dtype=float), (len(start) + 1, 1))
    vertices[1:] += math.log(10.0) * np.eye(len(start))
    return vertices


def predict(
    records: Record | Sequence[Record],
    model: Model,
    params: Mapping[str, ArrayLike],
    horizons: Sequence[float] = (),
    *,
    channels: Sequence[str] | None = None,
    noise: Noise | None = None,
    disturbance: float | None = None,
    fit_measurement_noise: bool = True,
) -> list[Prediction]:
    """Run the Kalman filter of ``model`` at ``params`` over each record (as the model reads
    it: :func:`jaxflex.measured.model_record`) and predict ``horizons`` seconds ahead.

    ``channels`` default to the fitted ones. The process noise ``disturbance`` (``σ_τ``, N m)
    and, with ``fit_measurement_noise``, the measurement noise of every channel ``noise`` does
    not give are fitted by maximum likelihood over the records (:func:`fit_noise`, never below
    :func:`measurement_noise`, the sensors' own: on a real rig what the model misses adds to
    them); without it the channels keep :func:`measurement_noise`.
    """
    check_records(records, "predict")
    records = list(record_tuple(records))
    channels = fitted_channels(records, model) if channels is None else check_channels(
        channels, model)
    values = {k: jnp.asarray(v, dtype=jnp.float64) for k, v in params.items()}
    model.space.validate(values)
    check_per_sample(model, values, channels)
    steps = [horizon_steps(horizons, r.dt, [r]) for r in records]
    if disturbance is not None and not (math.isfinite(disturbance) and disturbance > 0):
        raise ValueError(f"disturbance must be a positive torque (N m), got {disturbance!r}")
    levels = measurement_noise(records, model, channels, noise)
    free = [c for c in channels if c not in dict(noise or {})] if fit_measurement_noise else []
    levels, disturbance = fit_noise(records, model, values, channels, levels, free, disturbance)
    sigma_y = jnp.asarray([levels[c] for c in channels])
    results = []
    for record, ks in zip(records, steps, strict=True):
        torque, measured, present = record_arrays(record, channels)
        run = _filter_jit(model, values, torque, measured, present, record.dt, tuple(channels),
                          sigma_y, jnp.asarray(disturbance))
        ahead = {}
        if ks:
            order = sorted(set(ks))
            out = np.asarray(_predict_jit(model, values, torque, run.states, record.dt,
                                          tuple(channels), tuple(order)))
            ahead = {h: out[order.index(k)] for h, k in zip(horizons, ks, strict=True)}
        results.append(Prediction(
            name=record.name, channels=tuple(channels), measured=np.asarray(measured),
            one_step=np.asarray(run.predicted), innovations=np.asarray(run.innovations),
            variance=np.asarray(run.variance), predicted=ahead, sigma_y=levels,
            disturbance=float(disturbance), log_likelihood=float(run.log_likelihood)))
    return results


__all__ = ["Filtered", "Prediction", "Update", "check_per_sample", "filter_core", "fit_noise",
           "horizon_steps", "log_likelihood", "measurement_noise", "measurement_update", "predict",
           "predict_core", "record_arrays", "step_and_output", "value_and_jacobian"]
