"""The prediction-error objective: weighted least squares of the Kalman filter's innovations.

Output error (:mod:`jaxflex.objective`) compares a free simulation with the records; on a plant
with a free rigid-body mode, or on a closed-loop record, every small torque mismatch integrates
into drift and the criterion measures the drift. Prediction error compares the one-step
predictions of the model's Kalman filter (:mod:`jaxflex.kalman`) instead: the residual is
``s_rc·(ŷ_{t|t−1} − y_t)``, the innovations, with the output-error scales ``s_rc``, so the cost is
the weighted mean squared NRMSE of the one-step predictions. The filter's noise levels (the
process-noise torque ``σ_τ`` and each channel's measurement noise) are held fixed during the
search: given, or fitted by maximum likelihood (:func:`jaxflex.kalman.fit_noise`).

:class:`PredictionObjective` is an :class:`~jaxflex.objective.Objective` whose simulation is the
filter's one-step prediction, so the evolutionary search, the Levenberg–Marquardt refinement and
the intervals use it unchanged.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Float, Scalar

from jaxflex.data import Record
from jaxflex.kalman import (
    check_disturbance,
    check_per_sample,
    filter_core,
    fit_noise,
    measurement_noise,
)
from jaxflex.noise import Noise
from jaxflex.objective import Objective, per_record

CRITERIA: tuple[str, ...] = ("output", "prediction")
"""Identification criteria: output error (free simulation) or prediction error (innovations)."""


class PredictionObjective(Objective):
    """An objective whose simulated channels are the filter's one-step predictions."""

    sigma_y: Float[Array, " C"] = eqx.field(kw_only=True)  # measurement noise per channel
    disturbance: Scalar = eqx.field(kw_only=True)  # process-noise torque σ_τ, N m

    def simulate(self, params: Mapping[str, ArrayLike]) -> tuple[Float[Array, "R C n"], ...]:
        """One-step predictions ``ŷ_{t|t−1}`` per group of equally long records."""
        full = self.full(params)

        def one(torque, measured, scale):
            return filter_core(self.model, full, torque, measured, (scale > 0).astype(float),
                               self.dt, self.channels, self.sigma_y, self.disturbance).predicted

        return tuple(per_record(one, t, y, s)
                     for t, y, s in zip(self.torque, self.measured, self.scale, strict=True))


def check_criterion(criterion: str) -> str:
    """``criterion`` if it is one of :data:`CRITERIA`, else a one-line ValueError naming it."""
    if criterion not in CRITERIA:
        raise ValueError(f"unknown criterion {criterion!r}; criteria: {list(CRITERIA)}")
    return criterion


def prediction_objective(
    objective: Objective,
    records: Sequence[Record],
    params: Mapping[str, ArrayLike],
    *,
    noise: Noise | None = None,
    disturbance: float | None = None,
) -> PredictionObjective:
    """``objective`` (built on ``records``) as prediction error. ``noise`` gives channels'
    measurement noise and ``disturbance`` the process-noise torque (N m); whatever is not given
    is fitted by maximum likelihood at ``params`` (every parameter, physical units)."""
    channels = objective.channels
    values = {k: jnp.asarray(v, dtype=jnp.float64) for k, v in params.items()}
    check_per_sample(objective.model, values, channels)
    check_disturbance(disturbance)
    levels = measurement_noise(records, objective.model, channels, noise)
    free = [c for c in channels if c not in dict(noise or {})]
    levels, disturbance = fit_noise(records, objective.model, values, channels, levels, free,
                                    disturbance)
    fields = {name: getattr(objective, name) for name in objective.__dataclass_fields__}
    return PredictionObjective(**fields, sigma_y=jnp.asarray([levels[c] for c in channels]),
                               disturbance=jnp.asarray(disturbance))


def noise_settings(objective: Objective) -> dict[str, object]:
    """The filter's noise levels of a prediction-error objective, for a fit's settings."""
    if not isinstance(objective, PredictionObjective):
        return {}
    return {"disturbance": float(objective.disturbance),
            "measurement_noise": dict(zip(objective.channels, map(float, objective.sigma_y),
                                          strict=True))}


__all__ = ["CRITERIA", "PredictionObjective", "check_criterion", "noise_settings",
           "prediction_objective"]
