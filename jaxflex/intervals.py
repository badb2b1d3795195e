"""How well each identified parameter is known: Gauss–Newton intervals, robust ones beside
them, and identifiability.

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
nothing). The robust intervals answer "how much would the estimate move with
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

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax.scipy.special import ndtri
from jaxtyping import Array, ArrayLike, Float

from jaxflex.objective import Objective

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


def phi_jacobian(objective: Objective, u: Float[ArrayLike, " d"]
                 ) -> tuple[Callable, np.ndarray, np.ndarray, int]:
    """The residuals-and-Jacobian program of ``objective`` in the coordinates ``φ``, compiled
    (lowered at the unit-box point ``u``); with the box's lower corner and extent in ``φ``,
    ``φ = lower + u·span`` (the box map without its clip), and the number of residuals.
    :func:`jaxflex.refine.refine`'s Levenberg–Marquardt steps call it: their last
    linearisation is then :func:`uncertainty`'s, on a bound too."""
    _, to_phi, _ = _coordinate_maps(objective)
    lower = np.asarray(to_phi(jnp.asarray(objective.space.lower)))
    span = np.asarray(to_phi(jnp.asarray(objective.space.upper))) - lower
    compiled = _jacobian_jit.lower(objective, jnp.asarray(lower + np.asarray(u) * span)).compile()
    return compiled, lower, span, len(objective.layout()[0])


def _phi_linearization(objective: Objective, linearization):
    """A unit-box linearisation ``(r, ∂r/∂u)`` in the coordinates ``φ`` (``∂φ/∂u`` is
    ``log(hi/lo)`` on a log scale, ``hi − lo`` otherwise; :func:`phi_jacobian`)."""
    if linearization is None:
        return None
    log, _, _ = _coordinate_maps(objective)
    lower = np.array([s.lower for s in objective.specs])
    upper = np.array([s.upper for s in objective.specs])
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
    :attr:`jaxflex.refine.Refinement.linearization`, :func:`phi_jacobian`'s scaled to the
    box), is reused instead of evaluating the Jacobian again.

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
    reused = _phi_linearization(objective, linearization)
    r, jac = reused or _jacobian_jit(objective, to_phi(jnp.asarray(x)))
    r, jac = np.asarray(r), np.asarray(jac)
    if not (np.all(np.isfinite(r)) and np.all(np.isfinite(jac))):
        raise ValueError("uncertainty: the simulation is not finite at the estimate")
    # a channel a record does not log adds zeros of scale 0: leave them out
    observed = objective.observed()
    r, jac = r[observed], jac[observed]
    n_res, d = jac.shape
    record, channel, scale = (a[observed] for a in objective.layout())

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
            + (f" ({widening_span(min(widen), max(widen))} than the nominal ones)"
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


def widening_span(low: float, high: float) -> str:
    """The robust intervals' widths over the nominal ones, in words that say which way:
    ``"1.2-6.85 x wider"``, ``"1.21 x narrower to 6.85 x wider"`` (from the ratios
    0.827-6.85)."""

    def span(a: float, b: float) -> str:
        return f"{a:.3g}" if f"{a:.3g}" == f"{b:.3g}" else f"{a:.3g}-{b:.3g}"

    if low >= 1:
        return f"{span(low, high)} x wider"
    if high <= 1:
        return f"{span(1 / high, 1 / low)} x narrower"
    return f"{1 / low:.3g} x narrower to {high:.3g} x wider"


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
    "BOUND_MARGIN",
    "UNIDENTIFIABLE_RATIO",
    "WHITE_ALPHA",
    "HAC_MAX_FRACTION",
    "WIDENING_LIMIT",
    "Uncertainty",
    "phi_jacobian",
    "uncertainty",
    "widening_span",
]
