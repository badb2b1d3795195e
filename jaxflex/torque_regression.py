"""The missing torque's shape: sparse regression of the smoothed ``d̂`` on candidate terms.

:func:`torque_map` takes :func:`jaxflex.missing_torque.estimate_missing_torque`'s result and
regresses ``d̂`` on a library of terms of the smoothed hub angle ``theta``, velocity ``omega``,
the input ``u`` and the time ``t`` (:func:`default_terms`; every term's name is a SymPy formula
in those variables, so the map it finds is one a rig file's formula torque can take):

1. samples whose ``d̂`` is much less certain than the record's typical sample (standard
   deviation over :data:`UNCERTAIN` times the median: the start, where the torque's prior
   still shows, and the end) are left out, and the rest thinned to at most
   :data:`MAX_SAMPLES`;
2. stability selection: on ``B`` subsamples, each half of the samples' :data:`BLOCKS`
   consecutive blocks (``d̂`` is correlated from sample to sample; no sample twice), thinned to
   one sample per correlation time of the residuals of a least-squares fit on every term
   (:func:`correlation_time`: the criterion counts independent samples), the lasso
   path of the standardised, centred columns is cut by the Bayesian information criterion
   (scikit-learn's ``LassoLarsIC``; the noise variance the mean of ``d̂``'s own variance, or
   that of the residuals of the fit on every term where larger); a
   term's *inclusion probability* is the fraction of subsamples that keep it;
3. the terms kept in at least :data:`STABLE` of them are refitted by ordinary least squares
   (with a constant), each coefficient's 95 % interval the percentiles over ``B`` moving-block
   bootstrap resamples (blocks of ``n/BLOCKS`` samples); those whose interval holds zero are
   dropped and the rest refitted.

The words follow :data:`MAP_RULES`: ``d̂`` within :data:`NOISE_LEVEL` times its own standard
deviation (RMS over RMS) is *at noise level* and no term is selected; otherwise the fraction of
``d̂``'s variance that the map explains says whether the missing torque is a function of the
state and input, partly one, or none (then it points at a sensor, not the dynamics).
"""

from __future__ import annotations

import warnings
from collections.abc import Sequence
from typing import NamedTuple

import numpy as np
import sympy

from jaxflex.missing_torque import MissingTorque

VARIABLES = ("theta", "omega", "u", "t")
"""The variables of a term: smoothed hub angle (rad), velocity (rad/s), input, time (s)."""
SIGN_SMOOTHING = 0.01
"""Velocity (rad/s) over which the smoothed sign ``tanh(omega/0.01)`` turns."""
DEAD_ZONE_FRACTIONS = (0.05, 0.1, 0.2, 0.3)
"""Dead-zone half-widths ``c`` as fractions of the largest ``|u|``: a dead zone withholds the
torque ``clip(u, −c, c)``, the term ``Max(Min(u, c), -c)``."""
SATURATION_FRACTIONS = (0.5, 0.75)
"""Saturation levels ``c`` as fractions of the largest ``|u|``: a saturation withholds
``u − clip(u, −c, c)``, the term ``u - Max(Min(u, c), -c)``."""
STRIBECK_FRACTIONS = (0.05, 0.2)
"""Stribeck velocities ``vs`` as fractions of the largest ``|omega|`` for the decaying term
``tanh(omega/0.01)*exp(-(omega/vs)**2)``."""
HARMONICS = 8
"""Default highest harmonic ``k`` of ``sin(k*theta)``, ``cos(k*theta)``."""
UNCERTAIN = 2.0
"""Samples whose ``d̂`` standard deviation exceeds this multiple of the median are left out."""
MAX_SAMPLES = 1000
"""At most this many samples (evenly thinned) enter the regression."""
BLOCKS = 25
"""The moving-block bootstrap cuts the samples into blocks of ``n/BLOCKS`` samples."""
STABLE = 0.6
"""Inclusion probability from which a term is stable (kept for the refit)."""
NOISE_LEVEL = 2.0
"""``RMS(d̂) / RMS(σ_d̂)`` at or below which the missing torque is at noise level."""
EXPLAINED = 0.8
"""Explained variance from which the missing torque is a function of state and input."""
PARTLY = 0.3
"""Explained variance from which it is partly one (below: none)."""

MAP_RULES: dict[str, tuple[str, str]] = {
    "noise": (f"RMS(d̂) <= {NOISE_LEVEL:g}·RMS(σ)",
              "at noise level: the missing torque is within its own uncertainty"),
    "explained": (f"explained variance >= {EXPLAINED:g}",
                  "a function of state and input"),
    "partly": (f"{PARTLY:g} <= explained variance < {EXPLAINED:g}",
               "partly a function of state and input"),
    "sensor": (f"explained variance < {PARTLY:g}",
               "no function of state and input: points at a sensor, not the dynamics"),
}
"""The map's verdicts: key → (rule, words), checked in this order."""

_SYMBOLS = sympy.symbols(VARIABLES)


def _round(value: float) -> str:
    """Two significant digits, as a formula writes them."""
    return f"{float(f'{value:.2g}'):g}"


def default_terms(estimate: MissingTorque, harmonics: int = HARMONICS) -> tuple[str, ...]:
    """The candidate terms for ``estimate``'s records (see the module constants): ``1``,
    ``theta``, ``sin/cos(k*theta)`` for ``k = 1..harmonics``, ``omega``, the smoothed sign,
    ``abs(omega)*omega``, Stribeck-like decays, ``u``, dead zones, saturations and ``t``.
    Thresholds scale with the records' largest ``|u|`` and ``|omega|``. The input's rate is
    not a candidate: a formula in ``theta, omega, u, t`` cannot state it."""
    if isinstance(harmonics, bool) or not isinstance(harmonics, int) or harmonics < 0:
        raise ValueError(f"harmonics={harmonics!r}: expected a non-negative int")
    u_max = max(float(np.max(np.abs(r.u))) for r in estimate.records)
    w_max = max(float(np.max(np.abs(r.omega))) for r in estimate.records)
    sign = f"tanh(omega/{SIGN_SMOOTHING:g})"
    terms = ["1", "theta"]
    for k in range(1, harmonics + 1):
        terms += [f"sin({k}*theta)", f"cos({k}*theta)"] if k > 1 else ["sin(theta)", "cos(theta)"]
    terms += ["omega", sign, "abs(omega)*omega"]
    terms += [f"{sign}*exp(-(omega/{_round(f * w_max)})**2)" for f in STRIBECK_FRACTIONS
              if w_max > 0]
    terms += ["u"]
    if u_max > 0:
        terms += [f"Max(Min(u, {c}), -{c})" for c in
                  dict.fromkeys(_round(f * u_max) for f in DEAD_ZONE_FRACTIONS)]
        terms += [f"u - Max(Min(u, {c}), -{c})" for c in
                  dict.fromkeys(_round(f * u_max) for f in SATURATION_FRACTIONS)]
    return (*terms, "t")


def term_function(term: str):
    """A formula in ``theta, omega, u, t`` as a NumPy function of them (a ValueError naming the
    term unless it parses and uses only those variables)."""
    try:
        expr = sympy.sympify(term, locals=dict(zip(VARIABLES, _SYMBOLS, strict=True)))
    except (sympy.SympifyError, SyntaxError, TypeError) as error:
        raise ValueError(f"term {term!r} is not a formula: {error}") from None
    stray = sorted(str(s) for s in expr.free_symbols if s not in _SYMBOLS)
    if stray:
        raise ValueError(f"term {term!r} uses {stray}; terms may use only {list(VARIABLES)}")
    return sympy.lambdify(_SYMBOLS, expr, "numpy")


def term_variables(term: str) -> set[str]:
    """The variables a term uses."""
    return {str(s) for s in sympy.sympify(
        term, locals=dict(zip(VARIABLES, _SYMBOLS, strict=True))).free_symbols}


def evaluate_terms(terms: Sequence[str], theta, omega, u, t) -> np.ndarray:
    """The terms' values at the samples (samples × terms)."""
    n = np.shape(theta)[0]
    return np.stack([np.broadcast_to(np.asarray(term_function(s)(theta, omega, u, t),
                                                dtype=np.float64), (n,)) for s in terms], 1)


class TorqueMap(NamedTuple):
    """:func:`torque_map`'s result. ``terms`` the library; ``inclusion`` each term's bootstrap
    inclusion probability (the constant, always fitted, 1); ``selected`` the terms of the map
    with ``coefficients`` and 95 % ``intervals``; ``expression`` the map as a formula in
    ``theta, omega, u, t``; ``explained`` the fraction of ``d̂``'s variance it explains;
    ``noise_ratio`` ``RMS(d̂)/RMS(σ_d̂)``; ``verdict`` a key of :data:`MAP_RULES` and ``words``
    its words."""

    terms: tuple[str, ...]
    inclusion: dict[str, float]
    selected: tuple[str, ...]
    coefficients: dict[str, float]
    intervals: dict[str, tuple[float, float]]
    expression: str
    explained: float
    noise_ratio: float
    verdict: str
    words: str
    samples: int

    def to_dict(self) -> dict:
        """The map as JSON-ready values (intervals as ``[low, high]``)."""
        return {"expression": self.expression, "verdict": self.verdict, "words": self.words,
                "explained": self.explained, "noise_ratio": self.noise_ratio,
                "samples": self.samples, "coefficients": dict(self.coefficients),
                "intervals": {k: list(v) for k, v in self.intervals.items()},
                "inclusion": dict(self.inclusion), "terms": list(self.terms)}

    def evaluate(self, theta, omega, u, t, only: set[str] | None = None) -> np.ndarray:
        """The map at the samples; with ``only``, the selected terms that use no other
        variable than those (and the constant)."""
        keep = [s for s in self.selected if only is None or term_variables(s) <= only]
        total = np.zeros(np.shape(theta)[0])
        for s in keep:
            total = total + self.coefficients[s] * evaluate_terms([s], theta, omega, u, t)[:, 0]
        return total


def term_product(factor: str, term: str) -> str:
    """``factor*term`` as formula text: the term in parentheses where it is a sum
    (``c*(u - Max(Min(u, 0.2), -0.2))``), the constant term ``1`` as ``factor`` alone."""
    if term == "1":
        return factor
    grouped = " + " in term or " - " in term
    return f"{factor}*({term})" if grouped else f"{factor}*{term}"


def _expression(coefficients: dict[str, float]) -> str:
    """``c1*term1 + c2*term2``, each coefficient to four significant digits."""
    parts = [term_product(f"{c:.4g}", term) for term, c in coefficients.items()]
    text = " + ".join(parts) or "0"
    return text.replace("+ -", "- ")


def _blocks(n: int, rng: np.random.Generator) -> np.ndarray:
    """One moving-block bootstrap resample of ``n`` sample indices."""
    size = max(1, n // BLOCKS)
    starts = rng.integers(0, n - size + 1, size=-(-n // size))
    return (starts[:, None] + np.arange(size)).ravel()[:n]


def _half_blocks(n: int, rng: np.random.Generator) -> np.ndarray:
    """A stability-selection subsample: half of the ``BLOCKS`` blocks, without replacement."""
    edges = np.linspace(0, n, BLOCKS + 1).astype(int)
    chosen = np.sort(rng.choice(BLOCKS, BLOCKS // 2, replace=False))
    return np.concatenate([np.arange(edges[b], edges[b + 1]) for b in chosen])


def correlation_time(residual: np.ndarray) -> float:
    """The integrated autocorrelation time (samples) of ``residual``: ``1 + 2Σρ_k`` over the
    lags before the autocorrelation first falls to zero or below (at least 1)."""
    r = residual - residual.mean()
    power = float(r @ r)
    if power == 0.0:
        return 1.0
    rho = np.correlate(r, r, "full")[r.size:] / power
    stop = np.flatnonzero(rho <= 0.0)
    return max(1.0, 1.0 + 2.0 * float(np.sum(rho[: stop[0] if stop.size else rho.size])))


def _lasso_bic(x: np.ndarray, y: np.ndarray, noise_variance: float) -> np.ndarray:
    """Which standardised columns the BIC-cut lasso path keeps, the noise variance the
    smoother's own (the residuals of a regression on correlated samples would understate it)."""
    from sklearn.exceptions import ConvergenceWarning
    from sklearn.linear_model import LassoLarsIC
    from sklearn.preprocessing import StandardScaler

    z = StandardScaler().fit_transform(x)
    with warnings.catch_warnings():  # near-collinear terms: LARS drops one and says so
        warnings.simplefilter("ignore", ConvergenceWarning)
        fit = LassoLarsIC(criterion="bic", noise_variance=noise_variance).fit(z, y - y.mean())
    return np.abs(fit.coef_) > 0


def _ols(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Least-squares coefficients of ``[1, x]``."""
    design = np.column_stack([np.ones(len(y)), x])
    return np.linalg.lstsq(design, y, rcond=None)[0]


def torque_map(estimate: MissingTorque, *, terms: Sequence[str] | None = None,
               bootstrap: int = 50, seed: int = 0) -> TorqueMap:
    """The shape of ``estimate``'s missing torque (see the module doc): ``terms`` default to
    :func:`default_terms`; ``bootstrap`` resamples seeded by ``seed``."""
    if not isinstance(estimate, MissingTorque):
        raise TypeError("torque_map takes the MissingTorque of estimate_missing_torque")
    if isinstance(bootstrap, bool) or not isinstance(bootstrap, int) or bootstrap < 2:
        raise ValueError(f"bootstrap={bootstrap!r}: expected an int >= 2")
    terms = tuple(default_terms(estimate) if terms is None else terms)
    keep = [r.std <= UNCERTAIN * np.median(r.std) for r in estimate.records]
    pick = {name: np.concatenate([getattr(r, name)[k] for r, k in
                                  zip(estimate.records, keep, strict=True)])
            for name in ("torque", "std", "theta", "omega", "u", "time")}
    stride = max(1, -(-pick["torque"].size // MAX_SAMPLES))
    pick = {k: v[::stride] for k, v in pick.items()}
    y, n = pick["torque"], pick["torque"].size
    columns = evaluate_terms(terms, pick["theta"], pick["omega"], pick["u"], pick["time"])
    varying = [i for i in range(len(terms)) if np.std(columns[:, i]) > 0]
    noise_ratio = float(np.sqrt(np.mean(y**2)) / np.sqrt(np.mean(pick["std"] ** 2)))
    full = columns[:, varying]
    residual = y - np.column_stack([np.ones(n), full]) @ _ols(full, y) if n > len(varying) + 1 \
        else y - y.mean()
    spacing = max(1, round(correlation_time(residual)))
    # the noise the criterion weighs a term against: the smoother's own, or what the whole
    # library leaves unexplained where that is more (a torque of no term: a sensor's)
    variance = max(float(np.mean(pick["std"] ** 2)), float(np.var(residual)))
    rng = np.random.default_rng(seed)
    resamples = [_blocks(n, rng) for _ in range(bootstrap)]
    counts = np.zeros(len(terms))
    for _ in range(bootstrap):
        idx = _half_blocks(n, rng)[::spacing]
        counts[varying] += _lasso_bic(columns[idx][:, varying], y[idx], variance)
    inclusion = {s: float(c / bootstrap) for s, c in zip(terms, counts, strict=True)}
    inclusion.update({s: 1.0 for i, s in enumerate(terms) if i not in varying})
    if noise_ratio <= NOISE_LEVEL:
        verdict, chosen, coefficients, intervals, explained = "noise", [], {}, {}, 0.0
    else:
        chosen = [i for i in varying if counts[i] / bootstrap >= STABLE]
        for _ in range(2):  # refit; drop the terms whose interval holds zero; refit
            boots = np.array([_ols(columns[idx][:, chosen], y[idx]) for idx in resamples])
            low, high = np.percentile(boots, [2.5, 97.5], axis=0)
            significant = (low > 0) | (high < 0)
            chosen = [i for i, s in zip(chosen, significant[1:], strict=True) if s]
        beta = _ols(columns[:, chosen], y)
        boots = np.array([_ols(columns[idx][:, chosen], y[idx]) for idx in resamples])
        low, high = np.percentile(boots, [2.5, 97.5], axis=0)
        names = ["1", *(terms[i] for i in chosen)]
        with_constant = bool(low[0] > 0 or high[0] < 0)
        order = [j for j in range(len(names)) if j > 0 or with_constant]
        coefficients = {names[j]: float(beta[j]) for j in order}
        intervals = {names[j]: (float(low[j]), float(high[j])) for j in order}
        fitted = np.column_stack([np.ones(n), columns[:, chosen]]) @ beta
        explained = float(1.0 - np.var(y - fitted) / np.var(y))
        verdict = ("explained" if explained >= EXPLAINED else
                   "partly" if explained >= PARTLY else "sensor")
    return TorqueMap(
        terms=terms, inclusion=inclusion, selected=tuple(coefficients), coefficients=coefficients,
        intervals=intervals, expression=_expression(coefficients), explained=explained,
        noise_ratio=noise_ratio, verdict=verdict, words=MAP_RULES[verdict][1], samples=n)


__all__ = ["MAP_RULES", "TorqueMap", "VARIABLES", "default_terms", "evaluate_terms",
           "correlation_time", "term_function", "term_product", "term_variables", "torque_map"]
