"""Bounded Levenberg–Marquardt: jaxflex's one gradient solver for least-squares fits.

optimistix's Levenberg–Marquardt (trust region, QR solve of the damped system) with a descent
that respects box bounds (:class:`BoxedDampedNewton`: a parameter on a bound that the gradient
pushes outwards is held there for the step, each step is cut back into the box), and a dense
forward-mode Jacobian (:func:`dense_jacobian`: a handful of parameters, thousands of
residuals). The fitted set is a boolean mask (held parameters keep their start values, their
Jacobian columns vanish), so one compilation serves every fitted set of the same size. A solved
point is kept only if its cost is finite and lower than at the start.

It serves identification (:func:`jaxflex.refine.refine`: the objective's residuals in the unit
box of the search, with optimistix's damping ``λ I``, since Marquardt's, near Gauss–Newton from
the first step, carries weakly determined parameters onto their bounds) and discovery (its
quantisation-aware likelihood, :mod:`jaxflex.discovery`, with Marquardt's scale-free
``λ diag(JᵀJ)``: on a cost of millions in coordinates of order one, ``λ I`` takes bare
Gauss–Newton steps and, when those fail, stalls).

Why a mask and a box-aware descent rather than unconstrained coordinates (``z = logit(u)``): a
logit path compiles once per fitted set, and a parameter ending on its bound sends ``z`` off to
infinity and uses every step, where the box-aware descent holds it on the bound. The solver is
stepped in a loop that also stops when the cost only changes at round-off (``ftol``,
:data:`STALL_STEPS`), because optimistix's own test (the step and every residual within
``rtol``/``atol``) is not met there. Discovery's and identification's solves are stepped from
the host with the residuals and Jacobian of their own compiled programs
(:func:`bounded_least_squares_of`) rather than compiling the simulator's derivatives a second
time.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

import equinox as eqx
import jax
import jax.numpy as jnp
import lineax as lx
import numpy as np
import optimistix as optx
from jaxtyping import Array, ArrayLike, Bool, Float
from threadpoolctl import threadpool_limits

RESULT_NAMES: tuple[str, ...] = (
    "successful",
    "nonlinear_max_steps_reached",
    "nonlinear_divergence",
    "nonfinite",
)


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
    curvature: Float[Array, "d d"]  # the secant estimate of Σ rᵢ∇²rᵢ (zero without secant)
    queried: Bool[Array, ""]  # y and f_info are an accepted point's (not init's zeros)
    curved: Bool[Array, ""]  # the next step uses the curvature (it predicted the last one best)


def secant_curvature(curvature: Float[Array, "d d"], step: Float[Array, " d"],
                     jac: Float[Array, "n d"], residual: Float[Array, " n"],
                     jac_before: Float[Array, "n d"], residual_before: Float[Array, " n"]
                     ) -> Float[Array, "d d"]:
    """The structured secant update of ``S ≈ Σ rᵢ∇²rᵢ`` over an accepted ``step`` (Dennis,
    Gay & Welsch's, as in NL2SOL), sized down first where it overstates the curvature seen
    along the step; unchanged where the step shows no positive curvature (``yᵀs ≤ 0``).

    ``y = Jᵀr − J₀ᵀr₀`` is the change of the gradient, ``y♯ = (J − J₀)ᵀr`` its part from the
    residuals' own curvature; the update is the symmetric rank-two one closest to ``S`` with
    ``S₊ s = y♯``.
    """
    gradient = jac.T @ residual
    change = gradient - jac_before.T @ residual_before
    sharp = gradient - jac_before.T @ residual
    along = change @ step
    seen = step @ curvature @ step
    size = jnp.where(seen != 0, jnp.minimum(1.0, jnp.abs(step @ sharp) / jnp.where(
        seen != 0, jnp.abs(seen), 1.0)), 1.0)
    sized = size * curvature
    miss = sharp - sized @ step
    safe = jnp.where(along > 0, along, 1.0)
    updated = (sized + (jnp.outer(miss, change) + jnp.outer(change, miss)) / safe
               - (miss @ step) * jnp.outer(change, change) / safe**2)
    return jnp.where(along > 0, updated, curvature)


class BoxedDampedNewton(optx.AbstractDescent):
    """optimistix's damped Newton (Levenberg–Marquardt) descent on ``lower ≤ y ≤ upper``.

    A coordinate on a bound that the gradient ``Jᵀr`` pushes outwards is held there for the
    step (its column leaves the damped system), and the step is cut back into the box. The
    trust-region search then judges the step actually taken. The damping is optimistix's
    ``λ I`` (``λ = 1/step size``, first 1), or with ``marquardt`` Marquardt's scale-free
    ``λ diag(JᵀJ)`` (first ``λ`` :data:`FIRST_DAMPING`): on a cost of millions in coordinates
    of order one, ``λ I`` takes bare Gauss–Newton steps and, when those fail, stalls.

    With ``secant`` the damped system also holds a secant estimate ``S`` of the residuals' own
    curvature ``Σ rᵢ∇²rᵢ`` (:func:`secant_curvature`, updated at every accepted point):
    ``(JᵀJ + S + λD²) δ = Jᵀr``. Gauss–Newton alone converges only linearly where the
    residuals stay far above the noise (each step leaves a fixed fraction of the excess cost);
    ``S`` restores a superlinear tail. As in NL2SOL, a step uses ``S`` only if, of the two
    quadratic models, the one with ``S`` predicted the cost at the last accepted point at least
    as well (where it mispredicts, shorter steps alone would not mend it and the solve would
    stall); and where ``JᵀJ + S + λD²`` is not positive definite the step is the Gauss–Newton
    one. Identification's refinement keeps plain Gauss–Newton: it stops on the step's size
    rather than the cost's change, and with ``S`` took 30 steps on ROTFLEX instead of 12.
    """

    lower: Float[Array, " d"]
    upper: Float[Array, " d"]
    marquardt: bool = eqx.field(static=True, default=False)
    secant: bool = eqx.field(static=True, default=False)
    linear_solver: lx.AbstractLinearSolver = lx.QR()

    def init(self, y, f_info_struct):
        def zero(leaf):
            shaped = isinstance(leaf, jax.ShapeDtypeStruct)
            return jnp.zeros(leaf.shape, leaf.dtype) if shaped else leaf

        f_info = jax.tree.map(zero, f_info_struct)
        d = y.shape[0]
        return _BoxState(y, f_info, jnp.zeros(d, bool), jnp.ones(d), jnp.zeros((d, d)),
                         jnp.array(False), jnp.array(False))

    def query(self, y, f_info, state):
        g = f_info.jac.transpose().mv(f_info.residual)
        held = ((y <= self.lower) & (g > 0)) | ((y >= self.upper) & (g < 0))
        jac = f_info.jac.as_matrix() if self.marquardt or self.secant else None
        norms = jnp.ones(y.shape)
        if self.marquardt:
            norms = jnp.linalg.norm(jac, axis=0)
            norms = jnp.maximum(norms, 1e-6 * jnp.max(norms) + jnp.finfo(norms.dtype).tiny)
        curvature, curved = state.curvature, jnp.array(False)
        if self.secant:
            curvature, curved = self._secant(y, f_info.residual, jac, state)
        return _BoxState(y, f_info, held, norms, curvature, jnp.array(True), curved)

    @staticmethod
    def _secant(y, residual, jac, state: _BoxState):
        """The curvature updated over the step from ``state``'s point to ``y``, and whether
        the next step uses it: NL2SOL's choice, the model whose prediction of this step's cost
        was closer (none before the first step: that one is Gauss–Newton's)."""
        step, before = y - state.y, state.f_info
        jac_before = before.jac.as_matrix()
        updated = secant_curvature(state.curvature, step, jac, residual, jac_before,
                                   before.residual)
        linear = jnp.sum((before.residual + jac_before @ step) ** 2)
        cost = jnp.sum(residual**2)
        curved = state.queried & (jnp.abs(cost - linear - step @ state.curvature @ step)
                                  <= jnp.abs(cost - linear))
        return jnp.where(state.queried, updated, state.curvature), curved

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
        delta = sol.value
        if self.secant:
            delta = jnp.where(state.curved, self._with_curvature(state, damping, delta), delta)
        trial = jnp.clip(state.y - jnp.where(state.held, 0.0, delta), self.lower, self.upper)
        return trial - state.y, optx.RESULTS.promote(sol.result)

    @staticmethod
    def _with_curvature(state: _BoxState, damping, gauss_newton):
        """The solution of ``(JᵀJ + S + λD²) δ = Jᵀr`` on the free coordinates (scaled by
        ``D``, by Cholesky), or ``gauss_newton`` where that matrix is not positive definite."""
        jac = state.f_info.jac.as_matrix() / state.norms
        free = ~state.held
        matrix = jac.T @ jac + state.curvature / jnp.outer(state.norms, state.norms)
        matrix = jnp.where(jnp.outer(free, free), matrix, 0.0)
        matrix = matrix + jnp.diag(jnp.where(free, damping, 1.0))
        factor = jnp.linalg.cholesky(matrix)
        scaled = jax.scipy.linalg.cho_solve((factor, True),
                                            jnp.where(free, jac.T @ state.f_info.residual, 0.0))
        delta = scaled / state.norms
        usable = jnp.all(jnp.isfinite(factor)) & jnp.all(jnp.isfinite(delta))
        return jnp.where(usable, delta, gauss_newton)


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


def _solver(residuals: Residuals, args, start, lower, upper, free, rtol, atol, marquardt,
            secant):
    """The solver and its function of the coordinates (``residuals`` with held coordinates
    kept at ``start``), and the loop's first carry: ``(y, state, cost_start, cost, done,
    k)`` (the state's arrays only; :func:`_advance` puts its static part back)."""
    fn = dense_jacobian(lambda y: residuals(jnp.where(free, y, start), args))

    def with_aux(y, _):
        return fn(y), None

    descent = BoxedDampedNewton(lower, upper, marquardt, secant)
    solver = BoundedLevenbergMarquardt(rtol, atol, descent)
    state = solver.init(with_aux, start, None, {}, jax.eval_shape(fn, start), None, frozenset())
    state, static = eqx.partition(state, eqx.is_array)  # the loop carries arrays only
    inf = jnp.array(jnp.inf, dtype=start.dtype)  # not weakly typed: a step returns it strong
    first = (start, state, inf, inf, jnp.array(False), jnp.array(0))
    return with_aux, solver, static, first


def _advance(with_aux, solver, static, ftol, carry):
    """One step of the solve: the carry after it (the cost at the last accepted point, and
    whether the solve is done: converged, or with ``ftol`` a small or stalled step)."""
    y, state, cost_start, cost, _, k = carry
    tags = frozenset()
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


def _ending(carry, static, start, free):
    """What a solve returns from its last carry: the point, its result, steps, costs, and the
    residuals and Jacobian the last accepted step evaluated there."""
    y, state, cost_start, cost, done, steps = carry
    state = eqx.combine(state, static)
    result = optx.RESULTS.where(done, state.result, optx.RESULTS.nonlinear_max_steps_reached)
    linearization = (state.f_info.residual, state.f_info.jac.as_matrix())
    return jnp.where(free, y, start), result, steps, cost_start, cost, linearization


def _bounded_solve(residuals: Residuals, args, start, lower, upper, free, rtol, atol, ftol,
                   max_steps, marquardt=False, secant=False):
    """:class:`BoundedLevenbergMarquardt` stepped in a loop that also stops on ``ftol``."""
    with_aux, solver, static, first = _solver(residuals, args, start, lower, upper, free, rtol,
                                              atol, marquardt, secant)

    def proceed(carry):
        *_, done, k = carry
        return ~done & (k < max_steps)

    carry = jax.lax.while_loop(proceed, lambda c: _advance(with_aux, solver, static, ftol, c),
                               first)
    return _ending(carry, static, start, free)


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
    secant: bool = False,
    solve: Callable | None = None,
) -> BoundedSolution:
    """Levenberg–Marquardt (:class:`BoundedLevenbergMarquardt`) of ``residuals(p, args)`` on
    ``lower ≤ p ≤ upper``.

    ``free`` (default all) marks the fitted coordinates; the others keep their start values
    (their Jacobian columns vanish). Arrays change nothing compiled: one compilation serves
    every fitted set, start and box of the same size. It stops on optimistix's ``rtol``/``atol``
    (step and residuals), after ``max_steps``, or (``ftol > 0``) when an accepted step lowers
    the cost by less than ``ftol`` of it or :data:`STALL_STEPS` steps in a row are rejected.
    ``marquardt`` chooses the damping, ``secant`` adds the residuals' curvature to the damped
    system (:class:`BoxedDampedNewton`).
    ``solve`` is ``_bounded_solve`` compiled ahead by the caller (to time it). The value is the
    last accepted point if its cost is finite and below the start's, else the start.
    """
    solve = _bounded_solve_jit if solve is None else solve
    p, lower, upper, free = _box(start, lower, upper, free)
    return _solution(p, *solve(residuals, args, p, lower, upper, free, rtol, atol, ftol,
                               max_steps, marquardt, secant))


def _box(start, lower, upper, free):
    """A solve's start (clipped into the box where free), box and fitted mask, as arrays."""
    p = jnp.asarray(start, dtype=jnp.float64)
    lower, upper = jnp.asarray(lower, dtype=jnp.float64), jnp.asarray(upper, dtype=jnp.float64)
    free = jnp.ones(p.shape, bool) if free is None else jnp.asarray(free, dtype=bool)
    return jnp.where(free, jnp.clip(p, lower, upper), p), lower, upper, free


def _solution(start, end, result, steps, cost_start, cost, linearization) -> BoundedSolution:
    """The :class:`BoundedSolution` of a solve's ending: its last accepted point if its cost
    is finite and below the start's, else the start."""
    cost_start, cost = float(cost_start), float(cost)
    cost_start = cost_start if math.isfinite(cost_start) else math.inf
    better = math.isfinite(cost) and cost < cost_start
    return BoundedSolution(
        value=np.asarray(end if better else start),
        cost_start=cost_start,
        cost=cost if better else cost_start,
        result=_result_name(result),
        message=_result_message(result),
        steps=int(steps),
        linearization=tuple(map(np.asarray, linearization)) if better else None,
    )


System = Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]]
"""``system(p)``: the residual vector and its Jacobian at ``p``, computed on the host."""

@jax.custom_jvp
def _given(p, residual, jac):
    """``residual``, whatever ``p``, with the derivative ``jac``: the residuals and Jacobian
    the host computed at the point the solver evaluates next."""
    return residual


@_given.defjvp
def _given_jvp(primals, tangents):
    _, residual, jac = primals
    return residual, jac @ tangents[0]


def _given_residuals(p: Array, args: tuple) -> Array:
    return _given(p, *args)


@eqx.filter_jit
def _host_first(start, lower, upper, free, rtol, atol, marquardt, secant, size):
    """The first carry of a host-driven solve (:func:`bounded_least_squares_of`)."""
    template = (jnp.zeros(size), jnp.zeros((size, start.shape[0])))
    return _solver(_given_residuals, template, start, lower, upper, free, rtol, atol, marquardt,
                   secant)[3]


@eqx.filter_jit
def _host_step(carry, residual, jac, start, lower, upper, free, rtol, atol, ftol, marquardt,
               secant):
    """One step of a host-driven solve, given the residuals and Jacobian at the point it
    evaluates: the carry after it and the solve's ending there (:func:`_ending`)."""
    with_aux, solver, static, _ = _solver(_given_residuals, (residual, jac), start, lower,
                                          upper, free, rtol, atol, marquardt, secant)
    carry = _advance(with_aux, solver, static, ftol, carry)
    return carry, _ending(carry, static, start, free)


def bounded_least_squares_of(system: System, size: int, start: ArrayLike, lower: ArrayLike,
                             upper: ArrayLike, *, free: ArrayLike | None = None, rtol: float,
                             atol: float, ftol: float = 0.0, max_steps: int,
                             marquardt: bool = False, secant: bool = False) -> BoundedSolution:
    """:func:`bounded_least_squares` of a residual vector (length ``size``) and Jacobian that
    the caller computes (``system``).

    The solve is stepped from the host: each compiled step (without the model in it, compiled
    once per size) is given the residuals and Jacobian at the point it evaluates, which the
    caller's own compiled program computes — discovery's forward-mode block, which its score
    tests compile anyway, instead of a second compilation of the simulator's derivatives.
    Stepped from the host rather than calling the system back from a compiled loop, the
    system's program has every CPU worker to itself (a loop waiting in a call-back held one:
    on one core the system waited for ever). The BLAS libraries run on one thread meanwhile:
    a step's QR factorisation is LAPACK's, whose idle threads otherwise spin on the cores
    the system's next call needs (a ROTFLEX refit's Jacobian blocks took 1.5 times as long).
    """
    p, lower, upper, free = _box(start, lower, upper, free)
    fixed = (p, lower, upper, free, rtol, atol)
    with threadpool_limits(limits=1, user_api="blas"):
        carry, steps = _host_first(*fixed, marquardt, secant, size), 0
        while True:
            residual, jac = system(np.asarray(carry[1].y_eval))
            carry, end = _host_step(carry, jnp.asarray(residual, dtype=jnp.float64),
                                    jnp.asarray(jac, dtype=jnp.float64), *fixed, ftol,
                                    marquardt, secant)
            steps += 1
            if steps >= max_steps or bool(carry[4]):
                return _solution(p, *end)


__all__ = [
    "RESULT_NAMES",
    "FIRST_DAMPING",
    "STALL_STEPS",
    "BoxedDampedNewton",
    "BoundedLevenbergMarquardt",
    "BoundedSolution",
    "bounded_least_squares",
    "bounded_least_squares_of",
    "dense_jacobian",
    "in_fit_words",
    "secant_curvature",
]
