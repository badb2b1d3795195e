"""Score (Lagrange-multiplier) tests of candidate effects and likelihood-ratio p-values, with
the boundary nulls of the library's effects (see :mod:`jaxflex.discovery`)."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from jaxflex.diagnosis import (
    chi2_sf,
)
from jaxflex.discovery._universe import Slot
from jaxflex.discovery.candidates import Candidate
from jaxflex.parameters import ParameterSpec

ALPHA = 0.01

"""Default family-wise significance level of each step (Bonferroni over the candidates)."""


@dataclass(frozen=True)
class ScoreResult:
    """The score test of one candidate at the current fit.

    ``statistic`` is ``S`` (one-sided tests: ``max(z, 0)²``), ``p_value`` its p-value after the
    profile correction (``profile`` members × the best member's), ``estimate`` the one-step
    estimate ``β̂`` of the candidate's parameters (physical units, from the null) and ``setting``
    the profile member it came from (e.g. ``"v_s=0.1"``). ``profile_drop`` and its p-value are
    set when the loop scanned the candidate's nonlinear profile (see :func:`profile_scan`).

    In a report, ``evidence`` holds the candidate's named statistics at its step, ``status``
    what happened to it, ``claims`` the sentences the rules of :mod:`jaxflex.discovery.explain`
    allow on them (``explanation`` joins them) and ``rank`` its place in the step's ranking.
    """

    effect: str
    parameters: tuple[str, ...]
    statistic: float
    dof: int
    p_value: float
    one_sided: bool
    z: float | None
    estimate: dict[str, float]
    units: dict[str, str]
    setting: str = ""
    profile: int = 1
    significant: bool = False
    member: int = 0
    explanation: str = ""
    profile_drop: float | None = None
    profile_p_value: float | None = None
    evidence: dict[str, Any] = field(default_factory=dict, compare=False)
    status: str = ""
    claims: tuple[dict[str, str], ...] = ()
    rank: int = 0

    def to_dict(self) -> dict[str, Any]:
        return {
            "effect": self.effect,
            "statistic": self.statistic,
            "p_value": self.p_value,
            "dof": self.dof,
            "one_sided": self.one_sided,
            "estimate": self.estimate,
            "setting": self.setting or None,
            "significant": self.significant,
            "profile_drop": self.profile_drop,
            "profile_p_value": self.profile_p_value,
            "rank": self.rank,
            "status": self.status,
            "evidence": self.evidence,
            "claims": list(self.claims),
            "explanation": self.explanation,
        }


def one_sided(spec: ParameterSpec) -> int:
    """+1 if the null is the lower boundary, −1 the upper, 0 if it lies inside the bounds."""
    if spec.null <= spec.lower:
        return 1
    if spec.null >= spec.upper:
        return -1
    return 0


def score_statistic(cand: Candidate, slot: Slot, specs: Sequence[ParameterSpec], g: np.ndarray,
                    v: np.ndarray) -> ScoreResult:
    """The score statistic of one profile member from ``g = J_c⊥ᵀ r`` and ``V = J_c⊥ᵀ J_c⊥``."""
    k = len(specs)
    side = one_sided(specs[0]) if k == 1 else 0
    if not np.all(np.isfinite(v)) or not np.trace(v) > 0:
        stat, p, z, beta = 0.0, 1.0, None, np.zeros(k)
    else:
        beta = np.linalg.pinv(v, rcond=1e-12) @ g
        if side:
            z = side * float(g[0] / math.sqrt(v[0, 0]))
            stat = max(z, 0.0) ** 2
            p = 0.5 * chi2_sf(stat, 1) if stat > 0 else 1.0
        else:
            z, stat = None, float(g @ beta)
            p = chi2_sf(stat, k)
    return ScoreResult(
        effect=cand.name,
        parameters=slot.tested_own,
        statistic=float(stat),
        dof=k,
        p_value=float(p),
        one_sided=bool(side),
        z=z,
        estimate={o: float(sp.null + b) for o, sp, b in zip(slot.tested_own, specs, beta,
                                                           strict=True)},
        units={o: sp.unit for o, sp in zip(slot.tested_own, specs, strict=True)},
        setting=cand.label(slot.member),
        profile=len(cand.effects),
        member=slot.member,
    )


def lr_test(lr: float, specs: Sequence[ParameterSpec]) -> float:
    """p-value of a likelihood-ratio statistic for adding parameters ``specs`` (boundary nulls:
    the 50:50 χ̄² mixture for one parameter)."""
    if not lr > 0:
        return 1.0
    if len(specs) == 1 and one_sided(specs[0]) != 0:
        return 0.5 * chi2_sf(lr, 1)
    return chi2_sf(lr, len(specs))


__all__ = [
    "ALPHA",
    "ScoreResult",
]
