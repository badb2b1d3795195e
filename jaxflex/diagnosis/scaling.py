"""Consistency across amplitudes: how the residual grows with the records' torque amplitude."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from jaxflex.data import Record
from jaxflex.diagnosis.noise import root_mean_square


@dataclass(frozen=True)
class AmplitudeScaling:
    """How the residual RMS grows with the records' torque amplitude, per channel.

    ``exponent`` is the least-squares slope of log RMS on log amplitude (``None`` with fewer
    than two distinct amplitudes): ≈ 1 means a linear-model error (stiffness, inertia),
    well below 1 an amplitude-independent one (friction, offsets), above 1 a nonlinearity.
    """

    amplitudes: np.ndarray
    rms: dict[str, np.ndarray]
    nrmse: dict[str, np.ndarray]
    exponent: dict[str, float | None]


def amplitude_scaling(
    records: Sequence[Record], residuals: Sequence[Mapping[str, ArrayLike]]
) -> AmplitudeScaling:
    """Residual RMS and NRMSE per record against the record's peak |torque|."""
    amplitudes = np.array([float(np.max(np.abs(r.input))) for r in records])
    channels = list(residuals[0])
    rms = {c: np.array([root_mean_square(res[c]) for res in residuals]) for c in channels}
    nrmse = {
        c: np.array([100.0 * root_mean_square(res[c]) / root_mean_square(rec.channel(c))
                     for rec, res in zip(records, residuals, strict=True)])
        for c in channels
    }
    exponent: dict[str, float | None] = {}
    distinct = np.unique(np.round(np.log(amplitudes), 6)).size > 1
    for c in channels:
        if distinct and np.all(rms[c] > 0):
            exponent[c] = float(np.polyfit(np.log(amplitudes), np.log(rms[c]), 1)[0])
        else:
            exponent[c] = None
    return AmplitudeScaling(amplitudes=amplitudes, rms=rms, nrmse=nrmse, exponent=exponent)


__all__ = [
    "AmplitudeScaling",
    "amplitude_scaling",
]
