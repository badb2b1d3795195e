"""The whole picture: :func:`diagnose` runs every diagnostic on records and the model's
predictions and returns a :class:`Diagnosis`."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from jaxflex.data import Record
from jaxflex.diagnosis.correlation import (
    Autocorrelation,
    CrossCorrelation,
    autocorrelation,
    cross_correlation,
)
from jaxflex.diagnosis.frf import LINK_OUTPUTS, FrfComparison, frf_error
from jaxflex.diagnosis.localise import Localisation, localise
from jaxflex.diagnosis.noise import (
    UNITS,
    Noise,
    NoiseLevel,
    estimate_noise,
    root_mean_square,
)
from jaxflex.diagnosis.scaling import AmplitudeScaling, amplitude_scaling
from jaxflex.diagnosis.spectrum import ResidualSpectrum, residual_spectrum
from jaxflex.records import OUTPUT_COLUMNS

RMS_RATIO_LIMIT = 1.3

"""A residual whose RMS exceeds this multiple of the noise level is "well above the noise"."""


QUANTISED_EXCESS_LIMIT = 0.25

"""Quantised channel: tolerated RMS of the residual beyond ``±q/2``, in quantisation steps."""


@dataclass(frozen=True)
class ChannelDiagnosis:
    """Everything about one output channel's residuals, pooled over the records.

    ``rate_correlation`` is the model's own output rate (its time derivative) correlated with
    the input: a late torque leaves a residual ``≈ −d·ẏ``, so a residual–input correlation of
    the opposite sign at the same lag is what a delay would leave.
    """

    channel: str
    nrmse: float  # percent, mean over records
    noise_floor_nrmse: float  # percent, the NRMSE that the noise alone would give
    rms: float
    noise: NoiseLevel
    whiteness: Autocorrelation
    input_correlation: CrossCorrelation
    spectrum: ResidualSpectrum
    beyond_quantisation: float | None  # RMS of (|r| − q/2)⁺ in steps q; quantised channels only
    rate_correlation: CrossCorrelation | None = None  # the model's output rate vs the input

    @property
    def rms_ratio(self) -> float:
        """Residual RMS over the noise standard deviation (≈ 1 for a correct model)."""
        return self.rms / self.noise.sigma if self.noise.sigma > 0 else math.inf

    def consistent(self, alpha: float = 0.01) -> bool:
        """Are these residuals explained by the measurement noise?

        White noise: RMS within :data:`RMS_RATIO_LIMIT` × σ and Ljung–Box not rejected at
        ``alpha``. Quantised: the residual stays within ``±q/2`` up to
        :data:`QUANTISED_EXCESS_LIMIT` steps RMS (quantisation error is not white).
        """
        if self.noise.kind == "quantised":
            return self.beyond_quantisation is not None and (
                self.beyond_quantisation <= QUANTISED_EXCESS_LIMIT
            )
        return self.rms_ratio <= RMS_RATIO_LIMIT and self.whiteness.white(alpha)


@dataclass(frozen=True)
class Diagnosis:
    """Residual diagnostics of a model on a set of records (see :mod:`jaxflex.diagnosis`)."""

    channels: dict[str, ChannelDiagnosis]
    frf: FrfComparison | None
    localisation: Localisation
    scaling: AmplitudeScaling
    record_names: tuple[str, ...]
    nrmse_per_record: dict[str, np.ndarray]
    alpha: float = 0.01
    residuals: tuple[dict[str, np.ndarray], ...] = field(default=(), repr=False)
    units: dict[str, str] = field(default_factory=dict)  # a channel's own unit (a sensor's)

    def amount(self, value: float, channel: str, digits: int = 3) -> str:
        """``value`` in ``channel``'s unit: its own (:attr:`units`), else the output's."""
        unit = self.units.get(channel) or UNITS.get(channel, "")
        return f"{value:.{digits}g}" if unit in ("", "1") else f"{value:.{digits}g} {unit}"

    @property
    def consistent_with_noise(self) -> bool:
        """True if every channel's residuals are explained by its measurement noise."""
        return all(c.consistent(self.alpha) for c in self.channels.values())

    @property
    def nrmse(self) -> dict[str, float]:
        return {c: d.nrmse for c, d in self.channels.items()}

    @property
    def noise_floor(self) -> dict[str, float]:
        return {c: d.noise_floor_nrmse for c, d in self.channels.items()}

    def unexplained(self) -> dict[str, Any] | None:
        """Where structure beyond the noise remains (``None`` if consistent with noise)."""
        if self.consistent_with_noise:
            return None
        bad = [c for c in self.channels.values() if not c.consistent(self.alpha)]
        peaks = sorted(
            ((r, f) for c in bad for f, r in zip(c.spectrum.peaks_hz, c.spectrum.peak_ratios,
                                                 strict=True)),
            reverse=True,
        )
        freqs = list(dict.fromkeys(round(f, 3) for _, f in peaks))
        worst = sorted(self.localisation.windows, key=lambda w: -w.concentration)
        times = [w for w in worst if w.concentration > 1.5][:3] or worst[:1]
        parts = []
        for c in bad:
            parts.append(
                f"{c.channel}: NRMSE {c.nrmse:.3g} % vs noise floor {c.noise_floor_nrmse:.3g} % "
                f"(RMS {self.amount(c.rms, c.channel)}, {c.rms_ratio:.2g}x noise)"
            )
        where_f = ", ".join(f"{f:.1f} Hz" for f in freqs[:4])
        where_t = ", ".join(w.condition for w in times)
        message = "; ".join(parts)
        if where_f:
            message += f"; residual spectrum peaks at {where_f}"
        if where_t:
            message += f"; misfit concentrated in {where_t}"
        return {
            "message": message,
            "frequency_hz": freqs,
            "time_s": [_window_bounds(w.condition) for w in times],
            "nrmse": {c.channel: c.nrmse for c in bad},
            "noise_floor": {c.channel: c.noise_floor_nrmse for c in bad},
        }

    def summary(self) -> list[str]:
        """Human-readable findings, one per line."""
        lines = []
        for c in self.channels.values():
            ok = c.consistent(self.alpha)
            status = "consistent with noise" if ok else "NOT explained by noise"
            white = (
                f"Ljung-Box Q={c.whiteness.statistic:.3g} (p={c.whiteness.p_value:.2g})"
                if c.noise.kind == "white"
                else f"beyond quantisation {c.beyond_quantisation:.3g} steps RMS"
            )
            lines.append(
                f"{c.channel}: NRMSE {c.nrmse:.3g} % (noise floor {c.noise_floor_nrmse:.3g} %), "
                f"{white}: {status}"
            )
            lines.append(f"  noise level σ = {self.amount(c.noise.sigma, c.channel, 4)} "
                         f"({c.noise.describe()})")
            if ok:
                continue
            xc = c.input_correlation
            if xc.significant:
                lines.append(
                    f"  residual correlates with the torque: peak {xc.peak_value:+.2f} at lag "
                    f"{1e3 * xc.peak_lag_s:+.3g} ms"
                )
            if c.spectrum.peaks_hz:
                peaks = ", ".join(
                    f"{f:.1f} Hz ({r:.0f}x)"
                    for f, r in zip(c.spectrum.peaks_hz, c.spectrum.peak_ratios, strict=True)
                )
                lines.append(f"  residual spectrum above noise at {peaks}")
        if self.frf is not None:
            lines.append(f"FRF NRMSE (torque -> {self.frf.output}, 0-{self.frf.f_max:g} Hz): "
                         f"{self.frf.nrmse:.3g} %")
            for r in self.frf.resonances:
                if abs(r.shift_hz) >= 0.05:
                    where = "beyond" if r.significant else "within"
                    lines.append(
                        f"  resonance measured at {r.measured_hz:.2f} Hz, model "
                        f"{r.model_hz:.2f} Hz ({r.shift_hz:+.2f} Hz, {where} the "
                        f"{r.resolution_hz:.2g} Hz resolution)"
                    )
        if self.consistent_with_noise:
            return lines
        conds = sorted(self.localisation.conditions, key=lambda c: -c.concentration)
        for c in conds[:3]:
            if c.concentration > 1.5:
                lines.append(
                    f"  misfit concentrated in '{c.condition}': "
                    f"{100 * c.combined:.0f} % of the misfit in "
                    f"{100 * c.time_share:.0f} % of the time"
                )
        for c, e in self.scaling.exponent.items():
            if e is not None:
                lines.append(f"  {c} residual RMS grows with torque amplitude^{e:.2f}")
        return lines

    def to_dict(self) -> dict[str, Any]:
        """Plain numbers for JSON (no arrays longer than the lags of interest)."""
        channels = {}
        for name, c in self.channels.items():
            channels[name] = {
                "nrmse": c.nrmse,
                "noise_floor_nrmse": c.noise_floor_nrmse,
                "rms": c.rms,
                "noise_sigma": c.noise.sigma,
                "noise_kind": c.noise.kind,
                "noise_obtained": c.noise.describe(),
                "rms_ratio": c.rms_ratio,
                "ljung_box": {
                    "statistic": c.whiteness.statistic,
                    "dof": c.whiteness.dof,
                    "p_value": c.whiteness.p_value,
                },
                "beyond_quantisation": c.beyond_quantisation,
                "input_correlation": {
                    "peak_lag_s": c.input_correlation.peak_lag_s,
                    "peak_value": c.input_correlation.peak_value,
                    "band": c.input_correlation.band,
                },
                "spectrum_peaks_hz": list(c.spectrum.peaks_hz),
                "consistent": c.consistent(self.alpha),
            }
        frf = None
        if self.frf is not None:
            frf = {
                "output": self.frf.output,
                "nrmse": self.frf.nrmse,
                "bands": [vars(b) for b in self.frf.bands],
                "resonances": [
                    {"measured_hz": r.measured_hz, "model_hz": r.model_hz, "shift_hz": r.shift_hz,
                     "resolution_hz": r.resolution_hz, "significant": r.significant}
                    for r in self.frf.resonances
                ],
            }
        return {
            "records": list(self.record_names),
            "consistent_with_noise": self.consistent_with_noise,
            "channels": channels,
            "frf": frf,
            "localisation": {
                c.condition: {"time_share": c.time_share, "share": c.share}
                for c in self.localisation.conditions + self.localisation.windows
            },
            "amplitude_exponent": self.scaling.exponent,
            "unexplained": self.unexplained(),
        }


def _window_bounds(name: str) -> list[float]:
    lo, hi = name.removesuffix(" s").split("-")
    return [float(lo), float(hi)]


def _prediction_channels(prediction: Any, n: int, name: str,
                         channels: Sequence[str]) -> dict[str, np.ndarray]:
    """``channels`` of a prediction (an ``Outputs``, a ``Record`` or a mapping), and its joint
    angle and velocity where it has them."""
    out = {}
    for c in dict.fromkeys((*channels, "joint_angle", "joint_velocity")):
        if isinstance(prediction, Mapping):
            value = prediction.get(c)
        elif isinstance(prediction, Record):
            value = prediction.channel(c) if c in prediction.columns else None
        elif c in (getattr(prediction, "readings", None) or {}):  # a sensor's reading
            value = prediction.readings[c]
        else:
            value = getattr(prediction, c, None)
        if value is None:
            if c in channels:
                raise ValueError(f"prediction for record {name!r} has no {c!r} output")
            continue
        a = np.asarray(value, dtype=np.float64)
        if a.shape != (n,):
            raise ValueError(
                f"prediction {c!r} for record {name!r} has shape {a.shape}, expected ({n},)"
            )
        out[c] = a
    return out


def diagnose(
    records: Sequence[Record],
    predictions: Sequence[Any],
    *,
    noise: Noise | None = None,
    alpha: float = 0.01,
    max_lag: int | None = None,
    f_max: float = 15.0,
    channels: Sequence[str] = OUTPUT_COLUMNS,
    units: Mapping[str, str] | None = None,
) -> Diagnosis:
    """Run every diagnostic on the residuals of ``predictions`` (one per record) in
    ``channels``, the outputs the records measure (default ``joint_angle`` and
    ``tip_acceleration``; a rig's sensors give their own channels, e.g. ``deflection_angle``).

    A prediction is an :class:`~jaxflex.simulation.Outputs`, a :class:`Record` or a mapping
    with every channel (its ``joint_angle`` and ``joint_velocity`` localise the misfit where
    present). ``noise`` gives channels' levels (a :class:`NoiseLevel` or a white σ); the others
    are estimated by :func:`estimate_noise`. ``alpha`` is the level of the whiteness test. The
    FRF comparison uses the first of :data:`~jaxflex.diagnosis.frf.LINK_OUTPUTS` among the
    channels (none without a link channel). ``units`` gives channels' own units (a sensor's,
    e.g. ``{"acc": "counts"}``) for the findings' text.
    """
    records = list(records)
    predictions = list(predictions)
    if not records:
        raise ValueError("diagnose needs at least one record")
    if len(predictions) != len(records):
        raise ValueError(f"{len(records)} record(s) but {len(predictions)} prediction(s)")
    if not 0 < alpha < 1:
        raise ValueError(f"alpha={alpha!r} must lie in (0, 1)")
    outputs = (channels,) if isinstance(channels, str) else tuple(channels)
    if not outputs:
        raise ValueError("diagnose needs at least one channel")
    preds = [_prediction_channels(p, r.n_samples, r.name, outputs)
             for p, r in zip(predictions, records, strict=True)]
    residuals = tuple(
        {c: r.channel(c) - p[c] for c in outputs} for r, p in zip(records, preds, strict=True)
    )
    levels = estimate_noise(records, residuals, given=noise, channels=outputs)
    dt = records[0].dt
    channels = {}
    nrmse_per_record = {}
    for c in outputs:
        res = [r[c] for r in residuals]
        per_record = np.array([100.0 * root_mean_square(x) / root_mean_square(rec.channel(c))
                               for x, rec in zip(res, records, strict=True)])
        nrmse_per_record[c] = per_record
        level = levels[c]
        floor = float(np.mean([100.0 * level.sigma / root_mean_square(rec.channel(c))
                               for rec in records]))
        beyond = None
        if level.kind == "quantised":
            excess = np.concatenate([np.maximum(np.abs(x) - 0.5 * level.step, 0.0) for x in res])
            beyond = root_mean_square(excess) / level.step
        channels[c] = ChannelDiagnosis(
            channel=c,
            nrmse=float(per_record.mean()),
            noise_floor_nrmse=floor,
            rms=root_mean_square(np.concatenate(res)),
            noise=level,
            whiteness=autocorrelation(res, max_lag, dt),
            input_correlation=cross_correlation(
                res, [r.input for r in records], max_lag=min(200, records[0].n_samples // 4),
                dt=dt,
            ),
            spectrum=residual_spectrum(res, dt, noise_sigma=level.sigma),
            beyond_quantisation=beyond,
            rate_correlation=cross_correlation(
                [np.gradient(p[c], dt) for p in preds], [r.input for r in records],
                max_lag=min(200, records[0].n_samples // 4), dt=dt,
            ),
        )
    velocities = [p.get("joint_velocity") for p in preds]
    # a record without an encoder is localised along the model's joint angle
    angles = [r.joint_angle if r.joint_angle is not None else p.get("joint_angle")
              for r, p in zip(records, preds, strict=True)]
    localisation = localise(
        records, residuals, noise=levels,
        velocity=None if any(v is None for v in velocities) else velocities,
        angle=None if any(a is None for a in angles) else angles,
    )
    link = next((c for c in LINK_OUTPUTS if c in outputs), None)
    try:
        frf = None if link is None else frf_error(records, preds, f_max=f_max, output=link)
    except ValueError:
        frf = None
    return Diagnosis(
        channels=channels,
        frf=frf,
        localisation=localisation,
        scaling=amplitude_scaling(records, residuals),
        record_names=tuple(r.name for r in records),
        nrmse_per_record=nrmse_per_record,
        alpha=alpha,
        residuals=residuals,
        units=dict(units or {}),
    )


__all__ = [
    "ChannelDiagnosis",
    "Diagnosis",
    "diagnose",
]
