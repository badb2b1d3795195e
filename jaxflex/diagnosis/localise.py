"""Where in time and operating condition: the share of the misfit while the torque acts or in
free vibration, near zero joint velocity and at reversals, at high speed, per angle range and
per time window."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from jaxflex.data import Record
from jaxflex.diagnosis.noise import NoiseLevel, excess_misfit, root_mean_square
from jaxflex.preprocess import differentiate


@dataclass(frozen=True)
class ConditionShare:
    """The misfit in one operating condition or time window.

    ``share`` is the fraction of a channel's residual sum of squares beyond the noise that falls
    in the condition, ``combined`` the same over all channels with each normalised by its noise
    variance, ``time_share`` the fraction of samples; ``concentration = combined/time_share`` is
    above 1 where the misfit concentrates.
    """

    condition: str
    time_share: float
    share: dict[str, float]  # per channel
    combined: float
    rms: dict[str, float]  # per channel, residual RMS in the condition

    @property
    def concentration(self) -> float:
        """``combined / time_share``: how much denser the misfit is here than on average."""
        return self.combined / self.time_share if self.time_share > 0 else 0.0


@dataclass(frozen=True)
class Localisation:
    """Misfit shares by operating condition and by time window (pooled over records)."""

    conditions: tuple[ConditionShare, ...]
    windows: tuple[ConditionShare, ...]  # equal time windows, condition names "t0-t1 s"
    window_edges_s: np.ndarray

    def condition(self, name: str) -> ConditionShare:
        for c in self.conditions + self.windows:
            if c.condition == name:
                return c
        names = [c.condition for c in self.conditions + self.windows]
        raise KeyError(f"no condition {name!r}; conditions: {names}")

    def worst_window(self) -> ConditionShare:
        return max(self.windows, key=lambda c: c.concentration)


def _degrees(radians: float) -> str:
    """Whole degrees, with no "-0" for a bin edge just below zero."""
    return f"{int(round(math.degrees(radians))) + 0}"


def _masks(record: Record, velocity: np.ndarray, v_zero: float, n_angle_bins: int, reversal_s):
    """Boolean masks of the operating conditions of one record."""
    torque_on = np.abs(record.input) > 1e-3 * max(np.max(np.abs(record.input)), 1e-300)
    v_peak = max(float(np.max(np.abs(velocity))), 1e-300)
    slow = np.abs(velocity) < v_zero
    sign = np.sign(np.where(slow, 0.0, velocity))
    moving = np.flatnonzero(sign != 0)
    reversal = np.zeros(record.n_samples, dtype=bool)
    half = max(1, int(round(reversal_s / record.dt)))
    for a, b in zip(moving[:-1], moving[1:], strict=True):
        if sign[a] != sign[b]:
            reversal[max(a - half, 0) : b + half + 1] = True
    masks = {
        "torque on": torque_on,
        "free vibration": ~torque_on,
        "near-zero velocity": slow,
        "velocity reversals": reversal,
        "high speed": np.abs(velocity) > 0.5 * v_peak,
    }
    return masks


def localise(
    record: Record | Sequence[Record],
    residual: Mapping[str, ArrayLike] | Sequence[Mapping[str, ArrayLike]],
    *,
    velocity: ArrayLike | Sequence[ArrayLike] | None = None,
    angle: ArrayLike | Sequence[ArrayLike] | None = None,
    noise: Mapping[str, NoiseLevel] | None = None,
    v_zero: float = 0.05,
    reversal_s: float = 0.02,
    n_angle_bins: int = 4,
    n_windows: int = 10,
) -> Localisation:
    """Where the misfit lies: shares by operating condition and by time window.

    ``residual`` maps channel → residual (one mapping per record). ``velocity`` is the joint
    velocity (rad/s) per record, best the model's (smooth); by default it is the angle
    differentiated through a 20 Hz low-pass. ``angle`` is the joint angle per record (default:
    the measured one; give the model's for records without an encoder). Conditions: torque
    on / free vibration, near-zero velocity ``|θ'| < v_zero``, reversals (within
    ``reversal_s`` of a sign change of a moving joint), high speed (``|θ'|`` above half its
    peak), ``n_angle_bins`` equal angle ranges and ``n_windows`` equal time windows. The
    expected noise power ``σ²`` per sample (from ``noise``) is subtracted before sharing (for a
    quantised channel: only the part beyond ``±q/2`` counts), so a residual that is all noise
    shows no concentration.
    """
    records = [record] if isinstance(record, Record) else list(record)
    residuals = [residual] if isinstance(residual, Mapping) else list(residual)
    if len(residuals) != len(records):
        raise ValueError(f"{len(records)} record(s) but {len(residuals)} residual set(s)")
    if angle is None:
        angles = [r.joint_angle for r in records]
    else:
        angles = [angle] if isinstance(record, Record) else list(angle)
        angles = [np.asarray(a, dtype=np.float64) for a in angles]
    if velocity is None:
        velocities = [differentiate(a, r.dt, 1, smooth_hz=20.0)
                      for a, r in zip(angles, records, strict=True)]
    else:
        velocities = [velocity] if isinstance(record, Record) else list(velocity)
        velocities = [np.asarray(v, dtype=np.float64) for v in velocities]
    channels = list(residuals[0])
    for i, (rec, res, vel) in enumerate(zip(records, residuals, velocities, strict=True)):
        for c in channels:
            if np.shape(res[c]) != (rec.n_samples,):
                raise ValueError(
                    f"residual {c!r} of record {rec.name!r} has shape {np.shape(res[c])}, "
                    f"expected ({rec.n_samples},)"
                )
        if vel.shape != (rec.n_samples,):
            raise ValueError(f"velocity {i} has shape {vel.shape}, expected ({rec.n_samples},)")
    angle_all = np.concatenate(angles)
    angle_edges = np.linspace(angle_all.min(), angle_all.max(), n_angle_bins + 1)
    duration = max(r.duration for r in records)
    window_edges = np.linspace(0.0, duration, n_windows + 1)

    masks: dict[str, list[np.ndarray]] = {}
    for rec, vel, theta in zip(records, velocities, angles, strict=True):
        m = _masks(rec, vel, v_zero, n_angle_bins, reversal_s)
        for j in range(n_angle_bins):
            lo, hi = angle_edges[j], angle_edges[j + 1]
            name = f"angle {_degrees(lo)} to {_degrees(hi)} deg"
            upper = theta <= hi if j == n_angle_bins - 1 else theta < hi
            m[name] = (theta >= lo) & upper
        t = rec.time - rec.time[0]
        for j in range(n_windows):
            lo, hi = window_edges[j], window_edges[j + 1]
            upper = t <= hi if j == n_windows - 1 else t < hi
            m[f"{lo:.2f}-{hi:.2f} s"] = (t >= lo) & upper
        for k, v in m.items():
            masks.setdefault(k, []).append(v)

    res = {c: np.concatenate([np.asarray(r[c], dtype=np.float64) for r in residuals])
           for c in channels}
    excess = {c: excess_misfit(res[c], noise.get(c) if noise else None) for c in channels}
    # a pure-noise residual's white excess sums to 0 ± √(2N): do not share out that scatter
    scatter = {c: 3.0 * math.sqrt(2.0 * res[c].size)
               if noise and c in noise and noise[c].kind == "white" else 0.0 for c in channels}
    total = {c: max(float(excess[c].sum()), scatter[c]) for c in channels}

    def share(name: str) -> ConditionShare:
        mask = np.concatenate(masks[name])
        count = int(mask.sum())
        part = {c: max(float(excess[c][mask].sum()), 0.0) for c in channels}
        return ConditionShare(
            condition=name,
            time_share=count / mask.size,
            share={c: part[c] / total[c] if total[c] > 0 else 0.0 for c in channels},
            combined=sum(part.values()) / sum(total.values()) if sum(total.values()) else 0.0,
            rms={c: root_mean_square(res[c][mask]) if count else 0.0 for c in channels},
        )

    window_names = [f"{a:.2f}-{b:.2f} s" for a, b in zip(window_edges[:-1], window_edges[1:],
                                                         strict=True)]
    return Localisation(
        conditions=tuple(share(k) for k in masks if k not in window_names),
        windows=tuple(share(k) for k in window_names),
        window_edges_s=window_edges,
    )


__all__ = [
    "Localisation",
    "localise",
]
