"""Gradient refinement of an identified parameter set, and how well each parameter is known.

Refinement
    Levenberg–Marquardt (``optimistix``) on the residual vector of an :class:`Objective`, in the
    unconstrained coordinates ``z = logit(u)`` so that every iterate respects the bounds. The
    Jacobian is built by forward-mode AD (a handful of parameters, thousands of residuals). The
    refined point is accepted only if its cost is finite and lower than at the start.

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
import numpy as np
import optimistix as optx
from jax.scipy.special import ndtri
from jaxtyping import Array, ArrayLike, Float

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


def _solve(objective: Objective, z0: Array, rtol: float, atol: float, max_steps: int):
    residuals = dense_jacobian(objective.unconstrained_residuals)
    solver = optx.LevenbergMarquardt(rtol=rtol, atol=atol)
    sol = optx.least_squares(
        lambda z, _: residuals(z), solver, z0, max_steps=max_steps, throw=False
    )
    cost0 = jnp.sum(residuals(z0) ** 2)
    cost1 = jnp.sum(residuals(sol.value) ** 2)
    return sol.value, sol.result, sol.stats["num_steps"], cost0, cost1


_solve_jit = eqx.filter_jit(_solve)


def refine(
    objective: Objective,
    starts: Mapping[str, ArrayLike] | Sequence[Mapping[str, ArrayLike]],
    *,
    rtol: float = 1e-6,
    atol: float = 1e-8,
    max_steps: int = 100,
) -> Refinement:
    """Levenberg–Marquardt from one start (free parameters, physical) or the best of several.

    Each start is refined; the end with the lowest cost is returned, accepted only if it is
    finite and below the cost of the best start. ``rtol``/``atol`` are optimistix's stopping
    tolerances (on the step in ``z`` and on the cost); the defaults resolve the parameters far
    below their statistical uncertainty.
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
    z_starts = []
    for start in starts:
        missing = [n for n in names if n not in start]
        if missing:
            raise ValueError(f"refinement start lacks parameter(s) {missing}")
        z_starts.append(space.to_unconstrained({n: start[n] for n in names}))

    t0 = time.perf_counter()
    compiled = _solve_jit.lower(objective, z_starts[0], rtol, atol, max_steps).compile()
    compile_time = time.perf_counter() - t0
    t0 = time.perf_counter()
    runs = []
    for z0 in z_starts:
        z, result, steps, c0, c1 = compiled(objective, z0, rtol, atol, max_steps)
        runs.append((float(c1) if np.isfinite(float(c1)) else math.inf, z0, z, result, steps, c0))
    wall_time = time.perf_counter() - t0

    cost_start = min(float(r[5]) for r in runs)
    best_start = min(runs, key=lambda r: float(r[5]))[1]
    cost_end, _, z, result, steps, _ = min(runs, key=lambda r: r[0])
    return Refinement(
        start=_floats(space.from_unconstrained(best_start), names),
        end=_floats(space.from_unconstrained(z), names),
        cost_start=cost_start,
        cost_end=cost_end,
        accepted=bool(cost_end < cost_start),
        result=_result_name(result),
        message=optx.RESULTS[result] or "converged",
        steps=int(steps),
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
    "Refinement",
    "Uncertainty",
    "bounded_levenberg_marquardt",
    "refine",
    "uncertainty",
]
