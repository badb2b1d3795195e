"""Noise levels of measured channels as they are given, stored and reported: one concept for
every function that takes ``noise`` (identification, discovery, comparison, synthetic records,
experiment design, the Kalman filter).

A level is a :class:`NoiseLevel`; what a user passes is :data:`Noise`, a mapping channel → white
standard deviation in the channel's unit or a :class:`NoiseLevel`. How a level is estimated from
records is :mod:`jaxflex.diagnosis.noise`'s business.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from jaxflex.records import OUTPUT_COLUMNS

NOISE_SOURCES: tuple[str, ...] = ("given", "quantisation", "estimated", "floor")

"""How a channel's noise level was obtained: given by the user, the quantisation step of the
measured values, estimated from the residuals as white noise, or the signal's resolution floor
(the white estimate fell below what the written values can resolve: unsure)."""


@dataclass(frozen=True)
class NoiseLevel:
    """The measurement noise of one channel: standard deviation, kind and how it was obtained.

    ``kind`` is ``"white"`` (additive white noise, e.g. an accelerometer) or ``"quantised"`` (an
    encoder with step ``step``: uniform error of standard deviation ``step/√12``, bounded by
    ``±step/2``, but constant whenever the signal rests). ``source`` is one of
    :data:`NOISE_SOURCES`; ``floor`` the resolution floor an estimate was held to (0 if none).
    """

    sigma: float
    kind: str = "white"
    step: float | None = None
    source: str = "given"
    floor: float = 0.0

    def __post_init__(self) -> None:
        if self.kind not in ("white", "quantised"):
            raise ValueError(f"noise kind must be 'white' or 'quantised', got {self.kind!r}")
        if self.source not in NOISE_SOURCES:
            raise ValueError(f"noise source must be one of {NOISE_SOURCES}, got {self.source!r}")

    @classmethod
    def quantised(cls, step: float, source: str = "given") -> NoiseLevel:
        return cls(sigma=step / math.sqrt(12.0), kind="quantised", step=step, source=source)

    @property
    def unsure(self) -> bool:
        """True when the level is a resolution floor rather than a measured noise."""
        return self.source == "floor"

    def describe(self) -> str:
        """How the level was obtained, for reports: ``"given"``, ``"quantisation step q=…"``,
        ``"white, estimated"`` or ``"floor: …"``."""
        if self.source == "quantisation":
            return f"quantisation step q={self.step:.6g}"
        if self.source == "estimated":
            return "white, estimated"
        if self.source == "floor":
            return (f"floor: the white estimate lies below the resolution {self.floor:.3g} of "
                    "the written values (unsure; give it with noise=...)")
        return "given" if self.kind == "white" else f"given, quantisation step q={self.step:.6g}"

    def to_dict(self) -> dict[str, Any]:
        return {"sigma": self.sigma, "kind": self.kind, "step": self.step,
                "source": self.source, "obtained": self.describe(), "unsure": self.unsure}


Noise = Mapping[str, float | NoiseLevel]

"""Noise levels as a user gives them: channel → white σ in the channel's unit, or a
:class:`NoiseLevel` (e.g. ``{"joint_angle": 1e-4}``; on the command line ``--noise
joint_angle=1e-4``)."""


def noise_levels(noise: Noise | None,
                 channels: Sequence[str] = OUTPUT_COLUMNS) -> dict[str, NoiseLevel]:
    """User-given noise levels, validated: channel → :class:`NoiseLevel` (a number is a white
    standard deviation in the channel's unit, e.g. ``{"joint_angle": 1e-4}``)."""
    levels = {}
    for channel, value in dict(noise or {}).items():
        if channel not in channels:
            raise ValueError(f"noise given for unknown channel {channel!r}; channels: "
                             f"{list(channels)}")
        if not isinstance(value, NoiseLevel):
            try:
                value = NoiseLevel(sigma=float(value))
            except (TypeError, ValueError):
                raise ValueError(f"noise level of {channel} must be a number or a NoiseLevel, "
                                 f"got {value!r}") from None
        if not (math.isfinite(value.sigma) and value.sigma > 0):
            raise ValueError(f"noise level of {channel} must be positive and finite, got "
                             f"{value.sigma!r}")
        levels[channel] = value
    return levels


__all__ = [
    "NOISE_SOURCES",
    "Noise",
    "NoiseLevel",
    "noise_levels",
]
