"""A physically consistent first estimate of the hub dynamics, by convex least squares.

Below its first flexible mode the arm turns as one rigid body, and the joint torque balance

    tau = J_tot·θ'' + b_v·θ' + tau_c·sgn(θ') + c

is *linear* in ``x = (J_tot, b_v, tau_c, c)`` (``c``: an optional torque offset). As in the dVRK
identification package, ``x`` is fitted by weighted least squares to the joint angle, filtered and
differentiated, under physical consistency constraints

    J_tot ≥ rhoA·L³/3  (so the hub inertia J_h = J_tot − rhoA·L³/3 ≥ 0),  b_v ≥ 0,  tau_c ≥ 0,

a box-constrained convex quadratic program (solved with ``jaxopt.ProjectedGradient``, then
polished on its active set so that the result is exact to round-off).

Signal processing (per record), with ``L`` the zero-phase Butterworth low-pass at ``cutoff_hz``:

* ``θ'`` and ``θ''`` are differences of ``L(θ)`` (the encoder angle is quantised to 2π/4096, so
  the cutoff must sit well below the first flexible mode *and* remove the quantisation noise);
* the sign regressor is ``L(s)`` with ``s = sgn(L(θ)')`` outside the dead band
  ``|L(θ)'| ≤ deadband`` and ``s = 0`` inside it, and the fitted torque is ``L(tau)``: every
  column passes through the same linear filter, so the filtered equation holds exactly where the
  unfiltered one does (filtering only the angle would smear a torque step into a bias);
* while the joint sticks (dead band) static friction balances any ``|tau| < tau_c``, which the
  regression model cannot express; those samples, and every sample within ``guard`` seconds of
  one (the filter spreads the stuck samples' torque that far) or of either end of the record
  (the filter's end extension bends the second derivative there), get zero weight.

The estimate seeds the evolutionary search (:func:`warm_start`) and is the first, rigid rung of
the model ladder (:func:`rigid_simulate`). It is biased when the link vibrates strongly below the
cutoff or when the record holds little motion: see ``tests/test_rigid.py``.
"""

from __future__ import annotations

import dataclasses
import math
import warnings
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float

from jaxflex.data import Dataset, Record
from jaxflex.parameters import ParameterSpace
from jaxflex.preprocess import differentiate, lowpass
from jaxflex.simulation import Outputs, check_dt, check_torque, with_readings
from jaxflex.testbed import Testbed

if TYPE_CHECKING:
    from jaxflex.model import Model

DEFAULT_CUTOFF_HZ = 4.0
"""Low-pass cutoff (Hz): half the reference arm's first free-hub mode (8.4 Hz)."""
DEFAULT_DEADBAND = 0.05
"""Joint speed (rad/s) below which the joint is taken to stick."""
COLUMNS: tuple[str, ...] = ("J_tot", "b_v", "tau_c", "offset")
"""Unknowns: total inertia (kg m²), viscous (N m s), Coulomb friction and offset (N m)."""
CONSTRAINTS: dict[str, str] = {
    "J_tot": "J_h >= 0 (J_tot >= rhoA L^3/3)",
    "b_v": "b_v >= 0",
    "tau_c": "tau_c >= 0",
}
"""The physical bound each unknown must satisfy, as text for the report."""
_MIN_SAMPLES_PER_COLUMN = 10

Records = Dataset | Record | Iterable[Record]
"""What the rigid-body fit accepts: a data set, one record or records."""


@dataclass(frozen=True)
class RigidEstimate:
    """Rigid-body hub dynamics fitted by constrained weighted least squares.

    ``active`` names the constraints the solution lies on (see :data:`CONSTRAINTS`);
    ``unconstrained`` is the plain weighted least-squares solution for comparison (it names
    ``offset`` only when the offset was fitted);
    ``condition_number`` is that of the weighted regressor with columns scaled to unit norm
    (large: the data do not separate the parameters, e.g. offset from Coulomb friction).
    """

    J_tot: float
    J_h: float
    b_v: float
    tau_c: float
    offset: float
    residual_rms: float  # N m, weighted RMS of the filtered torque residual
    active: tuple[str, ...]
    condition_number: float
    link_inertia: float  # rhoA·L³/3
    unconstrained: dict[str, float]
    n_samples: int  # samples with non-zero weight
    cutoff_hz: float
    deadband: float
    guard: float
    records: tuple[str, ...] = field(default=())

    def parameters(self) -> dict[str, float]:
        """The estimate as values of the model parameters it determines (J_h, b_v, tau_c)."""
        return {"J_h": self.J_h, "b_v": self.b_v, "tau_c": self.tau_c}

    def summary(self) -> str:
        """A few lines for people."""
        active = ", ".join(CONSTRAINTS[a] for a in self.active) or "none"
        return "\n".join(
            [
                f"rigid estimate from {self.n_samples} samples of {len(self.records)} record(s)"
                f" (cutoff {self.cutoff_hz:g} Hz, dead band {self.deadband:g} rad/s)",
                f"  J_tot = {self.J_tot:.5g} kg m^2  (J_h = {self.J_h:.5g}, link "
                f"{self.link_inertia:.5g})",
                f"  b_v   = {self.b_v:.5g} N m s/rad",
                f"  tau_c = {self.tau_c:.5g} N m",
                f"  offset = {self.offset:.5g} N m",
                f"  residual rms {self.residual_rms:.3g} N m, condition number "
                f"{self.condition_number:.3g}, active constraints: {active}",
            ]
        )


@dataclass(frozen=True)
class Regression:
    """Rows of the rigid-body regression of one record (see :func:`rigid_regression`)."""

    regressor: Float[np.ndarray, "n 4"]  # L(θ''), L(θ'), L(s), 1
    torque: Float[np.ndarray, " n"]  # L(tau)
    weight: Float[np.ndarray, " n"]  # 0 in the dead band and within the guard of it, else 1


def _as_records(records: Records) -> list[Record]:
    if isinstance(records, Record):
        return [records]
    records = list(records)
    if not records:
        raise ValueError("no records given: the rigid estimate needs at least one record")
    for i, r in enumerate(records):
        if not isinstance(r, Record):
            raise TypeError(f"records[{i}] must be a jaxflex.data.Record, got {type(r).__name__}")
    return records


def rigid_regression(
    record: Record,
    *,
    cutoff_hz: float = DEFAULT_CUTOFF_HZ,
    deadband: float = DEFAULT_DEADBAND,
    guard: float | None = None,
) -> Regression:
    """Filtered regressor rows ``[θ'', θ', s, 1]``, torque and automatic weights of one record.

    ``guard`` (s) defaults to ``0.5/cutoff_hz``, about the half-width of the zero-phase filter's
    impulse response.
    """
    fs = record.sample_rate
    if not (math.isfinite(cutoff_hz) and 0 < cutoff_hz < fs / 2):
        raise ValueError(
            f"cutoff_hz={cutoff_hz!r} must be a positive frequency below the Nyquist frequency "
            f"{fs / 2:g} Hz of record {record.name!r}"
        )
    if not (math.isfinite(deadband) and deadband >= 0):
        raise ValueError(f"deadband={deadband!r} must be a speed >= 0 rad/s")
    guard = 0.5 / cutoff_hz if guard is None else guard
    if not (math.isfinite(guard) and guard >= 0):
        raise ValueError(f"guard={guard!r} must be a time >= 0 s")
    if record.n_samples < 8:
        raise ValueError(f"record {record.name!r} has {record.n_samples} samples; need at least 8")
    dt = record.dt
    angle = lowpass(record.joint_angle, cutoff_hz, fs)
    velocity = differentiate(angle, dt, 1)
    acceleration = differentiate(angle, dt, 2)
    moving = np.abs(velocity) > deadband
    sign = np.where(moving, np.sign(velocity), 0.0)
    columns = np.stack(
        [acceleration, velocity, lowpass(sign, cutoff_hz, fs), np.ones_like(angle)], axis=1
    )
    # weight 0 within `guard` of a stuck sample or of either end (where the filter's odd
    # extension bends the second derivative)
    half = int(round(guard / dt))
    stuck = np.pad(~moving, half, constant_values=True).astype(np.float64)
    near_stuck = np.convolve(stuck, np.ones(2 * half + 1), mode="valid") > 0
    return Regression(columns, lowpass(record.input, cutoff_hz, fs), (~near_stuck).astype(float))


def estimate_rigid(
    records: Records,
    *,
    cutoff_hz: float = DEFAULT_CUTOFF_HZ,
    weights: Sequence[ArrayLike] | ArrayLike | None = None,
    offset: bool = True,
    testbed: Testbed | None = None,
    deadband: float = DEFAULT_DEADBAND,
    guard: float | None = None,
) -> RigidEstimate:
    """Fit ``tau = J_tot θ'' + b_v θ' + tau_c sgn θ' (+ offset)`` with physical constraints.

    ``records``: one record, a data set or a list of records (each filtered on its own, rows
    stacked). ``weights``: optional per-sample weights ≥ 0 (one array per record), multiplied
    with the automatic dead-band weights. ``offset=False`` fixes the torque offset at zero; with
    an offset the joint must turn both ways, otherwise offset and Coulomb friction are the same
    column and a ValueError says so. ``testbed`` gives the link inertia rhoA·L³/3 (default: the
    reference testbed).
    """
    records = _as_records(records)
    testbed = Testbed() if testbed is None else testbed
    user_weights = _check_weights(weights, records)
    rows = [
        rigid_regression(r, cutoff_hz=cutoff_hz, deadband=deadband, guard=guard) for r in records
    ]
    A = np.concatenate([r.regressor for r in rows])
    y = np.concatenate([r.torque for r in rows])
    w = np.concatenate([r.weight * u for r, u in zip(rows, user_weights, strict=True)])
    n_cols = 4 if offset else 3
    A = A[:, :n_cols]
    used = w > 0
    if used.sum() < _MIN_SAMPLES_PER_COLUMN * n_cols:
        raise ValueError(
            f"only {int(used.sum())} samples of {[r.name for r in records]} are usable (moving "
            f"faster than the dead band {deadband!r} rad/s, away from stops); the rigid estimate "
            f"needs at least {_MIN_SAMPLES_PER_COLUMN * n_cols}: use longer records or more motion"
        )
    velocity = A[used, 1]
    if offset and (np.all(velocity > 0) or np.all(velocity < 0)):
        raise ValueError(
            "the torque offset cannot be told from Coulomb friction: the joint turns only one "
            f"way in the usable samples of {[r.name for r in records]}; pass offset=False or "
            "add a record in which the joint turns both ways"
        )

    link = testbed.link_inertia
    lower = np.array([link, 0.0, 0.0, -np.inf])[:n_cols]
    upper = np.full(n_cols, np.inf)
    sw = np.sqrt(w)
    Aw, yw = A * sw[:, None], y * sw
    scale = np.linalg.norm(Aw, axis=0)
    if np.any(scale == 0):
        dead = [COLUMNS[i] for i in np.flatnonzero(scale == 0)]
        raise ValueError(f"the records do not excite {dead}: their regressor column is zero")
    x, active = box_least_squares(Aw / scale, yw, lower * scale, upper * scale)
    x = x / scale
    free, *_ = np.linalg.lstsq(Aw, yw, rcond=None)
    residual = yw - Aw @ x
    values = np.zeros(4)
    values[:n_cols] = x
    unconstrained = dict(zip(COLUMNS[:n_cols], free.tolist(), strict=True))
    return RigidEstimate(
        J_tot=float(values[0]),
        J_h=float(values[0] - link),
        b_v=float(values[1]),
        tau_c=float(values[2]),
        offset=float(values[3]),
        residual_rms=float(np.sqrt(np.sum(residual**2) / np.sum(w))),
        active=tuple(COLUMNS[i] for i in active),
        condition_number=float(np.linalg.cond(Aw[used] / scale)),
        link_inertia=float(link),
        unconstrained=unconstrained,
        n_samples=int(used.sum()),
        cutoff_hz=float(cutoff_hz),
        deadband=float(deadband),
        guard=float(0.5 / cutoff_hz if guard is None else guard),
        records=tuple(r.name for r in records),
    )


def _check_weights(weights, records: list[Record]) -> list[np.ndarray]:
    if weights is None:
        return [np.ones(r.n_samples) for r in records]
    if len(records) == 1 and np.ndim(weights) == 1:
        weights = [weights]
    weights = list(weights)
    if len(weights) != len(records):
        raise ValueError(f"weights: got {len(weights)} arrays for {len(records)} record(s)")
    out = []
    for r, wr in zip(records, weights, strict=True):
        wr = np.asarray(wr, dtype=np.float64)
        if wr.shape != (r.n_samples,):
            raise ValueError(
                f"weights for record {r.name!r} must have shape ({r.n_samples},), got {wr.shape}"
            )
        if not np.all(np.isfinite(wr)) or np.any(wr < 0):
            bad = int(np.flatnonzero(~(np.isfinite(wr) & (wr >= 0)))[0])
            raise ValueError(
                f"weights for record {r.name!r}: sample {bad} is negative or not finite"
            )
        out.append(wr)
    return out


def box_least_squares(
    A: Float[np.ndarray, "n k"],
    y: Float[np.ndarray, " n"],
    lower: Float[np.ndarray, " k"],
    upper: Float[np.ndarray, " k"],
    *,
    maxiter: int = 5000,
) -> tuple[np.ndarray, tuple[int, ...]]:
    """``argmin ‖A x − y‖²`` subject to ``lower ≤ x ≤ upper``, and the indices of active bounds.

    Projected (accelerated) gradient on ``½ xᵀQx − bᵀx`` with ``Q = AᵀA`` (jaxopt), then a polish:
    with the active bounds fixed, the free components are the exact least-squares solution, kept
    if it is feasible and the multipliers of the active bounds have the right sign (KKT).
    Columns of ``A`` should be of similar norm (the caller scales them).
    """
    with warnings.catch_warnings():  # jaxopt announces on import that it is unmaintained
        warnings.simplefilter("ignore", DeprecationWarning)
        import jaxopt

    Q, b = A.T @ A, A.T @ y
    lo, hi = np.asarray(lower, float), np.asarray(upper, float)
    x0 = np.clip(np.linalg.lstsq(A, y, rcond=None)[0], lo, hi)

    def fun(x):
        return 0.5 * x @ (jnp.asarray(Q) @ x) - jnp.asarray(b) @ x

    solver = jaxopt.ProjectedGradient(
        fun=fun,
        projection=jaxopt.projection.projection_box,
        stepsize=1.0 / float(np.linalg.eigvalsh(Q)[-1]),
        maxiter=maxiter,
        tol=1e-12,
    )
    x = np.asarray(solver.run(jnp.asarray(x0), hyperparams_proj=(lo, hi)).params)
    tol = 1e-9 * (1.0 + np.abs(x))
    at_bound = (x - lo <= tol) | (hi - x <= tol)
    return _polish(A, y, Q, b, x, lo, hi, at_bound)


def _polish(A, y, Q, b, x, lo, hi, at_bound):
    free = ~at_bound
    fixed = np.where(x - lo <= hi - x, lo, hi)
    polished = np.where(at_bound, fixed, 0.0)
    if free.any():
        rhs = y - A[:, at_bound] @ polished[at_bound]
        polished[free] = np.linalg.lstsq(A[:, free], rhs, rcond=None)[0]
    gradient = Q @ polished - b  # ∂/∂x of ½‖Ax − y‖²
    feasible = np.all(polished >= lo - 1e-12) & np.all(polished <= hi + 1e-12)
    at_lower = at_bound & (fixed == lo)
    kkt = np.all(gradient[at_lower] >= -1e-8 * np.abs(b).max()) and np.all(
        gradient[at_bound & ~at_lower] <= 1e-8 * np.abs(b).max()
    )
    if feasible and kkt:
        x = polished
    return x, tuple(int(i) for i in np.flatnonzero(at_bound))


# --- the rigid model ------------------------------------------------------------------------


def rigid_simulate(
    estimate: RigidEstimate,
    torque: Float[ArrayLike, " n"],
    dt: float,
    *,
    length: float | None = None,
    n_substeps: int = 4,
    model: Model | None = None,
) -> Outputs:
    """Joint motion of the rigid model ``J_tot θ'' = tau − c − b_v θ' − tau_c sgn θ'`` from rest.

    Zero-order-hold torque; each substep is backward Euler in the friction with the set-valued
    Coulomb law, solved in closed form: the joint sticks when ``|v + h(tau − c)/J| ≤ h·tau_c/J``
    and otherwise ``v⁺ = (v + h(tau − c − tau_c·s)/J) / (1 + h b_v/J)``. The angle advances by
    the trapezoidal rule. Outputs are those of :class:`jaxflex.simulation.Outputs` at the sample
    instants (right-hand limit of the torque): the tip acceleration of a rigid link is
    ``(r + L)·θ''`` (``length`` defaults to the reference testbed's, ``r`` is the clamp offset);
    deflection and strain are zero. With a rig ``model`` (its link, in place of ``length``) the
    outputs also hold its stations and its sensors' readings as a rigid link gives them (an
    accelerometer at ``x`` reads ``(r + x)·θ''``), so that they compare with its records.
    """
    if model is not None and length is not None:
        raise ValueError("give length or model, not both: the model's link has its length")
    torque = check_torque(torque)
    dt = check_dt(dt)
    if not (isinstance(n_substeps, int) and n_substeps >= 1):
        raise ValueError(f"n_substeps must be an int >= 1, got {n_substeps!r}")
    if not estimate.J_tot > 0:
        raise ValueError(f"the estimate's J_tot={estimate.J_tot!r} must be positive")
    link = Testbed() if model is None else model.testbed
    length = link.length if length is None else float(length)
    coefficients = jnp.array([estimate.J_tot, estimate.b_v, estimate.tau_c, estimate.offset])
    out = _rigid_scan(coefficients, jnp.asarray(torque), float(dt), n_substeps)
    angle, velocity, acceleration, joint_torque = (np.asarray(o) for o in out)
    zero = np.zeros_like(angle)
    outputs = Outputs(
        joint_angle=angle,
        tip_acceleration=(link.clamp_offset + length) * acceleration,
        joint_velocity=velocity,
        tip_deflection=zero,
        root_strain=zero,
        joint_torque=joint_torque,
    )
    if model is None or not model.stations:
        return outputs if model is None else with_readings(model, outputs)
    arm = link.clamp_offset + np.asarray(model.stations)
    still = np.zeros((angle.size, arm.size))
    return with_readings(model, dataclasses.replace(
        outputs, station_deflection=still, station_curvature=still,
        station_acceleration=acceleration[:, None] * arm[None, :]))


def _coulomb_step(v: Array, drive: Array, coefficients: Array, h: float) -> Array:
    """End-of-step velocity under ``drive = tau − c`` (backward Euler, set-valued Coulomb)."""
    J, b_v, tau_c, _ = coefficients
    free = v + h * drive / J
    slip = (free - h * tau_c * jnp.sign(free) / J) / (1.0 + h * b_v / J)
    return jnp.where(jnp.abs(free) <= h * tau_c / J, 0.0, slip)


def _acceleration(v: Array, drive: Array, coefficients: Array) -> tuple[Array, Array]:
    """Acceleration and net joint torque at an instant (stuck: friction balances the drive)."""
    J, b_v, tau_c, _ = coefficients
    moving = v != 0.0
    stuck_net = jnp.sign(drive) * jnp.maximum(jnp.abs(drive) - tau_c, 0.0)
    net = jnp.where(moving, drive - b_v * v - tau_c * jnp.sign(v), stuck_net)
    return net / J, net


@jax.jit(static_argnames=("dt", "n_substeps"))
def _rigid_scan(coefficients: Array, torque: Array, dt: float, n_substeps: int):
    h = dt / n_substeps
    drive = torque - coefficients[3]

    def sample(state, u):
        theta, v = state
        acc, net = _acceleration(v, u, coefficients)
        out = (theta, v, acc, net)
        for _ in range(n_substeps):
            v_next = _coulomb_step(v, u, coefficients, h)
            theta, v = theta + 0.5 * h * (v + v_next), v_next
        return (theta, v), out

    zero = jnp.zeros((), dtype=torque.dtype)
    _, out = jax.lax.scan(sample, (zero, zero), drive)
    return out


# --- warm start of the evolutionary search -----------------------------------------------------


def _resolved(estimate: RigidEstimate, space: ParameterSpace) -> dict[str, float]:
    """The estimate's values of ``space``'s parameters that it resolved: not on a physical
    constraint (``b_v = 0`` says only that the records do not resolve it)."""
    on_constraint = {"J_h" if a == "J_tot" else a for a in estimate.active}
    return {k: v for k, v in estimate.parameters().items()
            if k in space.names and k not in on_constraint}


def search_centre(estimate: RigidEstimate | None, space: ParameterSpace) -> dict[str, Array]:
    """Where the search from scratch is centred: ``space``'s reference values, with those the
    rigid-body ``estimate`` resolved (``None``: no estimate) put in, each clipped into the box.

    The point knows nothing of the flexible fit, so a base parameter that ends on a bound while
    compensating a missing effect can be sent back to it (:mod:`jaxflex.discovery`)."""
    known = {} if estimate is None else _resolved(estimate, space)
    centre = space.reference() | {k: jnp.asarray(v, dtype=jnp.float64) for k, v in known.items()}
    return {k: jnp.clip(v, space[k].lower, space[k].upper) for k, v in centre.items()}



def warm_start(
    estimate: RigidEstimate,
    space: ParameterSpace,
    population: int,
    *,
    spread: float = 0.05,
    seed: int = 0,
) -> Float[np.ndarray, "P d"]:
    """An initial population in unit-box coordinates of ``space`` for ``evolve.run``.

    J_h, b_v and tau_c are drawn uniformly within ``±spread`` (unit-box width) of the estimate,
    clipped into the box; a value the estimate left on a physical constraint (e.g. ``b_v = 0``:
    the records do not resolve it) says nothing about where it lies, so such a parameter is
    spread over its whole range like every other one (E, alpha, beta, effects).
    """
    if not (isinstance(population, (int, np.integer)) and population >= 1):
        raise ValueError(f"population must be an int >= 1, got {population!r}")
    if not (math.isfinite(spread) and 0 < spread <= 1):
        raise ValueError(f"spread={spread!r} must be in (0, 1] (a width in the unit box)")
    known = _resolved(estimate, space)
    rng = np.random.default_rng(seed)
    u = rng.uniform(0.0, 1.0, (int(population), len(space)))
    if not known:
        return u
    u0 = space.unit_seeds(search_centre(estimate, space))[0]
    for name in known:
        i = space.names.index(name)
        u[:, i] = np.clip(u0[i] + spread * rng.uniform(-1.0, 1.0, int(population)), 0.0, 1.0)
    return u


__all__ = [
    "CONSTRAINTS",
    "DEFAULT_CUTOFF_HZ",
    "DEFAULT_DEADBAND",
    "Regression",
    "RigidEstimate",
    "box_least_squares",
    "estimate_rigid",
    "rigid_regression",
    "rigid_simulate",
    "search_centre",
    "warm_start",
]
