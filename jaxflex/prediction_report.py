"""Simulation and k-step-ahead prediction side by side: the table and the figures' data.

A free simulation of a plant with a free rigid-body mode, or of a closed-loop record, drifts
with every small torque mismatch; the Kalman filter's predictions (:mod:`jaxflex.kalman`) say
how well the model foresees the record a given time ahead. :func:`compare_predictions` scores
both on each record, NRMSE (percent) per channel over the whole record: the simulation, the
one-step prediction and each horizon's.
"""

from __future__ import annotations

import math
import textwrap
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from jaxflex.data import Record
from jaxflex.kalman import Prediction, measurement_noise, predict
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
    floors: dict[str, float] = field(default_factory=dict)  # each channel's own noise level

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
            prediction=prediction,
            floors=measurement_noise([record], model, prediction.channels, noise)))
    return rows


WORSE_NOTE = (
    "{record} {channel}: the prediction {horizon} ahead ({predicted:.3g} %) is worse than the "
    "free simulation ({simulated:.3g} %): the filter's one-step innovations are {ratio:.3g}x "
    "the noise it assumes ({sigma:.4g}{unit}{floor}), so the model misses more than the random "
    "torque σ_τ = {disturbance:.3g} N m it allows for; the state the filter corrects towards "
    "the data runs off over that horizon, and the simulation is the better forecast there "
    "(what the model misses: `jaxflex discover`)")
"""The words of :func:`prediction_notes` for a horizon that predicts worse than the simulation."""


def prediction_notes(rows: Sequence[PredictionComparison],
                     units: Mapping[str, str] | None = None) -> list[str]:
    """A note for each record and channel whose prediction at some horizon is worse than the
    free simulation it starts from (the worst such horizon): by how much, and why, from the
    filter's own innovations against the noise it assumes."""
    notes = []
    for row in rows:
        scores, p = row.scores(), row.prediction
        horizons = [label for label in scores if label.endswith(" s")]
        for i, c in enumerate(row.channels):
            simulated = scores["simulation"][c]
            worse = [h for h in horizons if scores[h][c] > simulated]
            if not worse:
                continue
            horizon = max(worse, key=lambda h: scores[h][c])
            sigma = p.sigma_y[c]
            innovations = p.innovations[i][np.isfinite(p.innovations[i])]
            ratio = float(np.sqrt(np.mean(innovations**2))) / sigma if innovations.size else 0.0
            at_floor = c in row.floors and sigma <= row.floors[c] * (1.0 + 1e-9)
            unit = f" {units[c]}" if units and units.get(c) else ""
            notes.append(WORSE_NOTE.format(
                record=row.name, channel=c, horizon=horizon, predicted=scores[horizon][c],
                simulated=simulated, ratio=ratio, sigma=sigma, unit=unit,
                floor=", held at the sensor's own level" if at_floor else "",
                disturbance=p.disturbance))
    return notes


def prediction_table(rows: Sequence[PredictionComparison],
                     units: Mapping[str, str] | None = None) -> str:
    """One line per record and channel: NRMSE of the simulation, the one-step prediction and
    each horizon's prediction (percent); then :func:`prediction_notes` (``units``: each
    channel's, for the noise levels they quote)."""
    labels = list(rows[0].scores())
    head = f"{'record':<20} {'role':<8} {'channel':<18}" + "".join(f"{lab:>12}" for lab in labels)
    lines = ["NRMSE (%) of the simulation and of the k-step-ahead predictions", head]
    for row in rows:
        scores = row.scores()
        for c in row.channels:
            lines.append(f"{row.name[:20]:<20} {row.role:<8} {c[:18]:<18}"
                         + "".join(f"{scores[lab][c]:>12.3g}" if math.isfinite(scores[lab][c])
                                   else f"{'no motion':>12}" for lab in labels))
    notes = [textwrap.fill(n, 100, subsequent_indent="  ") for n in prediction_notes(rows, units)]
    return "\n".join([*lines, *notes]) + "\n"


__all__ = ["WORSE_NOTE", "PredictionComparison", "compare_predictions", "prediction_notes",
           "prediction_table"]
