"""Gradient refinement of an identified parameter set, and how well each parameter is known.

Refinement
    :func:`bounded_least_squares`: optimistix's Levenberg–Marquardt (trust region, QR solve of
    the damped system) with a descent that respects box bounds (:class:`BoxedDampedNewton`: a
    parameter on a bound that the gradient pushes outwards is held there for the step, each
    step is cut back into the box), and a dense forward-mode Jacobian (:func:`dense_jacobian`).
    :func:`refine` runs it on the objective's residuals in the unit box of the search (it was
    optimistix in ``z = logit(u)``, where a parameter ending on its bound drives ``z`` to
    infinity). The fitted set is a boolean mask, so one compilation serves every fitted set of
    the same size. A refined point is kept only if its cost is finite and lower than at the
    start.

Bounded Levenberg–Marquardt
    :func:`bounded_levenberg_marquardt` (NumPy, active-set projection on the bounds) refits
    discovery's models on its quantisation-aware likelihood; its docstring gives the
    measurements for which discovery does not use :func:`refine`.

Uncertainty (Gauss–Newton)
    The estimate minimises ``Σ e_i²`` with the objective's own weighting (RMS-normalised
    channels), so its covariance is the Gauss–Newton *sandwich*

        Cov φ ≈ A⁻¹ (Jᵀ Σ J) A⁻¹,     A = Jᵀ J,   J = ∂e/∂φ,

    where ``Σ`` is the covariance of the residuals. Each channel ``c`` (one sensor) has its own
    noise level, estimated from its residuals at the optimum in the channel's unit,
    ``σ_c² = mean_{i∈c} (e_i/s_i)² · N/(N − d)``, so ``Σ_ii = σ_c(i)² s_i²`` (``s_i`` the scale of
    :mod:`jaxflex.objective`). When the weights are ``1/σ_c²`` this is the textbook
    ``σ² (JᵀJ)⁻¹``; with any other weighting the plain formula would be overconfident.
    ``hac_lags > 0`` replaces the white-noise ``Σ`` by a Bartlett (Newey–West) estimate over
    that many lags within each record and channel, for residuals correlated in time (model
    error).

    The coordinates ``φ`` are ``log x`` for log-scale parameters and ``x`` otherwise: the
    Gaussian approximation is far better in ``log x`` for positive quantities spanning decades
    (intervals ``x·exp(±1.96 σ_φ)`` never cross zero) and, unlike ``z = logit(u)``, it does not
    distort near a bound. Physical standard deviations and covariance follow by the delta method
    (``∂x/∂ log x = x``).

    Identifiability: the eigen-decomposition of ``Jᵀ J`` of the objective's own residuals in
    relative coordinates (``∂e/∂ log x``) — independent of the noise estimate, so it also speaks
    for noise-free data. Eigenvalues below ``null_threshold · λ_max`` are near-null directions;
    the parameters that dominate them (and any whose interval spans more than a factor
    ``wide_ratio``) are reported as poorly identifiable.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field

import equinox as eqx
import jax
import jax.numpy as jnp
import lineax as lx
import numpy as np
import optimistix as optx
from jax.scipy.special import ndtri
from jaxtyping import Array, ArrayLike, Bool, Float

from jaxflex.objective import Objective

RESULT_NAMES: tuple[str, ...] = (
    "successful",
    "nonlinear_max_steps_reached",
    "nonlinear_divergence",
    "nonfinite",
)
BOUND_MARGIN = 1e-3
"""An estimate within this fraction of the search range (unit box) of a bound is 'at the bound'."""


def _result_name(result: optx.RESULTS) -> str:
    for name in RESULT_NAMES:
        if bool(result == getattr(optx.RESULTS, name)):
            return name
    return "failed"


def _floats(params: Mapping[str, ArrayLike], names: Sequence[str]) -> dict[str, float]:
    return {n: float(params[n]) for n in names}


# ------------------------------------------------------------------------------ refinement


@dataclass(frozen=True)
class Refinement:
    """Outcome of :func:`refine`: where it started and ended, and whether the end was kept.

    ``params`` is the accepted point (the start if the refinement was rejected), ``cost`` its
    cost; ``end``/``cost_end`` are where the solver stopped. ``result`` is the optimistix result
    code by name (``"successful"``, ``"nonlinear_max_steps_reached"``, …) and ``steps`` the
    number of Levenberg–Marquardt steps; with several starts, these describe the best one.
    """

    start: dict[str, float]
    end: dict[str, float]
    cost_start: float
    cost_end: float
    accepted: bool
    result: str
    message: str
    steps: int
    wall_time: float
    compile_time: float
    n_starts: int = 1

    @property
    def params(self) -> dict[str, float]:
        return self.end if self.accepted else self.start

    @property
    def cost(self) -> float:
        return self.cost_end if self.accepted else self.cost_start

    def to_dict(self) -> dict:
        return {
            "start": self.start,
            "end": self.end,
            "cost_start": self.cost_start,
            "cost_end": self.cost_end,
            "accepted": self.accepted,
            "result": self.result,
            "message": self.message,
            "steps": self.steps,
            "wall_time": self.wall_time,
            "compile_time": self.compile_time,
            "n_starts": self.n_starts,
        }

    @classmethod
    def from_dict(cls, data: Mapping) -> Refinement:
        return cls(**{k: data[k] for k in cls.__dataclass_fields__})


def dense_jacobian(fn: Callable[[Array], Array]) -> Callable[[Array], Array]:
    """``fn`` whose JVP materialises the full Jacobian by forward mode (``jacfwd``).

    Levenberg–Marquardt needs ``J`` and ``Jᵀr``; with a dense ``J`` (d columns, one batched
    forward pass) its linearisation transposes trivially instead of running the simulator in
    reverse, which halves compile time and speeds up every step.
    """

    @jax.custom_jvp
    def wrapped(z):
        return fn(z)

    @wrapped.defjvp
    def _jvp(primals, tangents):
        (z,), (t,) = primals, tangents
        jac, value = jax.jacfwd(lambda y: _twice(fn(y)), has_aux=True)(z)
        return value, jac @ t

    return wrapped


def _twice(x):
    return x, x


Residuals = Callable[[Array, object], Array]
"""``residuals(p, args)``: the residual vector at the solver coordinates ``p``."""


class _BoxedStep(eqx.Module):
    """``(J ŷ, √λ D ŷ)`` with the held coordinates of ``ŷ`` zeroed: the damped least-squares
    operator of the free coordinates (``D`` the column norms of ``J``)."""

    jac: lx.AbstractLinearOperator
    held: Bool[Array, " d"]
    norms: Float[Array, " d"]
    damping: Float[Array, ""]

    def __call__(self, v):
        return self.jac.mv(jnp.where(self.held, 0.0, v)), jnp.sqrt(self.damping) * self.norms * v


FIRST_DAMPING = 1e-3
"""``λ`` of the first step with Marquardt's damping (relative to ``diag(JᵀJ)``; the trust
region scales it after): close to a Gauss–Newton step."""


class _BoxState(eqx.Module):
    y: Float[Array, " d"]
    f_info: optx.FunctionInfo.ResidualJac
    held: Bool[Array, " d"]
    norms: Float[Array, " d"]


class BoxedDampedNewton(optx.AbstractDescent):
    """optimistix's damped Newton (Levenberg–Marquardt) descent on ``lower ≤ y ≤ upper``.

    A coordinate on a bound that the gradient ``Jᵀr`` pushes outwards is held there for the
    step (its column leaves the damped system), and the step is cut back into the box. The
    trust-region search then judges the step actually taken. The damping is optimistix's
    ``λ I`` (``λ = 1/step size``, first 1), or with ``marquardt`` Marquardt's scale-free
    ``λ diag(JᵀJ)`` (first ``λ`` :data:`FIRST_DAMPING`): on a cost of millions in coordinates
    of order one, ``λ I`` takes bare Gauss–Newton steps and, when those fail, stalls.
    """

    lower: Float[Array, " d"]
    upper: Float[Array, " d"]
    marquardt: bool = eqx.field(static=True, default=False)
    linear_solver: lx.AbstractLinearSolver = lx.QR()

    def init(self, y, f_info_struct):
        def zero(leaf):
            shaped = isinstance(leaf, jax.ShapeDtypeStruct)
            return jnp.zeros(leaf.shape, leaf.dtype) if shaped else leaf

        f_info = jax.tree.map(zero, f_info_struct)
        return _BoxState(y, f_info, jnp.zeros(y.shape, bool), jnp.ones(y.shape))

    def query(self, y, f_info, state):
        del state
        g = f_info.jac.transpose().mv(f_info.residual)
        held = ((y <= self.lower) & (g > 0)) | ((y >= self.upper) & (g < 0))
        if not self.marquardt:
            return _BoxState(y, f_info, held, jnp.ones(y.shape))
        norms = jnp.linalg.norm(f_info.jac.as_matrix(), axis=0)
        norms = jnp.maximum(norms, 1e-6 * jnp.max(norms) + jnp.finfo(norms.dtype).tiny)
        return _BoxState(y, f_info, held, norms)

    def step(self, step_size, state):
        tiny = step_size <= jnp.finfo(step_size.dtype).eps
        first = FIRST_DAMPING if self.marquardt else 1.0
        damping = jnp.where(tiny, jnp.finfo(step_size.dtype).max,
                            first / jnp.where(tiny, 1, step_size))
        f_info = state.f_info
        operator = lx.FunctionLinearOperator(
            _BoxedStep(f_info.jac, state.held, state.norms, damping), f_info.jac.in_structure()
        )
        vector = (f_info.residual, jnp.zeros_like(state.y))
        sol = lx.linear_solve(operator, vector, self.linear_solver, throw=False)
        trial = jnp.clip(state.y - jnp.where(state.held, 0.0, sol.value), self.lower, self.upper)
        return trial - state.y, optx.RESULTS.promote(sol.result)


class BoundedLevenbergMarquardt(optx.AbstractGaussNewton):
    """optimistix's Levenberg–Marquardt (trust-region damping, QR solve of the damped system)
    with :class:`BoxedDampedNewton` as its descent: every iterate stays in the box."""

    rtol: float
    atol: float
    descent: BoxedDampedNewton
    norm: Callable = optx.max_norm
    search: optx.ClassicalTrustRegion = eqx.field(default_factory=optx.ClassicalTrustRegion)
    verbose: Callable = eqx.field(static=True, default=lambda **_: None)


STALL_STEPS = 6
"""With ``ftol``: a solve also stops after this many rejected steps in a row (the trust region
shrunk 4⁶ ≈ 4,000-fold: the cost no longer falls above round-off)."""


def _bounded_solve(residuals: Residuals, args, start, lower, upper, free, rtol, atol, ftol,
                   max_steps, marquardt=False):
    """:class:`BoundedLevenbergMarquardt` stepped in a loop that also stops on ``ftol``."""
    fn = dense_jacobian(lambda y: residuals(jnp.where(free, y, start), args))

    def with_aux(y, _):
        return fn(y), None

    solver = BoundedLevenbergMarquardt(rtol, atol, BoxedDampedNewton(lower, upper, marquardt))
    tags = frozenset()
    state = solver.init(with_aux, start, None, {}, jax.eval_shape(fn, start), None, tags)
    state, static = eqx.partition(state, eqx.is_array)  # the loop carries arrays only

    def proceed(carry):
        *_, done, k = carry
        return ~done & (k < max_steps)

    def step(carry):
        y, state, cost_start, cost, _, k = carry
        state = eqx.combine(state, static)
        y, state, _ = solver.step(with_aux, y, None, {}, state, tags)
        new_cost = jnp.sum(state.f_info.residual**2)  # at y, the last accepted point
        accepted = state.num_steps_since_acceptance == 0
        small = accepted & (k > 0) & (cost - new_cost <= ftol * new_cost)
        stalled = state.num_steps_since_acceptance >= STALL_STEPS
        small, stalled = (ftol > 0) & small, (ftol > 0) & stalled
        converged, _ = solver.terminate(with_aux, y, None, {}, state, tags)
        cost_start = jnp.where(k == 0, new_cost, cost_start)  # the first step evaluates the start
        done = converged | small | stalled
        return y, eqx.filter(state, eqx.is_array), cost_start, new_cost, done, k + 1

    inf = jnp.array(jnp.inf)
    init = (start, state, inf, inf, jnp.array(False), jnp.array(0))
    y, state, cost_start, cost, done, steps = jax.lax.while_loop(proceed, step, init)
    state = eqx.combine(state, static)
    result = optx.RESULTS.where(done, state.result, optx.RESULTS.nonlinear_max_steps_reached)
    return jnp.where(free, y, start), result, steps, cost_start, cost


_bounded_solve_jit = eqx.filter_jit(_bounded_solve)


@dataclass(frozen=True)
class BoundedSolution:
    """Outcome of :func:`bounded_least_squares` (costs are ``Σ r²``)."""

    value: np.ndarray
    cost_start: float
    cost: float
    result: str
    message: str
    steps: int


def bounded_least_squares(
    residuals: Residuals,
    args: object,
    start: ArrayLike,
    lower: ArrayLike,
    upper: ArrayLike,
    *,
    free: ArrayLike | None = None,
    rtol: float,
    atol: float,
    ftol: float = 0.0,
    max_steps: int,
    marquardt: bool = False,
    solve: Callable | None = None,
) -> BoundedSolution:
    """Levenberg–Marquardt (:class:`BoundedLevenbergMarquardt`) of ``residuals(p, args)`` on
    ``lower ≤ p ≤ upper``.

    ``free`` (default all) marks the fitted coordinates; the others keep their start values
    (their Jacobian columns vanish). Arrays change nothing compiled: one compilation serves
    every fitted set, start and box of the same size. It stops on optimistix's ``rtol``/``atol``
    (step and residuals), after ``max_steps``, or (``ftol > 0``) when an accepted step lowers
    the cost by less than ``ftol`` of it or :data:`STALL_STEPS` steps in a row are rejected.
    ``marquardt`` chooses the damping (:class:`BoxedDampedNewton`).
    ``solve`` is ``_bounded_solve`` compiled ahead by the caller (to time it). The value is the
    last accepted point if its cost is finite and below the start's, else the start.
    """
    solve = _bounded_solve_jit if solve is None else solve
    p = jnp.asarray(start, dtype=jnp.float64)
    lower, upper = jnp.asarray(lower, dtype=jnp.float64), jnp.asarray(upper, dtype=jnp.float64)
    free = jnp.ones(p.shape, bool) if free is None else jnp.asarray(free, dtype=bool)
    p = jnp.where(free, jnp.clip(p, lower, upper), p)
    end, result, steps, cost_start, cost = solve(residuals, args, p, lower, upper, free, rtol,
                                                 atol, ftol, max_steps, marquardt)
    cost_start, cost = float(cost_start), float(cost)
    cost_start = cost_start if math.isfinite(cost_start) else math.inf
    better = math.isfinite(cost) and cost < cost_start
    return BoundedSolution(
        value=np.asarray(end if better else p),
        cost_start=cost_start,
        cost=cost if better else cost_start,
        result=_result_name(result),
        message=optx.RESULTS[result] or "converged",
        steps=int(steps),
    )


def _unit_residuals(u: Array, objective: Objective) -> Array:
    return objective.unit_residuals(u)


def refine(
    objective: Objective,
    starts: Mapping[str, ArrayLike] | Sequence[Mapping[str, ArrayLike]],
    *,
    rtol: float = 1e-6,
    atol: float = 1e-8,
    max_steps: int = 100,
) -> Refinement:
    """Levenberg–Marquardt from one start (free parameters, physical) or the best of several.

    Each start is refined by :func:`bounded_least_squares` in the unit box of the search; the
    end with the lowest cost is returned, accepted only if it is finite and below the cost of
    the best start. ``rtol``/``atol`` are optimistix's stopping tolerances (on the step in the
    unit box and on the residuals); the defaults resolve the parameters far below their
    statistical uncertainty.
    """
    starts = [starts] if isinstance(starts, Mapping) else list(starts)
    if not starts:
        raise ValueError("refine needs at least one start")
    if not (isinstance(max_steps, int) and max_steps >= 1):
        raise ValueError(f"max_steps must be an int >= 1, got {max_steps!r}")
    for label, tol in (("rtol", rtol), ("atol", atol)):
        if not (math.isfinite(tol) and tol > 0):
            raise ValueError(f"{label} must be a positive number, got {tol!r}")
    space, names = objective.space, objective.names
    u_starts = []
    for start in starts:
        missing = [n for n in names if n not in start]
        if missing:
            raise ValueError(f"refinement start lacks parameter(s) {missing}")
        u_starts.append(jnp.clip(space.to_unit({n: start[n] for n in names}), 0.0, 1.0))
    zeros, ones = jnp.zeros(len(names)), jnp.ones(len(names))

    t0 = time.perf_counter()
    compiled = _bounded_solve_jit.lower(
        _unit_residuals, objective, u_starts[0], zeros, ones, ones > 0, rtol, atol, 0.0,
        max_steps, False,
    ).compile()
    compile_time = time.perf_counter() - t0
    t0 = time.perf_counter()
    runs = [
        (u0, bounded_least_squares(_unit_residuals, objective, u0, zeros, ones, rtol=rtol,
                                   atol=atol, max_steps=max_steps, solve=compiled))
        for u0 in u_starts
    ]
    wall_time = time.perf_counter() - t0

    best_start = min(runs, key=lambda r: r[1].cost_start)
    _, best = min(runs, key=lambda r: r[1].cost)
    return Refinement(
        start=_floats(space.from_unit(best_start[0]), names),
        end=_floats(space.from_unit(best.value), names),
        cost_start=best_start[1].cost_start,
        cost_end=best.cost,
        accepted=bool(best.cost < best_start[1].cost_start),
        result=best.result,
        message=best.message,
        steps=best.steps,
        wall_time=wall_time,
        compile_time=compile_time,
        n_starts=len(starts),
    )


# ------------------------------------------------------------------------------ bounded LM


def bounded_levenberg_marquardt(
    system: Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]],
    phi: np.ndarray,
    lower: np.ndarray,
    upper: np.ndarray,
    *,
    max_steps: int,
    rtol: float,
) -> np.ndarray:
    """Levenberg–Marquardt in NumPy on the box ``lower ≤ φ ≤ upper`` by active-set projection.

    ``system(φ)`` gives the residual vector and its Jacobian. A parameter on a bound that the
    gradient pushes outwards is held there for the step; every trial is clipped into the box.
    Stops after ``max_steps`` Jacobians, when an accepted step lowers the cost by less than
    ``rtol`` of it, or when the damping exceeds 1e10. Returns the last accepted ``φ`` (the
    ``phi`` object itself if no step was accepted).

    Discovery refits with it rather than with :func:`refine`, for reasons measured on the
    payload case of ``tests/test_discover.py`` (2-core CPU, the same quantisation-aware residual
    in both, optimistix in this module's logit coordinates with :func:`refine`'s tolerances):
    both reach the same cost (to 9 digits, 6 and 7 parameters), but optimistix compiles once
    per set of fitted parameters (22–28 s each; a discovery run refits many sets, while the
    caller's one compiled Jacobian block serves them all), runs 3.7–4× slower once compiled
    (14.3 s against 3.9 s, 4.9 s against 1.2 s), and with a parameter ending on its bound it
    used all 100 steps (the logit coordinate runs off to infinity) where this one pins it.
    """
    def evaluate(p: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
        r, jac = system(p)
        cost = float(r @ r)
        return r, jac, cost if math.isfinite(cost) else math.inf

    lo, hi = lower, upper
    r, jf, cost = evaluate(phi)
    lam, nu = 1e-3, 2.0
    for _ in range(max_steps):
        g = jf.T @ r
        a = jf.T @ jf
        diag = np.maximum(np.diag(a), 1e-12 * max(np.max(np.diag(a)), 1e-300))
        # parameters on a bound that the gradient pushes outwards stay there this step
        span = hi - lo
        pinned = ((phi <= lo + 1e-9 * span) & (g > 0)) | ((phi >= hi - 1e-9 * span) & (g < 0))
        free = ~pinned
        step = np.zeros_like(phi)
        if free.any():
            sub = np.ix_(free, free)
            step[free] = np.linalg.solve(a[sub] + lam * np.diag(diag[free]), -g[free])
        trial = np.clip(phi + step, lo, hi)
        step = trial - phi
        predicted = -(2 * step @ g + step @ a @ step)
        r_t, jf_t, cost_t = evaluate(trial)
        if cost_t < cost:
            rho = (cost - cost_t) / predicted if predicted > 0 else 0.0
            lam *= max(1 / 3, 1 - (2 * rho - 1) ** 3)
            nu = 2.0
            small = cost - cost_t <= rtol * cost and lam < 1.0
            phi, r, jf, cost = trial, r_t, jf_t, cost_t
            if small:
                break
        else:
            lam *= nu
            nu *= 2.0
            if lam > 1e10:
                break
    return phi


# ------------------------------------------------------------------------------ uncertainty


@dataclass(frozen=True)
class Uncertainty:
    """Gauss–Newton uncertainty of the free parameters at an estimate (see the module doc).

    Arrays follow ``names``. ``lower``/``upper`` are the ``level`` intervals in physical units,
    ``std`` the delta-method standard deviations and ``covariance`` the covariance in physical
    units; ``correlation`` is that of the fit coordinates (``coordinates[i]`` is ``"log"`` or
    ``"linear"``). ``noise`` is the estimated noise level of each channel (its unit).
    ``eigenvalues`` (ascending, relative to the largest) and ``eigenvectors`` (columns) are those
    of the scaled ``JᵀJ``; ``poorly_identifiable`` names parameters in near-null directions or
    with intervals wider than ``wide_ratio``; ``warnings`` says so in words.
    """

    names: tuple[str, ...]
    estimate: np.ndarray
    coordinates: tuple[str, ...]
    std: np.ndarray
    lower: np.ndarray
    upper: np.ndarray
    covariance: np.ndarray
    correlation: np.ndarray
    noise: dict[str, float]
    eigenvalues: np.ndarray
    eigenvectors: np.ndarray
    poorly_identifiable: tuple[str, ...]
    warnings: tuple[str, ...]
    level: float = 0.95
    at_bounds: tuple[str, ...] = field(default=())

    @property
    def intervals(self) -> dict[str, tuple[float, float]]:
        """``name → (lower, upper)`` in physical units."""
        return {
            n: (float(lo), float(hi))
            for n, lo, hi in zip(self.names, self.lower, self.upper, strict=True)
        }

    def contains(self, params: Mapping[str, ArrayLike]) -> dict[str, bool]:
        """Whether each interval contains the given value (e.g. the truth of a synthetic test)."""
        return {n: bool(lo <= float(params[n]) <= hi) for n, (lo, hi) in self.intervals.items()}


def _coordinate_maps(objective: Objective):
    log = np.array([s.log_scale for s in objective.specs])

    def to_phi(x):
        return jnp.where(log, jnp.log(jnp.where(log, x, 1.0)), x)

    def from_phi(phi):
        return jnp.where(log, jnp.exp(phi), phi)

    return log, to_phi, from_phi


def _jacobian(objective: Objective, phi: Float[Array, " d"]):
    _, _, from_phi = _coordinate_maps(objective)

    def residuals(p):
        return objective.residuals(objective.space.from_vector(from_phi(p)))

    return residuals(phi), jax.jacfwd(residuals)(phi)


_jacobian_jit = eqx.filter_jit(_jacobian)


def _describe_direction(names, vector, cutoff=0.3) -> str:
    order = np.argsort(-np.abs(vector))
    terms = [f"{vector[i]:+.2f}·{names[i]}" for i in order if abs(vector[i]) >= cutoff]
    return " ".join(terms) or f"{vector[order[0]]:+.2f}·{names[order[0]]}"


def uncertainty(
    objective: Objective,
    params: Mapping[str, ArrayLike],
    *,
    level: float = 0.95,
    null_threshold: float = 1e-8,
    wide_ratio: float = 2.0,
    hac_lags: int = 0,
) -> Uncertainty:
    """Gauss–Newton covariance, ``level`` intervals and identifiability at ``params``.

    ``params`` holds (at least) the free parameters of ``objective``, in physical units.
    """
    if not 0.0 < level < 1.0:
        raise ValueError(f"level must be in (0, 1), got {level!r}")
    if not (isinstance(hac_lags, int) and hac_lags >= 0):
        raise ValueError(f"hac_lags must be an int >= 0, got {hac_lags!r}")
    if not wide_ratio > 1.0:
        raise ValueError(f"wide_ratio must be > 1, got {wide_ratio!r}")
    names = objective.names
    missing = [n for n in names if n not in params]
    if missing:
        raise ValueError(f"uncertainty: parameter value(s) missing for {missing}")
    x = np.array([float(params[n]) for n in names])
    log, to_phi, _ = _coordinate_maps(objective)
    r, jac = _jacobian_jit(objective, to_phi(jnp.asarray(x)))
    r, jac = np.asarray(r), np.asarray(jac)
    if not (np.all(np.isfinite(r)) and np.all(np.isfinite(jac))):
        raise ValueError("uncertainty: the simulation is not finite at the estimate")
    n_res, d = jac.shape
    record, channel, scale = objective.layout()

    # per-channel noise level (channel units), then the sandwich A⁻¹ M A⁻¹
    dof = n_res / max(n_res - d, 1)
    sigma = np.array(
        [
            math.sqrt(np.mean((r[channel == c] / scale[channel == c]) ** 2) * dof)
            for c in range(len(objective.channels))
        ]
    )
    if hac_lags == 0:
        meat = (jac * ((sigma[channel] * scale) ** 2)[:, None]).T @ jac
    else:
        meat = _bartlett_meat(jac * r[:, None], record * len(sigma) + channel, hac_lags) * dof
    a_inv, singular = _inverse(jac.T @ jac)
    cov_phi = a_inv @ meat @ a_inv
    std_phi = np.where(singular, np.inf, np.sqrt(np.maximum(np.diag(cov_phi), 0.0)))

    q = float(ndtri(0.5 + 0.5 * level))
    half = q * std_phi
    with np.errstate(over="ignore", invalid="ignore"):
        lower = np.where(log, x * np.exp(-half), x - half)
        upper = np.where(log, x * np.exp(half), x + half)
        jac_x = np.where(log, x, 1.0)
        covariance = cov_phi * np.outer(jac_x, jac_x)
        std = std_phi * jac_x
        correlation = cov_phi / np.outer(std_phi, std_phi)
    correlation = np.where(np.isfinite(correlation), correlation, np.nan)
    np.fill_diagonal(correlation, 1.0)

    # identifiability from the objective's own weighting, relative coordinates
    relative = jac * np.where(log, 1.0, np.abs(x) + (x == 0))[None, :]
    ev, evec = np.linalg.eigh(relative.T @ relative)
    rel = ev / ev[-1] if ev[-1] > 0 else np.zeros_like(ev)
    warnings: list[str] = []
    poor: set[str] = set()
    for k in np.flatnonzero(rel < null_threshold):
        v = evec[:, k]
        poor.update(names[i] for i in np.flatnonzero(np.abs(v) >= 0.3))
        warnings.append(
            f"poorly identifiable direction (eigenvalue {rel[k]:.1e} of the largest): "
            f"{_describe_direction(names, v)}; the data barely constrain this combination"
        )
    # an interval wider than a factor wide_ratio (linear: the same relative half-width)
    relative_half = (wide_ratio - 1.0) / (wide_ratio + 1.0)
    for i, n in enumerate(names):
        if log[i]:
            wide = half[i] > 0.5 * math.log(wide_ratio)
        else:
            wide = half[i] > relative_half * abs(x[i])
        if wide:
            poor.add(n)
            warnings.append(
                f"{n} is poorly identified: {100 * level:g} % interval "
                f"[{lower[i]:.4g}, {upper[i]:.4g}] around {x[i]:.4g}"
            )
    unit = np.asarray(objective.space.to_unit(objective.space.from_vector(x)))
    at_bounds = tuple(
        n for n, u in zip(names, unit, strict=True) if u < BOUND_MARGIN or u > 1 - BOUND_MARGIN
    )
    for n in at_bounds:
        spec = objective.space[n]
        warnings.append(
            f"{n} = {float(params[n]):.4g} lies at its search bound [{spec.lower:.4g}, "
            f"{spec.upper:.4g}] {spec.unit}; its interval ignores the bound (widen the bounds?)"
        )
    return Uncertainty(
        names=names,
        estimate=x,
        coordinates=tuple("log" if f else "linear" for f in log),
        std=std,
        lower=lower,
        upper=upper,
        covariance=covariance,
        correlation=correlation,
        noise=dict(zip(objective.channels, map(float, sigma), strict=True)),
        eigenvalues=rel,
        eigenvectors=evec,
        poorly_identifiable=tuple(n for n in names if n in poor),
        warnings=tuple(warnings),
        level=level,
        at_bounds=at_bounds,
    )


def _inverse(a: np.ndarray, rcond: float = 1e-15) -> tuple[np.ndarray, np.ndarray]:
    """Pseudo-inverse of a symmetric PSD matrix, and which coordinates touch its null space."""
    eigval, eigvec = np.linalg.eigh(a)
    keep = eigval > max(eigval[-1], 0.0) * rcond
    inverse = (eigvec[:, keep] / eigval[keep]) @ eigvec[:, keep].T
    singular = np.zeros(a.shape[0], dtype=bool)
    for k in np.flatnonzero(~keep):
        singular |= np.abs(eigvec[:, k]) >= 0.3
    return inverse, singular


def _bartlett_meat(scores: np.ndarray, series: np.ndarray, lags: int) -> np.ndarray:
    """``Σ_series Σ_{t,t'} w(|t − t'|) g_t g_t'ᵀ`` with Bartlett weights ``1 − |k|/(L+1)``."""
    meat = np.zeros((scores.shape[1], scores.shape[1]))
    for key in np.unique(series):
        g = scores[series == key]
        lag = min(lags, g.shape[0] - 1)
        weights = 1.0 - np.abs(np.arange(-lag, lag + 1)) / (lags + 1)
        smoothed = np.stack(
            [np.convolve(g[:, j], weights, mode="same") for j in range(g.shape[1])], axis=1
        )
        meat += g.T @ smoothed
    return meat


__all__ = [
    "RESULT_NAMES",
    "BoundedLevenbergMarquardt",
    "BoxedDampedNewton",
    "Refinement",
    "Uncertainty",
    "BoundedSolution",
    "bounded_levenberg_marquardt",
    "bounded_least_squares",
    "refine",
    "uncertainty",
]
