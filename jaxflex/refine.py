"""Gradient refinement of an identified parameter set, and how well each parameter is known.

Refinement: one engine
    :func:`bounded_least_squares` is jaxflex's one gradient refinement: optimistix's
    Levenberg–Marquardt (trust region, QR solve of the damped system) with a descent that
    respects box bounds (:class:`BoxedDampedNewton`: a parameter on a bound that the gradient
    pushes outwards is held there for the step, each step is cut back into the box), and a
    dense forward-mode Jacobian (:func:`dense_jacobian`: a handful of parameters, thousands of
    residuals). It serves identification (:func:`refine`: the objective's residuals in the unit
    box of the search, optimistix's damping ``λ I``; Marquardt's, near Gauss–Newton from the
    first step, carried the noise-free test's ``b_v`` and ``β`` onto their bounds and stopped
    there) and discovery (its quantisation-aware likelihood, :mod:`jaxflex.discovery`, with
    Marquardt's scale-free ``λ diag(JᵀJ)``, as its NumPy solver had): the fitted set
    is a boolean mask (held parameters keep their start values, their Jacobian columns vanish),
    so one compilation serves every fitted set of the same size. A refined point is kept only
    if its cost is finite and lower than at the start.

    It replaced two engines: optimistix in the logit coordinates ``z = logit(u)`` (refine) and a
    NumPy active-set Levenberg–Marquardt (discovery), which discovery had kept because the
    logit path compiled once per fitted set (22–28 s each), ran 3.7–4× slower and, with a
    parameter ending on its bound, used all its steps (``z`` runs off to infinity). The mask
    removes the recompilations and the box-aware descent holds a bound parameter instead of
    chasing it. The slowness was steps, not Jacobians (one step of each costs one forward pass
    with 8 tangents): optimistix's stopping test (the step and every residual within
    ``rtol``/``atol``) is not met while the cost only changes at round-off, so a fit that had
    converged in 14 steps ran all 30; the solver is therefore stepped in a loop that also stops
    on discovery's rule (``ftol``). Discovery needs Marquardt's scale-free damping: with
    optimistix's ``λ I`` (first ``λ = 1``) on a cost of millions, an added payload stalled at
    9.96e6 where the NumPy solver reached 141,921. Discovery's solve calls its own compiled
    Jacobian block back (:func:`bounded_least_squares_of`) rather than compiling the simulator's
    derivatives a second time (45.6 s cold, against 1.6 s for the solve without them).

    Measured on a busy 2-core CPU (load 8–10), both engines in one process without the
    persistent compilation cache: discovery on the payload case of ``tests/test_discover.py``
    (a base refit and the refit with the payload from the test's start, first call compiling
    and second; then a whole ``discover`` run with a hold-out); identify's refinement from its
    test start on noisy records (seeds 0 and 1):

    ==================  ===================  ================  =====  =======  ===========
    engine              case                 cost              steps  compile  run
    ==================  ===================  ================  =====  =======  ===========
    NumPy bounded LM    refit, 6 parameters  2930887.89336     27     shared   6.54 s
    this one            refit, 6 parameters  2930887.89122     28     14 s     3.57 s
    NumPy bounded LM    + payload, 7         6188.5251549      18     shared   5.06–7.97 s
    this one            + payload, 7         6188.52515495     17     shared   6.51–9.13 s
    NumPy bounded LM    discover             5494.61760156     —      —        48.8 s
    this one            discover             5494.61760015     —      —        39.8 s
    optimistix, logit   identify, seed 0     4.49728707151e-5  45     37.3 s   4.66 s
    this one            identify, seed 0     4.49728707155e-5  20     31.7 s   3.69 s
    optimistix, logit   identify, seed 1     4.38511897969e-5  43     shared   5.97 s
    this one            identify, seed 1     4.38511897937e-5  31     shared   3.87 s
    ==================  ===================  ================  =====  =======  ===========

    Costs are what each minimises. "shared": compiled by an earlier row; discovery's Jacobian
    block (25.7 s cold) is compiled by its score tests anyway. In the table's run the 14 s of
    this solver in discovery were 1.8 s for the solve and a second compilation of that block
    for the solve's callback, which ran under ``jax.default_device``; with that context reset
    (:func:`bounded_least_squares_of`) a whole ``discover`` run in a fresh process took 80.6 s
    against 73.2 s with the NumPy solver, a second run 43.0 s against 43.9 s (both at once).

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

    What the intervals assume, and the robust ones beside them: the nominal intervals hold if
    the model is right and each channel's noise white. Both are checked on the residuals
    (:func:`jaxflex.diagnosis.correlation.autocorrelation`: the lag-1 correlation and a
    Ljung–Box test per channel, records pooled), and a *robust* interval is always given beside
    the nominal one: the same sandwich with the Newey–West (Bartlett HAC) meat of the residuals
    themselves, ``M = Σ_series Σ_{|k|≤L} (1 − |k|/(L+1)) Σ_t g_t g_{t−k}ᵀ`` with the scores
    ``g_t = J_t e_t`` within each record and channel. That is the misfit-consistent
    (Eicker–Huber–White) estimate extended to autocorrelated residuals: a model error leaves
    smooth residuals, correlated over hundreds of samples, and White's diagonal meat alone
    would treat each sample as new evidence. The bandwidth ``L`` of each record and channel is
    Andrews' AR(1) plug-in ``1.1447 (α T)^{1/3}``, ``α = 4ρ²/((1 − ρ)²(1 + ρ)²)`` from the
    residuals' lag-1 correlation ``ρ``, at most a quarter of the record (``HAC_MAX_FRACTION``):
    white residuals give ``L ≈ 1`` and robust ≈ nominal, smooth ones the cap, where the robust
    interval is itself a lower bound of the truth's spread. When some channel fails the
    whiteness test (``WHITE_ALPHA``) and the robust intervals come out wider than the nominal
    ones by more than ``WIDENING_LIMIT``, the nominal ones are labelled conditional on the
    model (a quantised encoder alone fails the test on a correct model while widening
    nothing). Measured on the reference records (noise seed 0, refined from the test start):
    correct model, robust/nominal half-widths 0.96–0.99; records with a 5 g payload fitted
    without it (24 % rms NRMSE, residual lag-1 correlation 0.99), 4.7–13.6 (E ±0.37 % →
    ±4.7 %, J_h ±0.87 % → ±12 %); the DaISy 96-009 arm at its README fit (70 % NRMSE, lag-1
    correlation 0.84, bandwidth 47 samples), 1.4 (E: ±0.18 % → ±0.25 %) to 3.7 (τ_c), b_v
    not identifiable. The robust intervals answer "how much would the estimate move with
    other records of the same kind", misfit included; they do not measure how far a wrong
    model's best parameters are from the physical ones, which is why the label stays.

    An interval that is infinite or spans more than a factor ``UNIDENTIFIABLE_RATIO`` (a linear
    parameter: a half-width above its own size) is not an interval but the absence of one: the
    parameter is reported as not identifiable from these records.

    Identifiability: the eigen-decomposition of ``Jᵀ J`` of the objective's own residuals in
    relative coordinates (``∂e/∂ log x``) — independent of the noise estimate, so it also speaks
    for noise-free data. Eigenvalues below ``null_threshold · λ_max`` are near-null directions;
    the parameters that dominate them (and any whose interval spans more than a factor
    ``wide_ratio``) are reported as poorly identifiable.
"""

from __future__ import annotations

import itertools
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
from jaxflex.parallel import usable_cores

RESULT_NAMES: tuple[str, ...] = (
    "successful",
    "nonlinear_max_steps_reached",
    "nonlinear_divergence",
    "nonfinite",
)
BOUND_MARGIN = 1e-3
"""An estimate within this fraction of the search range (unit box) of a bound is 'at the bound'."""
UNIDENTIFIABLE_RATIO = 100.0
"""An interval spanning more than this factor (a linear parameter: a half-width above its own
size), or an infinite one, is reported as "not identifiable from these records"."""
WHITE_ALPHA = 0.01
"""Level of the Ljung–Box test below which a channel's residuals count as not white."""
HAC_MAX_FRACTION = 4
"""The robust intervals' Bartlett bandwidth is at most ``1/HAC_MAX_FRACTION`` of a record."""
WIDENING_LIMIT = 1.5
"""Residuals that are not white *and* robust intervals wider than this factor: the nominal
intervals are labelled conditional on the model (quantised encoders alone fail the whiteness
test while widening nothing)."""


def _result_name(result: optx.RESULTS) -> str:
    for name in RESULT_NAMES:
        if bool(result == getattr(optx.RESULTS, name)):
            return name
    return "failed"


_RESULT_MEANINGS = {
    "successful": "converged",
    "nonlinear_max_steps_reached": (
        "Levenberg–Marquardt took all its steps without meeting its tolerances: the estimate "
        "is the best point it reached, not a proven least-squares optimum, and intervals "
        "computed there are only indicative; a better start (more generations, or "
        "refine_starts= above 1) may let it converge"
    ),
    "nonlinear_divergence": (
        "Levenberg–Marquardt diverged; the best point it reached is kept only where it lowers "
        "the cost"
    ),
    "nonfinite": (
        "the simulation gave inf or nan at parameters Levenberg–Marquardt tried (the model "
        "blows up there); the best finite point is kept only where it lowers the cost, and "
        "narrower bounds keep the fit away from them"
    ),
}
"""What each end of a solve means for a fit, said instead of optimistix's messages, which
speak of solvers in general (a 'root-find on a function that has no roots', 'increase
`max_steps`')."""


def _result_message(result: optx.RESULTS) -> str:
    """The end of a solve in the words of a fit (:data:`_RESULT_MEANINGS`)."""
    name = _result_name(result)
    if name in _RESULT_MEANINGS:
        return _RESULT_MEANINGS[name]
    return f"a Levenberg–Marquardt step failed: {optx.RESULTS[result]}"


def in_fit_words(message: str) -> str:
    """``message`` with any of optimistix's result messages in it replaced by what it means
    for a fit (e.g. a warning or error of the solver that reached the user)."""
    text = " ".join(message.split())
    for name, meaning in _RESULT_MEANINGS.items():
        words = " ".join(optx.RESULTS[getattr(optx.RESULTS, name)].split())
        if words and words in text:
            text = text.replace(words, meaning)
    return text


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
    ``linearization`` holds the residuals and their Jacobian in the unit box at ``end`` (from
    the solver's last step; not serialised), which :func:`uncertainty` can reuse.
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
    linearization: tuple[np.ndarray, np.ndarray] | None = field(default=None, repr=False,
                                                                 compare=False)

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
        return cls(**{k: data[k] for k in cls.__dataclass_fields__ if k != "linearization"})


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
    # the residuals and Jacobian the last accepted step evaluated, at y
    linearization = (state.f_info.residual, state.f_info.jac.as_matrix())
    return jnp.where(free, y, start), result, steps, cost_start, cost, linearization


_bounded_solve_jit = eqx.filter_jit(_bounded_solve)


@dataclass(frozen=True)
class BoundedSolution:
    """Outcome of :func:`bounded_least_squares` (costs are ``Σ r²``). ``linearization`` is the
    residual vector and its Jacobian at ``value`` from the solver's last accepted step (None
    where the start was kept)."""

    value: np.ndarray
    cost_start: float
    cost: float
    result: str
    message: str
    steps: int
    linearization: tuple[np.ndarray, np.ndarray] | None = field(default=None, repr=False)


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
    end, result, steps, cost_start, cost, linearization = solve(
        residuals, args, p, lower, upper, free, rtol, atol, ftol, max_steps, marquardt
    )
    cost_start, cost = float(cost_start), float(cost)
    cost_start = cost_start if math.isfinite(cost_start) else math.inf
    better = math.isfinite(cost) and cost < cost_start
    return BoundedSolution(
        value=np.asarray(end if better else p),
        cost_start=cost_start,
        cost=cost if better else cost_start,
        result=_result_name(result),
        message=_result_message(result),
        steps=int(steps),
        linearization=tuple(map(np.asarray, linearization)) if better else None,
    )


System = Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]]
"""``system(p)``: the residual vector and its Jacobian at ``p``, computed on the host."""

_SYSTEMS: dict[int, System] = {}
_TOKENS = itertools.count()


def _run_system(token, p):
    # a callback runs under jax.default_device(its device): reset it, or every jitted function
    # the system calls compiles a second time for that context
    with jax.default_device(None), jax.disable_jit(False):
        r, jac = _SYSTEMS[int(token)](np.asarray(p))
    return np.asarray(r, dtype=np.float64), np.asarray(jac, dtype=np.float64)


def _call_system(p, token, template):
    shapes = (jax.ShapeDtypeStruct(template.shape, p.dtype),
              jax.ShapeDtypeStruct(template.shape + p.shape, p.dtype))
    return jax.pure_callback(_run_system, shapes, token, p, vmap_method="sequential")


@jax.custom_jvp
def _system_residuals(p, token, template):
    return _call_system(p, token, template)[0]


@_system_residuals.defjvp
def _system_jvp(primals, tangents):
    r, jac = _call_system(*primals)
    return r, jac @ tangents[0]


def _host_residuals(p: Array, args: tuple) -> Array:
    return _system_residuals(p, *args)


def bounded_least_squares_of(system: System, size: int, start: ArrayLike, lower: ArrayLike,
                             upper: ArrayLike, **options) -> BoundedSolution:
    """:func:`bounded_least_squares` of a residual vector (length ``size``) and Jacobian that
    the caller computes (``system``, called back from the compiled solve).

    The solve compiles without the model in it (a few seconds, once per size) and the
    caller's own compiled Jacobian serves it: discovery's forward-mode block, which its score
    tests compile anyway, instead of a second compilation of the simulator's derivatives.
    On a single usable core the solve runs uncompiled instead: XLA's CPU runtime then has one
    worker, which a compiled solve would hold while the system's compiled code waits for it.
    """
    token = next(_TOKENS)
    _SYSTEMS[token] = system
    try:
        args = (jnp.asarray(token), jnp.zeros(size))
        if usable_cores() > 1:
            return bounded_least_squares(_host_residuals, args, start, lower, upper, **options)
        with jax.disable_jit():
            return bounded_least_squares(
                _host_residuals, args, start, lower, upper, solve=_bounded_solve, **options
            )
    finally:
        del _SYSTEMS[token]


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
        linearization=best.linearization,
    )


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
    unidentifiable: tuple[str, ...] = field(default=())
    robust_std: np.ndarray | None = None
    robust_lower: np.ndarray | None = None
    robust_upper: np.ndarray | None = None
    residual_checks: dict = field(default_factory=dict)

    @property
    def intervals(self) -> dict[str, tuple[float, float]]:
        """``name → (lower, upper)`` in physical units."""
        return {
            n: (float(lo), float(hi))
            for n, lo, hi in zip(self.names, self.lower, self.upper, strict=True)
        }

    @property
    def robust_intervals(self) -> dict[str, tuple[float, float]]:
        """``name → (lower, upper)`` of the misfit-robust (HAC) intervals; empty if none."""
        if self.robust_lower is None or self.robust_upper is None:
            return {}
        return {
            n: (float(lo), float(hi))
            for n, lo, hi in zip(self.names, self.robust_lower, self.robust_upper, strict=True)
        }

    @property
    def model_conditional(self) -> bool:
        """True when the residuals are not white: the nominal intervals then hold only if the
        model were right and the noise white, and the robust ones are the ones to read."""
        return bool(self.residual_checks.get("conditional", False))

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


def _phi_linearization(objective: Objective, x: np.ndarray, linearization):
    """A unit-box linearisation ``(r, ∂r/∂u)`` at ``x`` in the coordinates ``φ``
    (``∂φ/∂u`` is ``log(hi/lo)`` on a log scale, ``hi − lo`` otherwise), or None where a
    parameter lies on a bound: the box map clips there, and its derivative is not ``φ``'s."""
    lower = np.array([s.lower for s in objective.specs])
    upper = np.array([s.upper for s in objective.specs])
    if linearization is None or not np.all((x > lower) & (x < upper)):
        return None
    log, _, _ = _coordinate_maps(objective)
    residuals, unit_jacobian = linearization
    ratio = np.where(log, upper, 1.0) / np.where(log, lower, 1.0)  # 1 where linear
    return residuals, unit_jacobian / np.where(log, np.log(ratio), upper - lower)


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
    linearization: tuple[np.ndarray, np.ndarray] | None = None,
    unidentifiable_ratio: float = UNIDENTIFIABLE_RATIO,
    white_alpha: float = WHITE_ALPHA,
) -> Uncertainty:
    """Gauss–Newton covariance, ``level`` intervals and identifiability at ``params``.

    ``params`` holds (at least) the free parameters of ``objective``, in physical units.
    ``linearization``, the residuals and their unit-box Jacobian at ``params`` (a refinement's
    :attr:`Refinement.linearization`), is reused where every parameter lies inside its bounds
    instead of compiling and evaluating the Jacobian again.

    Beside the nominal intervals (white noise, correct model) come the robust ones (HAC,
    bandwidth from the residuals' own lag-1 correlation) and the residual checks that say
    whether the nominal ones can be read at all (see the module doc). A parameter whose
    nominal interval spans more than a factor ``unidentifiable_ratio`` (a linear one: a
    half-width above its own size), or is infinite, is listed as ``unidentifiable``.
    """
    if not unidentifiable_ratio > wide_ratio:
        raise ValueError(f"unidentifiable_ratio must exceed wide_ratio={wide_ratio!r}, "
                         f"got {unidentifiable_ratio!r}")
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
    reused = _phi_linearization(objective, x, linearization)
    r, jac = reused or _jacobian_jit(objective, to_phi(jnp.asarray(x)))
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
    # robust: the same sandwich with the residuals' own Bartlett HAC meat
    series = record * len(sigma) + channel
    checks = _residual_checks(r / scale, series, channel, objective.channels, white_alpha)
    robust_meat = _bartlett_meat(jac * r[:, None], series, checks["hac_lags"]) * dof
    cov_robust = a_inv @ robust_meat @ a_inv
    half_robust = q * np.where(singular, np.inf,
                               np.sqrt(np.maximum(np.diag(cov_robust), 0.0)))
    with np.errstate(over="ignore", invalid="ignore"):
        checks["widening"] = dict(zip(names, map(float, half_robust / half), strict=True))
        lower = np.where(log, x * np.exp(-half), x - half)
        upper = np.where(log, x * np.exp(half), x + half)
        robust_lower = np.where(log, x * np.exp(-half_robust), x - half_robust)
        robust_upper = np.where(log, x * np.exp(half_robust), x + half_robust)
        robust_std = half_robust / q * np.where(log, x, 1.0)
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
    unidentifiable = tuple(
        n for i, n in enumerate(names)
        if not np.isfinite(half[i])
        or (half[i] > 0.5 * math.log(unidentifiable_ratio) if log[i] else half[i] > abs(x[i]))
    )
    # an interval wider than a factor wide_ratio (linear: the same relative half-width)
    relative_half = (wide_ratio - 1.0) / (wide_ratio + 1.0)
    for i, n in enumerate(names):
        if log[i]:
            wide = half[i] > 0.5 * math.log(wide_ratio)
        else:
            wide = half[i] > relative_half * abs(x[i])
        if wide and n in unidentifiable:
            poor.add(n)
        elif wide:
            poor.add(n)
            warnings.append(
                f"{n} is poorly identified: {100 * level:g} % interval "
                f"[{lower[i]:.4g}, {upper[i]:.4g}] around {x[i]:.4g}"
            )
    for n in unidentifiable:
        warnings.append(f"{n} is not identifiable from these records (its {100 * level:g} % "
                        f"interval is infinite or spans more than a factor "
                        f"{unidentifiable_ratio:g}): fix it or add records that excite it")
    widen = [w for w in checks["widening"].values() if math.isfinite(w)]
    checks["conditional"] = not checks["white"] and max(widen, default=1.0) > WIDENING_LIMIT
    if checks["conditional"]:
        coloured = [c for c, v in checks["channels"].items() if not v["white"]]
        warnings.append(
            "the intervals assume the model is right and the noise white, and the residuals "
            f"of {', '.join(coloured)} are not white (Ljung-Box p < {white_alpha:g}): "
            "read the robust intervals"
            + (f", which widen the nominal ones by a factor {min(widen):.3g}-{max(widen):.3g}"
               if widen else "")
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
        unidentifiable=unidentifiable,
        robust_std=robust_std,
        robust_lower=robust_lower,
        robust_upper=robust_upper,
        residual_checks=checks,
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


def _bartlett_meat(scores: np.ndarray, series: np.ndarray,
                   lags: int | Mapping[int, int]) -> np.ndarray:
    """``Σ_series Σ_{t,t'} w(|t − t'|) g_t g_t'ᵀ`` with Bartlett weights ``1 − |k|/(L+1)``
    (``lags``: one ``L`` for every series, or one per series key)."""
    from scipy.signal import fftconvolve

    meat = np.zeros((scores.shape[1], scores.shape[1]))
    for key in np.unique(series):
        g = scores[series == key]
        lags_here = lags if isinstance(lags, int) else lags[int(key)]
        lag = min(lags_here, g.shape[0] - 1)
        weights = 1.0 - np.abs(np.arange(-lag, lag + 1)) / (lags_here + 1)
        smoothed = fftconvolve(g, weights[:, None], mode="same", axes=0) if lag else g
        meat += g.T @ smoothed
    return meat


def _andrews_lags(rho: float, length: int) -> int:
    """Andrews' (1991) AR(1) plug-in bandwidth of the Bartlett kernel,
    ``1.1447 (α T)^{1/3}``, ``α = 4ρ² / ((1 − ρ)² (1 + ρ)²)``, at most a quarter record."""
    rho = min(max(rho, -0.999), 0.999)
    alpha = 4 * rho**2 / ((1 - rho) ** 2 * (1 + rho) ** 2)
    return int(min(math.ceil(1.1447 * (alpha * length) ** (1 / 3)), length // HAC_MAX_FRACTION))


def _residual_checks(errors: np.ndarray, series: np.ndarray, channel: np.ndarray,
                     channels: Sequence[str], alpha: float) -> dict:
    """Per channel: lag-1 correlation and Ljung–Box whiteness of the residuals (records
    pooled, :func:`jaxflex.diagnosis.correlation.autocorrelation`); per series the HAC
    bandwidth (:func:`_andrews_lags`); ``white``: every channel passes."""
    from jaxflex.diagnosis.correlation import autocorrelation

    out: dict = {"channels": {}, "hac_lags": {}, "white_alpha": alpha}
    for c, name in enumerate(channels):
        keys = [k for k in np.unique(series[channel == c])]
        segments = [errors[series == k] for k in keys]
        if not any(np.any(s != 0) for s in segments) or min(s.size for s in segments) < 10:
            out["channels"][name] = {"lag1": 0.0, "ljung_box_p": 1.0, "white": True,
                                     "hac_lags": 0}
            out["hac_lags"].update({int(k): 0 for k in keys})
            continue
        acf = autocorrelation(segments)
        out["channels"][name] = {"lag1": float(acf.values[1]), "ljung_box_p": acf.p_value,
                                 "white": bool(acf.white(alpha))}
        for k, s in zip(keys, segments, strict=True):
            s = s - s.mean()
            energy = float(s @ s)
            rho = float(s[1:] @ s[:-1]) / energy if energy > 0 else 0.0
            out["hac_lags"][int(k)] = _andrews_lags(rho, s.size)
        out["channels"][name]["hac_lags"] = max(out["hac_lags"][int(k)] for k in keys)
    out["white"] = all(v["white"] for v in out["channels"].values())
    return out


__all__ = [
    "RESULT_NAMES",
    "BoundedLevenbergMarquardt",
    "BoxedDampedNewton",
    "Refinement",
    "Uncertainty",
    "BoundedSolution",
    "bounded_least_squares",
    "bounded_least_squares_of",
    "refine",
    "uncertainty",
]
