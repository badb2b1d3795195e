"""Records that do not start at rest: their initial state, estimated or periodic.

A record logged mid-motion (a closed loop's continuous log, a window cut mid-run, a sine in
steady state) starts from a state the simulation must be told. Its coordinates are

    z = [θ₀, θ'₀, η_1 … η_k, η'_1 … η'_k],

the joint angle and velocity and the ``k`` lowest flexible modes' coordinates and velocities
(mass-normalised), all as deviations from rest under the loads; the other advanced modes start
at their quasi-static response to the first sample's joint torque (``η_j = p_j u₀/ω_j²``, the
mode-acceleration method), which is where a mode far above the input's band sits.

Three options (:data:`INITIAL_STATES`):

* ``rest``: ``z = 0``, the simulator's default;
* ``estimate``: for given parameters, ``z`` minimises the record's own residuals, by
  Gauss–Newton (:func:`estimate_state`) from the angle and velocity its first samples show.
  The state enters the modal step linearly (only the friction bends it: at a stick it hides
  the velocity, hence that start), so a few steps reach it, each ``2 + 2k`` forward columns.
  The objective stays a function of the parameters alone (variable projection), and the
  evolutionary search and the refinement run on it unchanged;
* ``periodic``: the cyclic steady state of a periodic input, ``x(P) = x(0)`` over the input's
  period ``P`` (:func:`input_period`) for the velocity and the modes, by Newton; the angle, a
  free rigid-body coordinate, then by least squares (:func:`periodic_state`).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Collection, Mapping
from typing import TYPE_CHECKING

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float
from scipy.special import ndtri

from jaxflex.data import Record
from jaxflex.modal import free_hub_modes
from jaxflex.model import Model
from jaxflex.parameters import Params
from jaxflex.simulation import Dynamics, InitialState, Outputs, model_dynamics, simulate_core

if TYPE_CHECKING:
    from jaxflex.objective import Objective

INITIAL_STATES: tuple[str, ...] = ("rest", "estimate", "periodic")
"""Where a record's simulation starts: at rest, at an estimated state, in periodic steady
state."""
DEFAULT_MODES = 2
"""Flexible modes whose coordinates an estimated or periodic start sets (the lowest ones)."""
GAUSS_NEWTON_STEPS = 6
"""Gauss–Newton (Newton, for ``periodic``) steps from rest; only the last is differentiated."""
LEVENBERG = 1e-9
"""Relative damping of each step (columns scaled to unit norm): an unobservable coordinate (the
angle of a record without an angle channel) stays where it is."""
JOIN_STEPS = 3.0
"""A record is one whole period of its input if the jump from its last sample to its first is
within this many times the RMS of its sample-to-sample steps."""
GUESS_WINDOW = 0.02
"""Seconds at a record's start whose angle gives the estimate its starting angle and velocity."""
REPEAT_TOLERANCE = 1e-3
"""An input repeats after ``P`` samples where its change over ``P`` has an RMS below this
fraction of its own (logged inputs keep 6–9 significant digits)."""


def check_initial_state(option: str) -> str:
    """``option`` when it is one of :data:`INITIAL_STATES`, else a one-line ValueError."""
    if option not in INITIAL_STATES:
        raise ValueError(f"initial_state must be one of {', '.join(INITIAL_STATES)}; "
                         f"got {option!r}")
    return option


def check_initial_modes(modes: int, model: Model) -> int:
    """The number of modes an initial state sets: a whole number from 0 to the advanced modes."""
    if isinstance(modes, bool) or not isinstance(modes, (int, np.integer)) or not (
            0 <= modes <= model.advanced_modes):
        raise ValueError(f"initial_modes must be a whole number from 0 to the "
                         f"{model.advanced_modes} modes rig {model.name!r} advances; "
                         f"got {modes!r}")
    return int(modes)


def coordinate_names(modes: int) -> tuple[str, ...]:
    """Names of the coordinates ``z`` (module doc) for ``modes`` modes."""
    return ("angle", "velocity", *(f"modal_{j + 1}" for j in range(modes)),
            *(f"modal_velocity_{j + 1}" for j in range(modes)))


def coordinate_units(modes: int) -> tuple[str, ...]:
    """Units of the coordinates ``z`` (modal coordinates are mass-normalised)."""
    return ("rad", "rad/s", *("kg^0.5 m",) * modes, *("kg^0.5 m/s",) * modes)


# ------------------------------------------------------------------------------ record checks


def input_period(record: Record) -> int:
    """The period of ``record``'s input, in samples, for a ``periodic`` start.

    The smallest lag past the input's first decorrelation after which it repeats
    (:data:`REPEAT_TOLERANCE`); a record whose input repeats nowhere within it counts as one
    whole period when its end joins its start like its own steps (within :data:`JOIN_STEPS`
    times their RMS). Otherwise a one-line ValueError naming the record.
    """
    u = np.asarray(record.input, dtype=np.float64)
    centred = u - np.mean(u)
    n = u.size
    power = float(np.sum(centred**2))
    if power == 0.0:
        return 1  # a constant input: the steady state of one sample is that of any
    spectrum = np.fft.rfft(centred, 2 * n)
    autocorrelation = np.fft.irfft(spectrum * np.conj(spectrum))[:n]
    squares = np.cumsum(centred**2)
    lags = np.arange(1, n // 2 + 1)
    tail = power - squares[lags - 1]  # Σ_{t ≥ P} u_t²
    head = squares[n - lags - 1]  # Σ_{t < n − P} u_t²
    change = np.maximum(tail + head - 2.0 * autocorrelation[lags], 0.0) / (n - lags)
    relative = np.sqrt(change / (power / n))
    decorrelated = np.flatnonzero(relative > 1.0)
    if decorrelated.size:
        repeats = np.flatnonzero(relative[decorrelated[0]:] <= REPEAT_TOLERANCE)
        for lag in lags[decorrelated[0] + repeats]:
            exact = np.sqrt(np.mean((u[lag:] - u[:-lag]) ** 2)) / np.sqrt(power / n)
            if exact <= REPEAT_TOLERANCE:
                return int(lag)
    jump, steps = abs(u[0] - u[-1]), float(np.sqrt(np.mean(np.diff(u) ** 2)))
    if jump <= JOIN_STEPS * steps:
        return n
    raise ValueError(
        f"record {record.name!r}: initial_state 'periodic' needs a periodic input, but its "
        f"{record.input_name!r} repeats nowhere within the record and its end does not join "
        f"its start (a jump of {jump:.6g} against steps of {steps:.6g} rms)"
    )


def check_record_length(record: Record, model: Model, modes: int, option: str) -> None:
    """A one-line ValueError unless ``record`` can hold an estimated start: more samples than
    four per coordinate, and one period of the lowest mode (at the rig's reference
    parameters): a shorter record cannot tell that mode's displacement from its velocity or
    from the rigid motion."""
    n_coordinates = 2 + 2 * modes
    need = 4 * n_coordinates
    if record.n_samples < need:
        raise ValueError(f"record {record.name!r} ({record.n_samples} samples) is too short for "
                         f"initial_state {option!r}: its {n_coordinates} coordinates need at "
                         f"least {need} samples")
    if modes == 0:
        return
    params = model.space.reference() | model.fixed_values
    omega = float(free_hub_modes(model.structure(params)).omega[0])
    period = 2.0 * math.pi / omega
    duration = record.n_samples * record.dt
    if duration < period:
        raise ValueError(
            f"record {record.name!r} ({duration:.4g} s) is too short for initial_state "
            f"{option!r} with {modes} modes: it must span one period of the lowest mode "
            f"({period:.4g} s at the rig's reference parameters); give a longer record or "
            "set 0 initial modes"
        )


STILL_FRACTION = 0.02
"""A channel that is zero and still at rest moves, at a record's start, where its value or
its change over :data:`GUESS_WINDOW` exceeds this fraction of its range (and
:data:`STILL_SIGMAS` of its noise)."""
STILL_SIGMAS = 4.0
"""...and this many standard deviations of its noise: the sensor's stated noise and
quantisation, or the scatter about the fit where that is larger (``±4σ``, as a rest band)."""


def why_not_still(record: Record, model: Model, channels: tuple[str, ...]) -> str | None:
    """Why ``record`` does not start at rest, in words naming it and what moved, or None.

    Only channels that read zero and stand still at rest count (angles, velocities,
    deflections, strains; not accelerations or torques, which the input moves at once): a
    quadratic over the first :data:`GUESS_WINDOW` seconds gives each one's start (unless the
    model reads the channel with an offset of its own) and slope, which count where they
    exceed both :data:`STILL_FRACTION` of the channel's range and :data:`STILL_SIGMAS` of its
    noise.
    """
    from jaxflex.sensors import Accelerometer

    still = [c for c in channels if c in record.columns and c not in (
        "tip_acceleration", "joint_torque") and not (
        c in model.channels and isinstance(model.sensor(c), Accelerometer))]
    t = record.time - record.time[0]
    early = t <= GUESS_WINDOW
    if np.count_nonzero(early) < 5:
        early = np.arange(t.size) < 5
    moved = []
    for c in still:
        y = record.channel(c)
        span = float(np.ptp(y))
        if not span > 0:
            continue
        coef = np.polynomial.polynomial.polyfit(t[early], y[early], 2)
        start, slope = coef[:2]
        window = float(t[early][-1])
        scatter = y[early] - np.polynomial.polynomial.polyval(t[early], coef)
        sigma = max(float(np.sqrt(np.mean(scatter**2))),
                    model.sensor(c).noise_std if c in model.channels else 0.0)
        limit = max(STILL_FRACTION * span, STILL_SIGMAS * sigma)
        if f"sensor_offset:{c}" in model.effect_names:
            start = 0.0  # the model reads it off zero at rest: only its slope counts
        if abs(start) > limit or abs(slope) * window > limit:
            moved.append(f"{c} starts at {start:.4g}, changing at {slope:.4g}/s")
    if not moved:
        return None
    return (f"record {record.name!r} does not start at rest ({'; '.join(moved)}) but is fitted "
            "from rest: give initial_state 'estimate' (or 'periodic' for a periodic input)")


# ------------------------------------------------------------------------------ simulation


def start_state(dynamics: Dynamics, model: Model, params: Params, first_torque: Array,
                z: Float[Array, " c"], modes: int) -> InitialState:
    """The :class:`InitialState` of coordinates ``z`` (module doc): the modes above the ``k``
    given ones at their quasi-static response to the joint torque of the first sample."""
    system = dynamics.system
    u0 = first_torque - model.friction(params, z[1])
    static = system.hub[modes:] * u0 / system.omega2[modes:]
    modal = jnp.concatenate([z[2 : 2 + modes], static])
    modal_velocity = jnp.concatenate([z[2 + modes :], jnp.zeros_like(static)])
    return InitialState(z[0], z[1], modal, modal_velocity)


def simulate_from(model: Model, params: Params, torque: Float[Array, " n"], dt: float,
                  z: Float[Array, " c"], modes: int) -> Outputs:
    """The outputs of one record simulated from coordinates ``z``."""
    dynamics = model_dynamics(model, params, dt)
    first = dynamics.fine_torque(torque)[0, 0]
    initial = start_state(dynamics, model, params, first, z, modes)
    return simulate_core(model, params, torque, dt, initial=initial)


def _value_and_jacobian(fn: Callable[[Array], Array], z: Array) -> tuple[Array, Array]:
    """``fn(z)`` and its Jacobian by forward columns (one batched call)."""
    def column(tangent):
        return jax.jvp(fn, (z,), (tangent,))

    values, columns = jax.vmap(column)(jnp.eye(z.shape[0], dtype=z.dtype))
    return values[0], columns.T


def _gauss_newton_step(fn: Callable[[Array], Array], z: Array) -> Array:
    """One Gauss–Newton step on ``|fn(z)|²`` (Newton for a square system), columns scaled."""
    r, jac = _value_and_jacobian(fn, z)
    return z - _least_squares(jac, r)


def _least_squares(jac: Array, r: Array) -> Array:
    """``x`` minimising ``|jac·x − r|²``, columns scaled to unit norm, with the relative
    :data:`LEVENBERG` damping (a zero column gets zero)."""
    norms = jnp.sqrt(jnp.sum(jac**2, axis=0))
    safe = jnp.where(norms > 0.0, norms, 1.0)
    scaled = jac / safe
    normal = scaled.T @ scaled + LEVENBERG * jnp.eye(jac.shape[1], dtype=jac.dtype)
    return jnp.linalg.solve(normal, scaled.T @ r) / safe


def gauss_newton(fn: Callable[[Array, Params], Array], z: Array, params: Params,
                 steps: int = GAUSS_NEWTON_STEPS) -> Array:
    """``z`` after ``steps`` Gauss–Newton steps on ``fn(·, params)``, compiled as one loop and a
    last step; derivatives with respect to ``params`` pass through the last step only, taken
    from the converged point (the implicit function's derivative, to first order)."""
    held = jax.lax.stop_gradient(params)
    z = jax.lax.fori_loop(0, steps - 1,
                          lambda _, z: _gauss_newton_step(lambda z: fn(z, held), z),
                          jax.lax.stop_gradient(z))
    return _gauss_newton_step(lambda z: fn(z, params), z)


def rigid_guess(residual: Callable[[Array, Params], Array], params: Params, modes: int,
                time: Float[Array, " n"], window: float = GUESS_WINDOW) -> Float[Array, " c"]:
    """A start for the estimate: the joint angle and velocity that the first ``window``
    seconds of the record show, by least squares on ``θ₀ + θ'₀·t + a·t²/2`` read through the
    residuals' response to the angle (nothing where no channel reads the angle). Near a stick
    phase friction hides the velocity from the Jacobian at rest; an angle's slope does not."""
    held = jax.lax.stop_gradient(params)
    zero = jnp.zeros(2 + 2 * modes)
    direction = zero.at[0].set(1.0)
    r, column = jax.jvp(lambda z: residual(z, held), (zero,), (direction,))
    n = time.shape[0]
    channels = r.shape[0] // n
    t = jnp.tile(time, channels)
    early = jnp.tile(time <= time[0] + window, channels)
    basis = jnp.stack([column, column * t, 0.5 * column * t**2], axis=1) * early[:, None]
    fit = -_least_squares(basis, r * early)
    return zero.at[0].set(fit[0]).at[1].set(fit[1])


def estimate_state(residual: Callable[[Array, Params], Array], params: Params, modes: int,
                   time: Float[Array, " n"]) -> Float[Array, " c"]:
    """The coordinates ``z`` that minimise a record's residuals ``residual(z, params)``, from
    the angle and velocity its first samples show (:func:`rigid_guess`)."""
    return gauss_newton(residual, rigid_guess(residual, params, modes, time), params)


def periodic_state(model: Model, params: Params, torque: Float[Array, " n"], dt: float,
                   modes: int, period: int,
                   residual: Callable[[Array, Params], Array]) -> Float[Array, " c"]:
    """The coordinates ``z`` of the cyclic steady state under ``torque`` (period ``period``
    samples): velocity and modes from ``x(P) = x(0)``, then the angle from ``residual``."""

    def gap(w, params):
        dynamics = model_dynamics(model, params, dt)
        fine = dynamics.fine_torque(torque)
        m = dynamics.system.hub.shape[0]
        z = jnp.concatenate([jnp.zeros(1), w])
        state = dynamics.start(start_state(dynamics, model, params, fine[0, 0], z, modes))
        end, _ = jax.lax.scan(lambda s, taus: (dynamics.advance(s, taus), None), state,
                              fine[:period])
        vector = dynamics.to_vector(end)
        after = jnp.concatenate([end[4][None],
                                 vector[2 : 2 + modes] - dynamics.system.initial[1][:modes],
                                 vector[2 + m : 2 + m + modes]])
        return after - w

    w = gauss_newton(gap, jnp.zeros(1 + 2 * modes), params)
    angle = gauss_newton(lambda a, p: residual(jnp.concatenate([a, w]), p), jnp.zeros(1),
                         params)
    return jnp.concatenate([angle, w])


def _by_record(objective: Objective, states: tuple[Array, ...]) -> dict[str, np.ndarray]:
    """The per-group rows of ``states`` by record name."""
    order = [i for group in objective.groups for i in group]
    rows = np.concatenate([np.asarray(z) for z in states])
    return {objective.record_names[i]: row for i, row in zip(order, rows, strict=True)}


def record_states(model: Model, params: Mapping[str, float], records, channels, option: str,
                  modes: int = DEFAULT_MODES) -> dict[str, np.ndarray]:
    """Each record's coordinates at ``params``, by name, started by ``option`` (``estimate``
    or ``periodic``) over the given ``channels``: a held-out record's start."""
    from jaxflex.objective import build_objective

    free = next(n for n in model.space.names if n not in model.fixed_values)
    held = {n: float(v) for n, v in params.items() if n != free and n in model.space.names}
    objective = build_objective(records, model, channels=channels, fixed=held,
                                initial_state=option, initial_modes=modes)
    return _by_record(objective, eqx.filter_jit(objective.initial_states)(
        {free: float(params[free])}))


_simulate_from_jit = eqx.filter_jit(simulate_from)


def simulate_record(model: Model, params: Mapping[str, float], record: Record,
                    z: Float[np.ndarray, " c"]) -> Outputs:
    """The outputs of ``record``'s input from coordinates ``z`` (their length gives the modes
    they set), the effects' calibrations applied."""
    from jaxflex.sensors import calibrated

    values = {k: jnp.asarray(float(v)) for k, v in params.items()}
    z = jnp.asarray(z, dtype=float)
    out = _simulate_from_jit(model, values, jnp.asarray(record.input), record.dt, z,
                             (z.shape[0] - 2) // 2)
    return calibrated(model, dict(params), out)


LEAD_IN_PERIODS = 2.0
"""A held-out record's state is estimated from its first this many periods of the model's
lowest flexible mode (:func:`lead_in`): long enough to tell that mode's displacement from its
velocity, short enough that the rest of the record is predicted, not fitted."""
MIN_LEAD_IN = 0.2
"""The shortest lead-in (s), for a stiff link whose lowest mode rings fast."""


def lead_in(model: Model, params: Mapping[str, float], record: Record, modes: int) -> float:
    """The span (s) at ``record``'s start from which its state is estimated when it is held
    out: :data:`LEAD_IN_PERIODS` periods of the lowest free-hub mode at ``params`` (at least
    :data:`MIN_LEAD_IN` s and four samples per coordinate), at most half the record."""
    values = {k: float(v) for k, v in params.items()}
    omega = float(free_hub_modes(model.structure(values)).omega[0])
    span = max(LEAD_IN_PERIODS * 2.0 * math.pi / omega, MIN_LEAD_IN,
               4 * (2 + 2 * modes) * record.dt)
    return min(span, 0.5 * record.duration)


def started_states(model: Model, params: Mapping[str, float], records, channels,
                   option: str = "rest", modes: int = DEFAULT_MODES,
                   states: Mapping[str, Float[np.ndarray, " c"]] | None = None,
                   held_out: Collection[str] = (),
                   ) -> tuple[dict[str, np.ndarray], dict[str, float]]:
    """Where each record starts: its coordinates in ``states`` where given (a fit's own),
    else its state under ``option`` (``estimate`` or ``periodic``) over those of ``channels``
    it logs; none at rest. A record named in ``held_out`` has its state estimated from its
    :func:`lead_in` alone, so that the rest of it is predicted, not fitted. Returns the
    coordinates and the lead-ins (s) by name."""
    states = {k: np.asarray(v, dtype=float) for k, v in (states or {}).items()}
    spans: dict[str, float] = {}
    if option != "rest":
        for record in records:
            if record.name not in states:
                own = [c for c in channels if c in record.columns]
                span = (lead_in(model, params, record, modes)
                        if option == "estimate" and record.name in held_out else None)
                part = record if span is None else record.trim(t_end=record.time[0] + span)
                states |= record_states(model, params, [part], own, option, modes)
                if span is not None:
                    spans[record.name] = span
    return states, spans


def simulate_started(model: Model, params: Mapping[str, float], records, channels,
                     option: str = "rest", modes: int = DEFAULT_MODES,
                     states: Mapping[str, Float[np.ndarray, " c"]] | None = None,
                     held_out: Collection[str] = (),
                     ) -> tuple[Outputs, ...]:
    """Each record's readings at ``params`` from where it starts (:func:`started_states`)."""
    from jaxflex.simulation import simulate_readings

    states, _ = started_states(model, params, records, channels, option, modes, states,
                               held_out)
    return tuple(
        simulate_record(model, params, r, states[r.name]) if r.name in states
        else simulate_readings(model, params, r.input, dt=r.dt)
        for r in records
    )


def initial_state_report(
    objective: Objective, estimate: Mapping[str, float], noise: Mapping[str, float] | None,
    level: float, finite: bool = True,
) -> tuple[dict[str, dict[str, float]], dict[str, dict[str, tuple[float, float]]]]:
    """Each record's initial coordinates at ``estimate``, by name, and their ``level``
    intervals (none without ``noise``): from the Jacobian in the free parameters and every
    record's coordinates together, so that they carry the parameters' uncertainty too. Empty
    at rest, or where the fit is not ``finite``."""
    if objective.initial_state == "rest" or not finite:
        return {}, {}
    free = {n: float(estimate[n]) for n in objective.names}
    states = eqx.filter_jit(objective.initial_states)(free)
    names = coordinate_names(objective.initial_modes)
    order = [i for group in objective.groups for i in group]
    flat = np.concatenate([np.asarray(z) for z in states]).reshape(-1)
    values = {r: dict(zip(names, map(float, z), strict=True))
              for r, z in _by_record(objective, states).items()}
    if noise is None:
        return values, {}
    sizes = [int(z.shape[0]) for z in states]

    def residuals(x, z):
        params = dict(zip(objective.names, x, strict=True))
        rows = jnp.split(z.reshape(len(order), -1), np.cumsum(sizes)[:-1])
        return objective.residuals_from(params, rows)

    x = jnp.asarray([free[n] for n in objective.names])
    jac_x, jac_z = eqx.filter_jit(jax.jacfwd(residuals, argnums=(0, 1)))(x, jnp.asarray(flat))
    jac = np.hstack([np.asarray(jac_x), np.asarray(jac_z)])
    _, channel, scale = objective.layout()
    sigma = np.array([noise[c] for c in objective.channels])
    norms = np.linalg.norm(jac, axis=0)
    norms = np.where(norms > 0, norms, 1.0)
    scaled = jac / norms
    inverse = np.linalg.pinv(scaled.T @ scaled, rcond=1e-13, hermitian=True)
    meat = (scaled * ((sigma[channel] * scale) ** 2)[:, None]).T @ scaled
    std = np.sqrt(np.maximum(np.diag(inverse @ meat @ inverse), 0.0)) / norms
    half = float(ndtri(0.5 + 0.5 * level)) * std[len(objective.names):]
    intervals = {
        objective.record_names[i]: {
            n: (v - h, v + h)
            for n, v, h in zip(names, z, row, strict=True)
        }
        for i, z, row in zip(order, flat.reshape(len(order), -1),
                             half.reshape(len(order), -1), strict=True)
    }
    return values, intervals


def state_lines(states: Mapping[str, Mapping[str, float]],
                intervals: Mapping[str, Mapping[str, tuple[float, float]]]) -> list[str]:
    """One line per record: its initial coordinates, each with its interval's half-width."""
    lines = []
    for record, z in states.items():
        within = intervals.get(record, {})
        units = dict(zip(z, coordinate_units((len(z) - 2) // 2), strict=True))
        parts = [f"{n} {v:.5g}" + (f" ±{0.5 * (within[n][1] - within[n][0]):.2g}"
                                   if n in within else "") + f" {units[n]}"
                 for n, v in z.items()]
        lines.append(f"initial state of {record!r}: " + ", ".join(parts))
    return lines


__all__ = ["DEFAULT_MODES", "INITIAL_STATES", "check_initial_modes", "check_initial_state",
           "check_record_length", "coordinate_names", "coordinate_units", "estimate_state",
           "gauss_newton", "initial_state_report", "input_period", "periodic_state",
           "lead_in", "record_states", "simulate_from", "simulate_record", "simulate_started",
           "start_state", "started_states",
           "state_lines", "why_not_still"]
