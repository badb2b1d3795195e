"""Optimal excitation: a Fourier-series torque that maximises the information about the parameters.

The paper excites the arm with a triangular, a pulse and a half-sine torque. For a nonlinear
simulation model the information an input carries about the parameters ``x`` is the Fisher
information of the simulated outputs ``y_c(t; x)`` (joint angle, tip acceleration) under the
sensors' white noise ``σ_c`` (encoder quantisation step/√12, accelerometer 0.05 m/s²),

    F = Σ_c Σ_t J_ctᵀ J_ct / σ_c²,        J_ct = ∂y_c(t) / ∂ log x     (``jax.jacfwd``),

and ``F⁻¹`` predicts the covariance of ``log x`` from one record: the relative 95 % half-width
of parameter ``i`` is ``1.96·√(F⁻¹)_ii``. The design maximises either

* ``D``: ``log det F`` (the volume of the confidence ellipsoid), or
* ``E``: ``log λ_min(F)`` (its longest axis: the worst-identified combination of parameters)

over the torque ``τ(t) = s·w(t)·Σ_k (a_k sin 2πkt/T + b_k cos 2πkt/T)``, ``k = 1..N`` (harmonics
of the record length ``T`` up to a maximum frequency), where ``w`` ramps up and down over
``ramp`` seconds so that the torque starts and ends at zero.

Constraints by scaling: ``s`` is the largest factor that keeps the peak torque and the RMS torque
within their limits, then reduced by a few fixed-point steps ``s ← s·min(1, A/max|θ|, S/max|θ'|)``
(each a simulation at the nominal parameters) until the joint angle and speed also fit — motion
under friction grows faster than proportionally with the torque, so the steps approach the limit
from above. The optimiser is normalised gradient ascent (reverse-mode through ``jacfwd``) with
backtracking: a step is taken only if the criterion increases and the simulated response meets
every limit, so the recorded criterion never decreases and every iterate is feasible. (The
simulator's implicit friction solve is differentiated exactly to first order only, so this
gradient of ``F`` is approximate — about 1 % off finite differences — which the acceptance
test on the exact criterion makes harmless.)

Coulomb friction ``tau_c·tanh(θ'/0.01)`` carries information almost only through the velocity
reversals, and viscous friction through sustained speed: the optimiser finds both.
"""

from __future__ import annotations

import math
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from statistics import NormalDist

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float

from jaxflex._arguments import positive
from jaxflex._progress import Progress
from jaxflex.data import Record
from jaxflex.drives import TorqueDrive
from jaxflex.model import Model
from jaxflex.noise import Noise, noise_levels
from jaxflex.parameters import Params
from jaxflex.signals import REFERENCE_AMPLITUDES, reference_input, time_grid
from jaxflex.simulation import (
    OUTPUT_NAMES,
    Outputs,
    check_torque,
    read_channels,
    simulate,
    simulate_core,
)
from jaxflex.synthetic import ACCELEROMETER_SIGMA, ENCODER_STEP

DEFAULT_NOISE: dict[str, float] = {
    "joint_angle": ENCODER_STEP / math.sqrt(12.0),
    "tip_acceleration": ACCELEROMETER_SIGMA,
}
"""Noise standard deviation of each measured output: encoder quantisation, accelerometer."""
CRITERIA: dict[str, str] = {"D": "log det F", "E": "log λ_min(F)"}
"""The design criteria and what each maximises."""
LIMITS: tuple[str, ...] = ("peak_torque", "rms_torque", "max_angle", "max_speed")
"""The limits a designed input must respect (see :data:`LIMIT_UNITS`)."""
LIMIT_UNITS: dict[str, str] = {
    "peak_torque": "N m",
    "rms_torque": "N m",
    "max_angle": "rad",
    "max_speed": "rad/s",
}
"""Unit of each limit."""
PAPER_INPUTS: tuple[str, ...] = tuple(REFERENCE_AMPLITUDES)
"""The paper's reference inputs, which :func:`paper_inputs` scales for comparison with a design."""
RESCALE_STEPS = 4
"""Fixed-point steps of the torque scale for the angle and speed limits."""
STEP_GROWTH = 1.5
"""Factor on the step after an accepted step (halved after each rejected one)."""
MAX_BACKTRACKS = 12
"""Step halvings tried before the ascent stops (a step 4096 times shorter than the last)."""


# --- information ---------------------------------------------------------------------------


def _check_noise(noise: Noise | None, model: Model) -> tuple[tuple[str, ...], np.ndarray]:
    """The channels the design weighs and their noise σ: outputs or the rig's sensor channels,
    each a white σ or a :class:`~jaxflex.noise.NoiseLevel` (:data:`~jaxflex.noise.Noise`)."""
    noise = DEFAULT_NOISE if noise is None else dict(noise)
    if not noise:
        raise ValueError("noise must name at least one output channel and its sigma")
    levels = noise_levels(noise, (*OUTPUT_NAMES, *model.channels))
    return tuple(levels), np.array([v.sigma for v in levels.values()], dtype=np.float64)


def _check_names(model: Model, params: Mapping[str, ArrayLike], names) -> tuple[str, ...]:
    names = tuple(model.space.names if names is None else names)
    unknown = [n for n in names if n not in model.space.names]
    if unknown or not names:
        raise ValueError(f"unknown parameter(s) {unknown}; known: {list(model.space.names)}")
    for n in names:
        if not float(params[n]) > 0:
            raise ValueError(
                f"parameter {n}={float(params[n])!r}: relative intervals need a positive value"
            )
    return names


def _fisher(model, params, names, torque, dt, channels, sigmas) -> tuple[Array, Outputs]:
    """``JᵀJ`` of the whitened outputs w.r.t. ``log x`` (forward mode: d tangents), and the
    simulated outputs themselves."""

    def whitened_outputs(log_values):
        values = dict(params) | {n: jnp.exp(log_values[i]) for i, n in enumerate(names)}
        out = simulate_core(model, values, torque, dt)
        y = read_channels(model, values, out, channels) / sigmas[:, None]
        return y.reshape(-1), out

    log_values = jnp.log(jnp.stack([params[n] for n in names]))
    jac, out = jax.jacfwd(whitened_outputs, has_aux=True)(log_values)
    return jac.T @ jac, out


@eqx.filter_jit
def _fisher_jit(model, params, torque, sigmas, names, dt, channels):
    return _fisher(model, params, names, torque, dt, channels, sigmas)[0]


def _nominal(model: Model, params: Mapping[str, ArrayLike] | None) -> Params:
    values = dict(model.space.reference())
    if params is not None:
        unknown = sorted(set(params) - set(model.space.names))
        if unknown:
            raise ValueError(f"unknown parameter(s) {unknown}; known: {list(model.space.names)}")
        values.update({k: jnp.asarray(v, dtype=jnp.float64) for k, v in params.items()})
    model.space.validate(values)
    return values


def fisher_information(
    model: Model | None,
    params: Mapping[str, ArrayLike] | None,
    torque: Float[ArrayLike, " n"],
    dt: float | None = None,
    noise: Noise | None = None,
    *,
    names: Sequence[str] | None = None,
) -> Float[np.ndarray, "d d"]:
    """Fisher information of one record about ``log x`` (``names``: default all parameters).

    ``noise`` maps each measured output to its noise σ (default :data:`DEFAULT_NOISE`).
    """
    model = Model() if model is None else model
    values = _nominal(model, params)
    names = _check_names(model, values, names)
    channels, sigmas = _check_noise(noise, model)
    dt = model.testbed.dt if dt is None else float(dt)
    torque = check_torque(torque)
    return np.asarray(
        _fisher_jit(model, values, jnp.asarray(torque), jnp.asarray(sigmas), names, dt, channels)
    )


def intervals_from_fisher(
    fisher: Float[ArrayLike, "d d"], names: Sequence[str], level: float = 0.95
) -> dict[str, float]:
    """Relative half-widths ``z·√(F⁻¹)_ii`` of the ``level`` intervals (``inf`` if unidentifiable).

    In ``log x`` the interval is ``x·exp(±z σ)``; its relative half-width is ``z σ`` to first
    order (e.g. 0.01 = ±1 %).
    """
    if not 0 < level < 1:
        raise ValueError(f"level={level!r} must be in (0, 1)")
    z = NormalDist().inv_cdf(0.5 + level / 2)
    fisher = np.asarray(fisher, dtype=np.float64)
    scale = np.sqrt(np.clip(np.diag(fisher), 1e-300, None))
    eigvals, eigvecs = np.linalg.eigh(fisher / np.outer(scale, scale))
    if eigvals[0] <= 1e-14 * eigvals[-1]:
        return {n: math.inf for n in names}
    variance = (eigvecs**2 / eigvals).sum(axis=1) / scale**2
    return {n: float(z * math.sqrt(v)) for n, v in zip(names, variance, strict=True)}


def predicted_intervals(
    model: Model | None,
    params: Mapping[str, ArrayLike] | None,
    torque: Float[ArrayLike, " n"],
    dt: float | None = None,
    noise: Noise | None = None,
    *,
    names: Sequence[str] | None = None,
    level: float = 0.95,
) -> dict[str, float]:
    """Predicted relative 95 % half-widths of each parameter from one record of ``torque``.

    Works for any input (the paper's three, a designed one, a measured torque), so comparing
    inputs is one call per input. ``params`` default to the model's reference values.
    """
    model = Model() if model is None else model
    names = tuple(model.space.names if names is None else names)
    fisher = fisher_information(model, params, torque, dt, noise, names=names)
    return intervals_from_fisher(fisher, names, level)


def response_limits(model: Model, params: Mapping[str, ArrayLike], torque, dt) -> dict[str, float]:
    """The four constrained quantities of an input, by simulation at ``params``."""
    torque = check_torque(torque)
    out = simulate(model, params, torque, dt)
    return {
        "peak_torque": float(np.max(np.abs(torque))),
        "rms_torque": float(np.sqrt(np.mean(torque**2))),
        "max_angle": float(np.max(np.abs(out.joint_angle))),
        "max_speed": float(np.max(np.abs(out.joint_velocity))),
    }


# --- the Fourier-series input ----------------------------------------------------------------


def fourier_basis(
    duration: float, dt: float, harmonics: int, ramp: float
) -> Float[np.ndarray, "2N n"]:
    """Rows ``w(t)·sin(2πkt/T)`` then ``w(t)·cos(2πkt/T)``, ``k = 1..N``, on ``time_grid``.

    ``w`` rises as ``sin²`` over the first ``ramp`` seconds and falls over the last.
    """
    t = time_grid(duration, dt)
    if not (isinstance(harmonics, (int, np.integer)) and harmonics >= 1):
        raise ValueError(f"harmonics={harmonics!r} must be an int >= 1")
    if not (math.isfinite(ramp) and 0 <= ramp <= duration / 2):
        raise ValueError(f"ramp={ramp!r} must be between 0 and half the duration ({duration / 2})")
    if harmonics / duration >= 0.5 / dt:
        raise ValueError(
            f"harmonics={harmonics} reach {harmonics / duration:g} Hz, above the Nyquist "
            f"frequency {0.5 / dt:g} Hz"
        )
    k = np.arange(1, harmonics + 1)[:, None]
    phase = 2 * np.pi * k * t[None, :] / duration
    edge = np.minimum(t, t[-1] - t)
    window = np.sin(0.5 * np.pi * np.clip(edge / ramp, 0, 1)) ** 2 if ramp > 0 else np.ones_like(t)
    return np.concatenate([np.sin(phase), np.cos(phase)]) * window


class _Problem(eqx.Module):
    """Everything the jitted criterion needs (arrays traced, structure static)."""

    model: Model
    params: Params
    basis: Float[Array, "2N n"]
    limits: Float[Array, " 4"]  # peak torque, RMS torque, max angle, max speed
    sigmas: Float[Array, " c"]
    names: tuple[str, ...] = eqx.field(static=True)
    channels: tuple[str, ...] = eqx.field(static=True)
    dt: float = eqx.field(static=True)
    criterion: str = eqx.field(static=True)


def _scaled_torque(problem: _Problem, c: Array) -> Array:
    """The feasible torque of coefficients ``c`` (see the module doc)."""
    shape = c @ problem.basis
    peak, rms, angle, speed = problem.limits
    scale = jnp.minimum(rms / jnp.sqrt(jnp.mean(shape**2)), peak / jnp.max(jnp.abs(shape)))

    # aim a hair inside the motion limits: another compiled simulation differs by round-off
    angle, speed = angle * (1.0 - 1e-6), speed * (1.0 - 1e-6)

    def rescale(_, scale):
        out = simulate_core(problem.model, problem.params, scale * shape, problem.dt)
        ratio = jnp.minimum(
            angle / jnp.max(jnp.abs(out.joint_angle)), speed / jnp.max(jnp.abs(out.joint_velocity))
        )
        return scale * jnp.minimum(1.0, ratio)

    return jax.lax.fori_loop(0, RESCALE_STEPS, rescale, scale) * shape


def _criterion_of_fisher(fisher: Array, criterion: str) -> Array:
    d = fisher.shape[0]
    ridge = 1e-12 * jnp.trace(fisher) / d  # keeps a singular F finite (no motion, no information)
    fisher = fisher + ridge * jnp.eye(d)
    if criterion == "D":
        return jnp.linalg.slogdet(fisher)[1]
    return jnp.log(jnp.linalg.eigvalsh(fisher)[0])


class _Evaluation(eqx.Module):
    """What one evaluation of a design yields besides the criterion."""

    torque: Float[Array, " n"]
    achieved: Float[Array, " 4"]  # peak torque, RMS torque, max |θ|, max |θ'|
    fisher: Float[Array, "d d"]
    response: Outputs


def _criterion(problem: _Problem, c: Array) -> tuple[Array, _Evaluation]:
    """Criterion of coefficients ``c``, with the torque, its limits, ``F`` and the response."""
    torque = _scaled_torque(problem, c)
    fisher, out = _fisher(
        problem.model,
        problem.params,
        problem.names,
        torque,
        problem.dt,
        problem.channels,
        problem.sigmas,
    )
    achieved = jnp.stack(
        [
            jnp.max(jnp.abs(torque)),
            jnp.sqrt(jnp.mean(torque**2)),
            jnp.max(jnp.abs(out.joint_angle)),
            jnp.max(jnp.abs(out.joint_velocity)),
        ]
    )
    value = _criterion_of_fisher(fisher, problem.criterion)
    return value, _Evaluation(torque, achieved, fisher, out)


# one compiled program per problem structure: value, gradient and everything else at once
_evaluate = eqx.filter_jit(jax.value_and_grad(_criterion, argnums=1, has_aux=True))


# --- the design --------------------------------------------------------------------------------


@dataclass(frozen=True)
class DesignResult:
    """A designed input and what it is predicted to achieve.

    ``history[i]`` is the criterion after ``i`` accepted steps (non-decreasing; shorter than
    ``iterations + 1`` if no further ascent step was found). ``intervals`` are the predicted
    relative 95 % half-widths at the nominal parameters; ``achieved`` the simulated peak and
    RMS torque, joint-angle range and speed, to compare with ``limits``.
    """

    time: Float[np.ndarray, " n"]
    torque: Float[np.ndarray, " n"]
    joint_angle: Float[np.ndarray, " n"]  # predicted response at the nominal parameters
    tip_acceleration: Float[np.ndarray, " n"]
    joint_velocity: Float[np.ndarray, " n"]
    coefficients: Float[np.ndarray, " 2N"]
    criterion: str
    history: Float[np.ndarray, " k"]
    intervals: dict[str, float]
    achieved: dict[str, float]
    limits: dict[str, float]
    nominal: dict[str, float]
    settings: dict[str, object] = field(default_factory=dict)
    wall_time: float = 0.0

    @property
    def worst(self) -> tuple[str, float]:
        """The worst-identified parameter and its predicted relative half-width."""
        name = max(self.intervals, key=self.intervals.__getitem__)
        return name, self.intervals[name]

    def to_record(self, name: str = "designed") -> Record:
        """The input as a record: torque plus the *predicted* (noise-free) response."""
        settings = ", ".join(f"{k}={v!r}" for k, v in self.settings.items())
        return Record(
            time=self.time,
            torque=self.torque,
            joint_angle=self.joint_angle,
            tip_acceleration=self.tip_acceleration,
            name=name,
            metadata={
                "note": "joint_angle and tip_acceleration are the model's predicted response "
                "at the nominal parameters, not measurements",
                "design": f"criterion {self.criterion}; {settings}",
                "nominal": ", ".join(f"{k}={v!r}" for k, v in self.nominal.items()),
            },
        )


def design_input(
    model: Model | None = None,
    params: Mapping[str, ArrayLike] | None = None,
    *,
    duration: float = 2.0,
    max_torque: float,
    rms_torque: float,
    max_angle: float,
    max_speed: float,
    criterion: str = "E",
    harmonics: int | None = None,
    max_frequency: float = 20.0,
    ramp: float = 0.1,
    iterations: int = 30,
    seed: int = 0,
    restarts: int = 1,
    noise: Noise | None = None,
    names: Sequence[str] | None = None,
    dt: float | None = None,
    progress: bool = False,
) -> DesignResult:
    """Design a torque record that maximises the information about the parameters.

    Limits: peak torque ``max_torque`` and RMS torque ``rms_torque`` (N m), joint angle within
    ``±max_angle`` (rad) and speed within ``max_speed`` (rad/s), checked by simulating at the
    nominal ``params`` (default: the model's reference values; the rigid estimate's values are a
    good choice for a new arm); a peak whose torque at the hub never exceeds the rig's breakaway
    friction (:meth:`~jaxflex.model.Model.breakaway_torque`) is refused. ``criterion`` is
    ``"D"`` or ``"E"`` (module doc); ``harmonics`` defaults to every harmonic of
    ``1/duration`` up to ``max_frequency`` Hz. Each start is a flat-spectrum multisine with
    random phases (start ``r`` draws them from ``numpy.random.default_rng((seed, r))``)
    followed by ``iterations`` ascent steps; the criterion has many local optima, so
    ``restarts`` starts are tried and the best is kept (``settings["start_values"]`` lists
    where each ended). ``progress`` reports the ascent of each start on stderr: a bar on a
    terminal or in Jupyter, else a line when it ends.
    """
    model = Model() if model is None else model
    values = _nominal(model, params)
    names = _check_names(model, values, names)
    channels, sigmas = _check_noise(noise, model)
    if criterion not in CRITERIA:
        raise ValueError(f"criterion={criterion!r}: choose one of {list(CRITERIA)}")
    dt = model.testbed.dt if dt is None else positive(dt, "dt")
    duration = positive(duration, "duration")
    limits = {
        "peak_torque": positive(max_torque, "max_torque"),
        "rms_torque": positive(rms_torque, "rms_torque"),
        "max_angle": positive(max_angle, "max_angle"),
        "max_speed": positive(max_speed, "max_speed"),
    }
    if limits["rms_torque"] > limits["peak_torque"]:
        raise ValueError(
            f"rms_torque={rms_torque!r} exceeds max_torque={max_torque!r}; the RMS of a torque "
            "cannot exceed its peak"
        )
    _check_moves(model, values, limits["peak_torque"])
    if harmonics is None:
        harmonics = int(math.floor(positive(max_frequency, "max_frequency") * duration + 1e-9))
    if not (isinstance(harmonics, (int, np.integer)) and 1 <= harmonics < duration / (2 * dt)):
        raise ValueError(
            f"harmonics={harmonics!r} must be an int >= 1 below the Nyquist frequency "
            f"({duration / (2 * dt):g} harmonics of 1/duration); raise max_frequency or duration"
        )
    if not (isinstance(iterations, (int, np.integer)) and iterations >= 0):
        raise ValueError(f"iterations={iterations!r} must be an int >= 0")
    if not (isinstance(seed, (int, np.integer)) and seed >= 0):
        raise ValueError(f"seed={seed!r} must be an int >= 0")
    if not (isinstance(restarts, (int, np.integer)) and restarts >= 1):
        raise ValueError(f"restarts={restarts!r} must be an int >= 1")
    basis = fourier_basis(duration, dt, harmonics, ramp)

    problem = _Problem(
        model=model,
        params=values,
        basis=jnp.asarray(basis),
        limits=jnp.asarray(list(limits.values())),
        sigmas=jnp.asarray(sigmas),
        names=names,
        channels=channels,
        dt=dt,
        criterion=criterion,
    )
    start = time.perf_counter()
    runs = []
    for r in range(restarts):
        phases = np.random.default_rng((seed, r)).uniform(0.0, 2.0 * np.pi, harmonics)
        c = jnp.asarray(np.concatenate([np.cos(phases), np.sin(phases)]))
        label = f"design {criterion}" + (f" start {r + 1}/{restarts}" if restarts > 1 else "")
        runs.append(
            _ascend(
                problem, c, iterations, Progress(range(iterations), label=label, enabled=progress)
            )
        )
    c, evaluation, history = max(runs, key=lambda run: run[2][-1])

    out = evaluation.response
    settings = {
        "duration": duration,
        "dt": dt,
        "harmonics": int(harmonics),
        "max_frequency_hz": harmonics / duration,
        "ramp": ramp,
        "iterations": int(iterations),
        "seed": int(seed),
        "restarts": int(restarts),
        "start_values": [run[2][-1] for run in runs],
        "noise": dict(zip(channels, sigmas.tolist(), strict=True)),
        "effects": list(model.effect_names),
    }
    return DesignResult(
        time=time_grid(duration, dt),
        torque=np.asarray(evaluation.torque),
        joint_angle=np.asarray(out.joint_angle),
        tip_acceleration=np.asarray(out.tip_acceleration),
        joint_velocity=np.asarray(out.joint_velocity),
        coefficients=np.asarray(c),
        criterion=criterion,
        history=np.asarray(history),
        intervals=intervals_from_fisher(np.asarray(evaluation.fisher), names),
        achieved=dict(zip(LIMITS, np.asarray(evaluation.achieved).tolist(), strict=True)),
        limits=limits,
        nominal={k: float(v) for k, v in values.items()},
        settings=settings,
        wall_time=time.perf_counter() - start,
    )


def _check_moves(model: Model, values: Params, max_torque: float) -> None:
    """Refuse a peak limit whose torque at the hub (through the drive, within its saturation)
    never exceeds the breakaway friction: no input within it moves the hub."""
    hub = abs(float(model.drive.torque(jnp.asarray(max_torque))))
    breakaway = model.breakaway_torque(values)
    if hub <= breakaway:
        through = "" if isinstance(model.drive, TorqueDrive) else f" ({hub:.3g} N m at the hub)"
        raise ValueError(
            f"max_torque={max_torque:g}{through} never exceeds the joint's breakaway friction "
            f"torque {breakaway:.3g} N m: no input within it moves the hub; raise it"
        )


def _ascend(problem: _Problem, c: Array, iterations: int, bar: Progress):
    """Normalised gradient ascent on the sphere ``|c| = const`` with backtracking (module doc).

    Returns the final coefficients, their evaluation and the criterion after each step.
    """
    radius = float(jnp.linalg.norm(c))
    (value, evaluation), grad = _evaluate(problem, c)
    if not _feasible(evaluation.achieved, problem.limits):
        limits = dict(zip(LIMITS, np.asarray(problem.limits).tolist(), strict=True))
        raise ValueError(
            "the start of the design violates a limit after scaling: "
            f"{_describe(evaluation.achieved, limits)}; loosen max_angle or max_speed"
        )
    history = [float(value)]
    step = 0.3
    for _ in bar:
        direction = grad * (radius / jnp.maximum(jnp.linalg.norm(grad), 1e-300))
        for _ in range(MAX_BACKTRACKS):
            trial = c + step * direction
            trial = trial * (radius / jnp.linalg.norm(trial))  # the scale is free: stay on a sphere
            (value, trial_evaluation), trial_grad = _evaluate(problem, trial)
            value = float(value)
            if value > history[-1] and _feasible(trial_evaluation.achieved, problem.limits):
                break
            step *= 0.5
        else:
            break  # no ascent step: a (local) optimum
        c, evaluation, grad = trial, trial_evaluation, trial_grad
        history.append(value)
        step = min(STEP_GROWTH * step, 1.0)
        bar.set_message(f"{problem.criterion} {history[-1]:.4g}")
    return c, evaluation, history


def _feasible(achieved: Array, limits: Array) -> bool:
    return bool(jnp.all(achieved <= limits * (1.0 + 1e-9)))


def _describe(achieved, limits: Mapping[str, float]) -> str:
    return ", ".join(
        f"{k} {float(a):.4g} (limit {lim:.4g} {LIMIT_UNITS[k]})"
        for (k, lim), a in zip(limits.items(), achieved, strict=True)
    )


# --- comparison with the paper's inputs ----------------------------------------------------------


def paper_inputs(
    rms_torque: float, duration: float = 2.0, dt: float = 1e-3
) -> dict[str, Float[np.ndarray, " n"]]:
    """The paper's triangular, pulse and half-sine torques, each scaled to ``rms_torque``."""
    rms_torque = positive(rms_torque, "rms_torque")
    inputs = {}
    for name in PAPER_INPUTS:
        _, torque = reference_input(name, duration=duration, dt=dt)
        inputs[name] = torque * rms_torque / np.sqrt(np.mean(torque**2))
    return inputs


def compare_inputs(
    inputs: Mapping[str, ArrayLike],
    model: Model | None = None,
    params: Mapping[str, ArrayLike] | None = None,
    dt: float | None = None,
    noise: Noise | None = None,
    *,
    names: Sequence[str] | None = None,
) -> dict[str, dict[str, dict[str, float]]]:
    """For each named input: predicted ``intervals`` and simulated ``achieved`` limits."""
    model = Model() if model is None else model
    values = _nominal(model, params)
    dt = model.testbed.dt if dt is None else dt
    return {
        name: {
            "intervals": predicted_intervals(model, values, torque, dt, noise, names=names),
            "achieved": response_limits(model, values, torque, dt),
        }
        for name, torque in inputs.items()
    }


def interval_table(comparison: Mapping[str, Mapping[str, Mapping[str, float]]]) -> str:
    """A text table of predicted relative 95 % half-widths (%) per input, worst last column."""
    rows = list(comparison.items())
    names = list(rows[0][1]["intervals"])
    header = f"{'input':<12}" + "".join(f"{n:>10}" for n in names) + f"{'worst':>10}"
    header += "rms N m".rjust(9) + "|θ| rad".rjust(9) + "|θ'| r/s".rjust(10)
    lines = ["predicted 95 % half-widths, % of the value", header]
    for label, entry in rows:
        iv, ach = entry["intervals"], entry["achieved"]
        cells = "".join(f"{100 * iv[n]:>10.3g}" for n in names)
        lines.append(
            f"{label:<12}{cells}{100 * max(iv.values()):>10.3g}{ach['rms_torque']:>9.3g}"
            f"{ach['max_angle']:>9.3g}{ach['max_speed']:>10.3g}"
        )
    return "\n".join(lines)


__all__ = [
    "CRITERIA",
    "DEFAULT_NOISE",
    "LIMITS",
    "PAPER_INPUTS",
    "DesignResult",
    "compare_inputs",
    "design_input",
    "fisher_information",
    "fourier_basis",
    "interval_table",
    "intervals_from_fisher",
    "paper_inputs",
    "predicted_intervals",
    "response_limits",
]
