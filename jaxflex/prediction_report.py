"""Simulation and k-step-ahead prediction side by side: the table and the figures' data.

A free simulation of a plant with a free rigid-body mode, or of a closed-loop record, drifts
with every small torque mismatch; the Kalman filter's predictions (:mod:`jaxflex.kalman`) say
how well the model foresees the record a given time ahead. :func:`compare_predictions` scores
both on each record, NRMSE (percent) per channel over the whole record: the simulation, the
one-step prediction and each horizon's.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from jaxflex.data import Record
from jaxflex.kalman import Prediction, predict
from jaxflex.metrics import nrmse
from jaxflex.model import Model
from jaxflex.noise import Noise
from jaxflex.simulation import simulate_readings


@dataclass(frozen=True, eq=False)
class PredictionComparison:
    """One record's simulation and predictions (channels × samples) and their NRMSE."""

    name: str
    role: str  # "fit" or "held-out"
    time: np.ndarray
    simulated: np.ndarray
    prediction: Prediction

    @property
    def channels(self) -> tuple[str, ...]:
        return self.prediction.channels

    def scores(self) -> dict[str, dict[str, float]]:
        """NRMSE (percent) per channel: ``simulation``, ``one_step`` and ``<h> s`` per horizon;
        NaN for a channel measured zero throughout (no motion: no NRMSE is defined)."""
        measured, p = self.prediction.measured, self.prediction
        series = {"simulation": self.simulated, "one_step": p.one_step} | {
            f"{h:g} s": y for h, y in p.predicted.items()}
        return {label: {c: nrmse(measured[i], y[i]) if np.any(measured[i]) else math.nan
                        for i, c in enumerate(self.channels)}
                for label, y in series.items()}

    def to_dict(self) -> dict[str, Any]:
        p = self.prediction
        return {"name": self.name, "role": self.role, "nrmse_percent": self.scores(),
                "disturbance": p.disturbance, "measurement_noise": dict(p.sigma_y),
                "log_likelihood": p.log_likelihood}


def compare_predictions(
    records: Sequence[Record],
    model: Model,
    params: Mapping[str, float],
    horizons: Sequence[float],
    *,
    fit_names: Sequence[str] = (),
    channels: Sequence[str] | None = None,
    noise: Noise | None = None,
    disturbance: float | None = None,
) -> list[PredictionComparison]:
    """Simulate and predict each record (as the model reads it) ``horizons`` seconds ahead.

    The filter's noise levels are ``noise`` and ``disturbance`` where given, else fitted by
    maximum likelihood on each record (:func:`jaxflex.kalman.predict`). Each record is
    predicted on those of ``channels`` (default: the ones the model fits) that it logs.
    """
    rows = []
    for record in records:
        own = None if channels is None else [c for c in channels if c in record.columns]
        [prediction] = predict(record, model, params, horizons, channels=own, noise=noise,
                               disturbance=disturbance)
        out = simulate_readings(model, params, record.input, record.dt)
        rows.append(PredictionComparison(
            name=record.name, role="fit" if record.name in fit_names else "held-out",
            time=record.time, simulated=np.stack([np.asarray(out.channel(c))
                                                  for c in prediction.channels]),
            prediction=prediction))
    return rows


def prediction_table(rows: Sequence[PredictionComparison]) -> str:
    """One line per record and channel: NRMSE of the simulation, the one-step prediction and
    each horizon's prediction (percent)."""
    labels = list(rows[0].scores())
    head = f"{'record':<20} {'role':<8} {'channel':<18}" + "".join(f"{lab:>12}" for lab in labels)
    lines = ["NRMSE (%) of the simulation and of the k-step-ahead predictions", head]
    for row in rows:
        scores = row.scores()
        for c in row.channels:
            lines.append(f"{row.name[:20]:<20} {row.role:<8} {c[:18]:<18}"
                         + "".join(f"{scores[lab][c]:>12.3g}" if math.isfinite(scores[lab][c])
                                   else f"{'no motion':>12}" for lab in labels))
    return "\n".join(lines) + "\n"


__all__ = ["PredictionComparison", "compare_predictions", "prediction_table"]
