"""What discovery returns: the fits, confirmations, steps and the report of a run."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from jaxflex._io import provenance, to_jsonable
from jaxflex.data import Dataset
from jaxflex.diagnosis import (
    Diagnosis,
    NoiseLevel,
)
from jaxflex.discovery.explain import RULES, bound_words, ranking_line
from jaxflex.discovery.scores import ScoreResult
from jaxflex.model import Model
from jaxflex.simulation import Outputs

if TYPE_CHECKING:
    from jaxflex.fit import Fit

SHORT: dict[str, str] = {"joint_angle": "angle", "tip_acceleration": "tip acc",
                         "root_strain": "strain", "tip_deflection": "deflection",
                         "joint_velocity": "velocity", "joint_torque": "torque"}
"""Short channel names of the step table's columns."""

INTERVAL_BASIS = ("Gauss-Newton at the stated noise levels; they assume the final model is "
                  "right and the noise as stated")
"""How the final model's intervals are computed, in the summary and in its fit file."""


@dataclass(frozen=True)
class DiscoveryFit:
    """A fitted model structure: the model, its parameters and the discovery-likelihood cost.

    ``cost`` is ``C`` of :mod:`jaxflex.discovery` (``−2 log L`` up to a constant), ``bic`` is
    ``C + n_params·ln(n_samples)``. ``covariance`` is that of the fitted parameters (physical
    units, in the order of ``intervals``), ``objective_cost`` the identification objective at
    ``params`` (:mod:`jaxflex.objective`): what a fit file calls its cost.
    """

    model: Model | None  # None for the rigid-body rung of the ladder
    params: dict[str, float]
    cost: float
    n_params: int
    n_samples: int
    noise: dict[str, NoiseLevel]
    intervals: dict[str, tuple[float, float]] = field(default_factory=dict)  # 95 %, fitted ones
    covariance: np.ndarray | None = field(default=None, repr=False, compare=False)
    objective_cost: float = math.nan

    @property
    def effects(self) -> tuple[str, ...]:
        return () if self.model is None else self.model.effect_names

    @property
    def bic(self) -> float:
        return self.cost + self.n_params * math.log(self.n_samples)


@dataclass(frozen=True)
class Confirmation:
    """The refit of one candidate: its likelihood-ratio test and BIC change.

    ``lr = C₀ − C₁`` (the drop of ``−2 log L``), ``p_value`` its p-value (one parameter on a
    boundary: ``½ P(χ²₁ > lr)``), ``delta_bic`` the BIC change, ``explained`` the share of the
    misfit above the noise it removed; ``member`` the profile member refitted (``setting``).
    ``level`` is the level the LR test was judged at, ``at_null`` whether the effect's parameters
    ended on their null-side bound, ``holdout_error`` the held-out relative error of the refit
    (the mean over the channels; ``None`` without held-out records). ``on_bound``: the effect's
    own parameters that ended on another bound, each with its side (such a refit is not
    confirmed: the bound, not the records, set its value); ``bounds`` its parameters' bounds at
    the end, ``widened`` the bounds they had before a bound was moved out to the effect's
    physical limit and the candidate refitted.
    """

    effect: str
    lr: float
    p_value: float
    delta_bic: float
    explained: float
    confirmed: bool
    params: dict[str, float]
    member: int = 0
    setting: str = ""
    level: float = math.nan
    at_null: bool = False
    holdout_error: float | None = None
    on_bound: dict[str, str] = field(default_factory=dict)
    bounds: dict[str, tuple[float, float]] = field(default_factory=dict)
    widened: dict[str, tuple[float, float]] = field(default_factory=dict)


@dataclass(frozen=True)
class Step:
    """One model structure of a discovery run and how well it fits."""

    added: str | None
    fit: DiscoveryFit
    nrmse: dict[str, float]  # percent, mean over records
    frf_nrmse: float  # percent, mean over records
    holdout: dict[str, dict[str, float]] | None
    diagnosis: Diagnosis | None
    ranking: tuple[ScoreResult, ...] = ()
    confirmations: tuple[Confirmation, ...] = ()
    lr: float | None = None
    p_value: float | None = None
    explained: float | None = None
    label: str = ""
    predictions: tuple[Outputs, ...] = field(default=(), repr=False)
    holdout_predictions: tuple[Outputs, ...] = field(default=(), repr=False)
    on_bound: dict[str, str] = field(default_factory=dict)  # base parameters: name → side
    bounds: dict[str, tuple[float, float]] = field(default_factory=dict)  # of those on_bound
    alternatives: tuple[dict[str, Any], ...] = ()  # confirmed candidates about as good
    torque_map: dict[str, Any] | None = None  # the step that adds the mapped torque: its map

    def bound_notes(self) -> list[str]:
        """The :data:`~jaxflex.discovery.explain.RULES` ``"base_on_bound"`` claim of each base
        parameter that ends on a bound at this step, e.g. ``"after 'base': b_v ends on the
        upper bound of b_v (0.3 N m s/rad): the bound, not the records, set it"``."""
        from jaxflex.fit import parameter_units

        units = parameter_units(self.fit.model) if self.fit.model is not None else {}
        notes = []
        for name, side in self.on_bound.items():
            bound = self.bounds[name][0 if side == "lower" else 1]
            words = bound_words(name, side, bound, units.get(name, ""))
            notes.append(f"after '{self.structure}': {name} ends on {words}: the bound, not "
                         "the records, set it")
        return notes

    @property
    def effects(self) -> tuple[str, ...]:
        return self.fit.effects

    @property
    def bic(self) -> float:
        return self.fit.bic

    @property
    def structure(self) -> str:
        return self.label or (" + ".join(("base",) + self.effects))

    def to_dict(self) -> dict[str, Any]:
        return {
            "added": self.added,
            "structure": self.structure,
            "effects": list(self.effects),
            "params": dict(self.fit.params),
            "intervals": {n: list(v) for n, v in self.fit.intervals.items()},
            "nrmse": dict(self.nrmse),
            "frf_nrmse": self.frf_nrmse,
            "holdout": self.holdout,
            "bic": self.bic,
            "cost": self.fit.cost,
            "n_params": self.fit.n_params,
            "lr": self.lr,
            "lr_p_value": self.p_value,
            "explained": self.explained,
            "on_bound": dict(self.on_bound),
            "alternatives": [dict(a) for a in self.alternatives],
            **({"torque_map": self.torque_map} if self.torque_map is not None else {}),
        }


@dataclass(frozen=True)
class DiscoveryReport:
    """What :func:`discover` found: the steps, the ranking at each step, what is unexplained."""

    steps: tuple[Step, ...]
    unexplained: dict[str, Any] | None
    withdrawn: tuple[str, ...]
    alpha: float
    candidates: tuple[str, ...]
    records: Dataset
    holdout: Dataset | None
    settings: dict[str, Any]
    wall_time: float
    noise_floor: dict[str, float]
    withdrawn_steps: tuple[Step, ...] = ()  # the steps cut when their effects were withdrawn
    torque_map: dict[str, Any] | None = None  # the missing torque's map and what came of it

    @property
    def final(self) -> Step:
        return self.steps[-1]

    @property
    def base(self) -> Step:
        """The first flexible model (after the rigid-body rung, if any)."""
        return next(s for s in self.steps if s.label != "rigid")

    @property
    def model(self) -> Model:
        return self.final.fit.model

    @property
    def params(self) -> dict[str, float]:
        return self.final.fit.params

    @property
    def channels(self) -> tuple[str, ...]:
        """The output channels fitted and scored (the ones the records measure)."""
        return tuple(self.steps[0].nrmse)

    @property
    def added(self) -> tuple[str, ...]:
        """Effects added, in order."""
        return tuple(s.added for s in self.steps if s.added)

    @property
    def noise(self) -> dict[str, NoiseLevel]:
        """The noise level each channel used (given or estimated; ``describe()`` says how)."""
        return self.final.fit.noise

    @property
    def rankings(self) -> tuple[tuple[ScoreResult, ...], ...]:
        return tuple(s.ranking for s in self.steps if s.ranking)

    def table(self) -> str:
        """The step table: structure → NRMSE per output, FRF NRMSE, held-out error, BIC."""
        channels = self.channels
        head = ["step", "structure", *(f"{SHORT.get(c, c)} NRMSE %" for c in channels),
                "FRF NRMSE %", *(f"held-out {SHORT.get(c, c)} %" for c in channels), "BIC"]
        rows = []
        for i, s in enumerate(self.steps):
            ho = s.holdout["relative_error"] if s.holdout else None
            rows.append([
                str(i), s.structure, *(f"{s.nrmse[c]:.4g}" for c in channels),
                _fmt(s.frf_nrmse), *(_fmt(100 * ho[c]) if ho else "-" for c in channels),
                f"{s.bic:.6g}" if math.isfinite(s.bic) else "-",
            ])
        widths = [max(len(r[k]) for r in rows + [head]) for k in range(len(head))]
        lines = ["  ".join(c.ljust(w) for c, w in zip(row, widths, strict=True)).rstrip()
                 for row in [head] + rows]
        floor = ", ".join(f"{k} {v:.3g} %" for k, v in self.noise_floor.items())
        lines.append(f"noise floor (NRMSE the measurement noise alone gives): {floor}")
        for channel, level in self.noise.items():
            lines.append(f"noise level {channel}: σ = "
                         f"{self.final.diagnosis.amount(level.sigma, channel, 4)} "
                         f"({level.describe()})")
        for s in (*self.steps, *self.withdrawn_steps):
            lines += s.bound_notes()
            if s.ranking:
                lines.append(ranking_line(s.structure, s.ranking))
            lines += [f"after '{s.structure}', alternatives: {a['text']}" for a in s.alternatives]
        if self.withdrawn:
            held = " and did not lower the held-out error" if self.holdout is not None else ""
            share = 100 * self.settings.get("min_explained", 0.9)
            lines.append(f"withdrawn (removed less than {share:.0f} % of the misfit above the "
                         f"noise{held}): {', '.join(self.withdrawn)}")
        if self.torque_map is not None:
            lines.append(f"torque map: {self.torque_map['claim']}")
        if self.unexplained:
            lines.append(f"UNEXPLAINED: {self.unexplained['message']}")
        else:
            lines.append("residuals are consistent with the measurement noise")
        return "\n".join(lines) + "\n"

    def summary(self) -> str:
        """The final model as ``jaxflex identify`` prints a fit: each parameter's value, its
        95 % interval (Gauss–Newton, from the discovery likelihood at the stated noise levels)
        and unit."""
        from jaxflex.fit import parameter_table, parameter_units

        final = self.final.fit
        if final.model is None:
            return ""
        lines = [f"final model: {self.final.structure} (−2 log L = {final.cost:.6g}, "
                 f"{final.n_params} fitted parameters)",
                 *parameter_table(final.params, final.intervals, parameter_units(final.model),
                                  level=0.95),
                 f"intervals: {INTERVAL_BASIS}"]
        return "\n".join(lines) + "\n"

    def explanations(self) -> list[str]:
        """The claims on each step's first three candidates, the added effect first (see
        :mod:`jaxflex.discovery.explain`: one rule per claim)."""
        lines = []
        for s in self.steps:
            lines += [f"{note}." for note in s.bound_notes()]
            for r in s.ranking[:3]:
                if r.explanation:
                    lines.append(r.explanation)
        if self.torque_map is not None:
            lines.append(f"{self.torque_map['claim']}.")
        return lines

    def to_fit(self) -> Fit:
        """The final model as a fit (:class:`jaxflex.fit.Fit`, the file ``identify --out``
        writes), so that ``validate --fit`` and ``discover --initial`` take it.

        Its intervals, standard deviations and covariance are the ones :meth:`summary` prints
        (Gauss–Newton on the discovery likelihood at the stated noise levels); ``cost`` is the
        identification objective at the final parameters, ``noise`` each channel's σ. No search
        ran on the final model: ``cost_search`` is NaN, the history empty, and ``method`` names
        the base model's search (``settings["search"]`` is null where the run started from
        given parameters). A ValueError if the final model is the rigid-body rung (no flexible
        model to write; :func:`discover` always keeps the base model).
        """
        from jaxflex.fit import Fit, History

        final = self.final.fit
        if final.model is None:
            raise ValueError("the final model is the rigid-body one: no flexible model to "
                             "write as a fit")
        fixed = dict(self.settings.get("fixed", {}))
        names = tuple(final.intervals) or tuple(n for n in final.model.space.names
                                                if n not in fixed)
        covariance = final.covariance
        if covariance is None or len(covariance) != len(final.intervals):
            covariance = np.full((0, 0), np.nan)  # none computed: intervals alone
        std = np.sqrt(np.abs(np.diag(covariance)))
        with np.errstate(invalid="ignore", divide="ignore"):
            correlation = covariance / np.outer(std, std)
        search = self.settings.get("search") or {}
        start = self.settings.get("initial_state", "rest")
        empty = np.zeros(0)
        return Fit(
            params={n: float(final.params[n]) for n in final.model.space.names},
            names=names,
            fixed=fixed,
            model=final.model,
            cost=final.objective_cost,
            cost_search=math.nan,
            intervals=dict(final.intervals),
            std=dict(zip(final.intervals, map(float, std), strict=False)),
            covariance=covariance,
            correlation=correlation,
            noise={c: float(level.sigma) for c, level in final.noise.items()},
            poorly_identifiable=(),
            warnings=() if start == "rest" else (
                f"the records' initial states ({start}) are not kept: validate with "
                f"--initial-state {start} to estimate them again",),
            history=History(best=empty, mean=empty, best_params={n: empty for n in names}),
            refinement=None,
            method=str(search.get("method", "de")).lower(),
            seed=int(self.settings["seed"]),
            settings={**self.settings, **({"strategy": {k: v for k, v in search.items()
                                                        if k != "method"}} if search else {}),
                      "made_by": f"discover ({self.final.structure})",
                      "interval_basis": INTERVAL_BASIS, "structure": self.final.structure,
                      "added": list(self.added), "withdrawn": list(self.withdrawn),
                      "discovery_cost": final.cost, "bic": final.bic},
            timing={"total": self.wall_time},
            record_names=self.records.names,
            provenance=provenance(),
            unidentifiable=tuple(n for n, (lo, hi) in final.intervals.items()
                                 if not (math.isfinite(lo) and math.isfinite(hi))),
            initial_state=start,
        )

    def to_dict(self) -> dict[str, Any]:
        """The JSON contract of ``jaxflex discover --json``."""
        return to_jsonable({
            "steps": [s.to_dict() for s in self.steps],
            "ranking": [[r.to_dict() | {"after": s.structure} for r in s.ranking]
                        for s in (*self.steps, *self.withdrawn_steps) if s.ranking],
            "withdrawn_steps": [s.to_dict() for s in self.withdrawn_steps],
            "unexplained": self.unexplained,
            "torque_map": self.torque_map,
            "withdrawn": list(self.withdrawn),
            "claim_rules": {r.name: r.when for r in RULES.values()},
            "noise_floor": self.noise_floor,
            "settings": self.settings,
            "timing": {"wall_time_s": self.wall_time},  # times only here: the rest reproduces
            "provenance": provenance(),
        })


def _fmt(x: float) -> str:
    return f"{x:.4g}" if x is not None and math.isfinite(x) else "-"


__all__ = [
    "DiscoveryFit",
    "Confirmation",
    "Step",
    "DiscoveryReport",
]
