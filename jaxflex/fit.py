"""A fit: an identified parameter set with how it was found and how well it is known, and its
file (JSON, format :data:`FIT_FORMAT`, checked against :data:`FIT_SCHEMA` before anything is
built from it). :func:`jaxflex.identification.identify` makes one.
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any

import numpy as np

from jaxflex import initial as _initial
from jaxflex._io import to_jsonable, write_json
from jaxflex.arm import MAX_ELEMENTS
from jaxflex.evolve import STRATEGIES, AbstractStrategy
from jaxflex.intervals import widening_span
from jaxflex.model import Model
from jaxflex.refine import Refinement
from jaxflex.testbed import Testbed

FIT_FORMAT = "jaxflex-fit/2"
"""Format tag written into fit files; bumped when their layout changes. Version 2 stores the
whole rig (:func:`describe_model`); version 1, which stored its testbed and effects, is read."""
_FORMATS = ("jaxflex-fit/1", FIT_FORMAT)


# ------------------------------------------------------------------------------ model description


def describe_model(model: Model) -> dict[str, Any]:
    """The rig's full content, JSON-able: its arm-file form (:func:`jaxflex.arm.arm_to_dict`),
    from which :func:`build_model` gives the same model back."""
    from jaxflex.arm import arm_to_dict

    return arm_to_dict(model)


def build_model(description: Mapping[str, Any]) -> Model:
    """The :class:`Model` a :func:`describe_model` description stands for (also the testbed
    and effects that fit files of format ``jaxflex-fit/1`` recorded)."""
    from jaxflex.arm import arm_from_dict
    from jaxflex.effects import get_effect

    if "link" in description:
        return arm_from_dict(description, "the fit's rig")
    try:
        testbed = Testbed(**description["testbed"])
        effects = tuple(
            get_effect(e["name"], **e.get("settings", {})) for e in description["effects"]
        )
        return Model(
            testbed, effects, int(description["n_substeps"]), n_modes=description.get("n_modes")
        )
    except KeyError as exc:
        raise ValueError(f"model description lacks {exc.args[0]!r}") from None
    except TypeError as exc:
        raise ValueError(f"model description does not fit this jaxflex: {exc}") from None


# ------------------------------------------------------------------------------ result


@dataclass(frozen=True)
class History:
    """Per generation (0 = the initial population): best and mean cost, best parameters."""

    best: np.ndarray
    mean: np.ndarray
    best_params: dict[str, np.ndarray]

    def to_dict(self) -> dict[str, Any]:
        return {"best": self.best, "mean": self.mean, "best_params": self.best_params}

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> History:
        return cls(
            best=_array(data["best"]),
            mean=_array(data["mean"]),
            best_params={k: _array(v) for k, v in data["best_params"].items()},
        )


@dataclass(frozen=True)
class Fit:
    """An identified parameter set with how it was found and how well it is known.

    ``params`` holds every model parameter (identified and fixed) in physical units;
    ``names`` are the identified ones, and ``intervals``/``std``/``covariance``/``correlation``
    refer to them (in that order for the matrices). ``cost`` is the final objective (weighted
    mean squared NRMSE, a fraction; see :mod:`jaxflex.objective`), ``cost_search`` the best the
    evolutionary search found. ``model`` is the whole rig (drive, sensors, specs, effects),
    kept in the fit file as its description (:attr:`model_description`), so a loaded fit has
    its :class:`Model` exactly, whatever became of its arm file; ``search`` is the strategy
    that found it.

    The nominal ``intervals`` assume the model is right and the noise white;
    ``robust_intervals`` (HAC, from the residuals themselves) hold without that, and
    ``residual_checks`` says whether the residuals are white and whether the nominal intervals
    are therefore only conditional on the model (:attr:`model_conditional`; see
    :func:`jaxflex.intervals.uncertainty`). ``unidentifiable`` names parameters whose interval is
    infinite or spans decades: not identifiable from these records. ``initial_state`` and, by
    record, ``initial_states`` and their ``initial_state_intervals``: where the records started
    (:mod:`jaxflex.initial`; empty at rest). Fit files written before these fields existed load
    with them empty. A fit made otherwise than by a search (``jaxflex discover --out``) says so
    in ``settings``: ``made_by`` heads its summary, ``interval_basis`` says how its intervals
    were computed.
    """

    params: dict[str, float]
    names: tuple[str, ...]
    fixed: dict[str, float]
    model: Model = field(compare=False)
    cost: float
    cost_search: float
    intervals: dict[str, tuple[float, float]]
    std: dict[str, float]
    covariance: np.ndarray
    correlation: np.ndarray
    noise: dict[str, float]
    poorly_identifiable: tuple[str, ...]
    warnings: tuple[str, ...]
    history: History
    refinement: Refinement | None
    method: str
    seed: int
    settings: dict[str, Any]
    timing: dict[str, float]
    record_names: tuple[str, ...]
    level: float = 0.95
    identifiability: dict[str, Any] = field(default_factory=dict)
    provenance: dict[str, Any] = field(default_factory=dict)
    unidentifiable: tuple[str, ...] = ()
    robust_intervals: dict[str, tuple[float, float]] = field(default_factory=dict)
    robust_std: dict[str, float] = field(default_factory=dict)
    residual_checks: dict[str, Any] = field(default_factory=dict)
    initial_state: str = "rest"
    initial_states: dict[str, dict[str, float]] = field(default_factory=dict)
    initial_state_intervals: dict[str, dict[str, tuple[float, float]]] = field(default_factory=dict)

    # --- use -------------------------------------------------------------------------------
    @property
    def model_description(self) -> dict[str, Any]:
        """The rig as the fit file stores it (:func:`describe_model`)."""
        return describe_model(self.model)

    @property
    def effects(self) -> tuple[str, ...]:
        return self.model.effect_names

    @property
    def search(self) -> AbstractStrategy:
        """The evolutionary strategy, with its settings, that found this fit."""
        return STRATEGIES.create(self.method, **self.settings["strategy"])

    @property
    def n_params(self) -> int:
        """Number of identified parameters."""
        return len(self.names)

    @property
    def nrmse(self) -> float:
        """``100·√cost``: the root-mean-square of the normalised errors, in percent."""
        return 100.0 * math.sqrt(self.cost) if math.isfinite(self.cost) else math.inf

    @property
    def model_conditional(self) -> bool:
        """True when the residuals are not white and the robust intervals are materially wider:
        the nominal intervals then hold only if the model were right and the noise white."""
        return bool(self.residual_checks.get("conditional", False))

    def summary(self) -> str:
        """A text table: value, nominal interval and relative half-width of each parameter,
        and the robust half-width beside it; what the intervals assume, in words."""
        search = f"search {self.cost_search:.6g}, " if math.isfinite(self.cost_search) else ""
        lines = [
            f"{self.settings.get('made_by', self.method.upper())} seed {self.seed}: cost "
            f"{self.cost:.6g} ({search}rms NRMSE {self.nrmse:.4g} %)",
            *parameter_table(self.params, self.intervals, parameter_units(self.model),
                             level=self.level, robust=self.robust_intervals,
                             unidentifiable=self.unidentifiable,
                             poorly=self.poorly_identifiable),
        ]
        if self.intervals:
            lines.append(self.interval_note())
        if self.refinement is not None:
            r = self.refinement
            lines.append(
                f"refinement: {r.result}, {r.steps} steps, cost {r.cost_start:.6g} -> "
                f"{r.cost_end:.6g} ({'accepted' if r.accepted else 'rejected'})"
            )
        lines += _initial.state_lines(self.initial_states, self.initial_state_intervals)
        lines += [f"warning: {w}" for w in self.warnings]
        return "\n".join(lines) + "\n"

    def interval_note(self) -> str:
        """One sentence: what the intervals assume and whether the residuals allow it (or
        how they were computed, where the fit states it: ``settings["interval_basis"]``)."""
        if self.settings.get("interval_basis"):
            return f"intervals: {self.settings['interval_basis']}"
        if not self.residual_checks:
            return ("intervals: assume the model is right and the noise white (not checked: "
                    "this fit predates the residual checks)")
        if self.model_conditional:
            widen = [w for w in self.residual_checks.get("widening", {}).values()
                     if w is not None and math.isfinite(w)]
            span = f" ({widening_span(min(widen), max(widen))})" if widen else ""
            return ("intervals: CONDITIONAL on the model - they assume the model is right and "
                    "the noise white, and the residuals are not white; read the robust "
                    f"(HAC) ones{span}")
        return ("intervals: assume the model is right and the noise white; the robust (HAC) "
                "ones agree")

    # --- files -----------------------------------------------------------------------------
    def to_dict(self) -> dict[str, Any]:
        """Plain JSON-able contents (arrays as lists, non-finite numbers as null)."""
        data = {"format": FIT_FORMAT}
        for f in fields(self):
            value = getattr(self, f.name)
            if isinstance(value, (History, Refinement)):
                value = value.to_dict()
            if isinstance(value, Model):
                data["model_description"] = self.model_description
                continue
            data[f.name] = value
        if data["refinement"] is not None:  # times only under "timing": the rest reproduces
            data["refinement"] = {
                k: v for k, v in data["refinement"].items() if k not in _REFINEMENT_TIMES
            }
        return to_jsonable(data)

    def to_json(self, path: str | os.PathLike, overwrite: bool = False) -> Path:
        """Write the fit as JSON, atomically; an existing file needs ``overwrite=True``."""
        return write_json(path, self.to_dict(), overwrite=overwrite)

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> Fit:
        """A fit from :meth:`to_dict`'s contents, checked field by field (:func:`check_fit`)."""
        check_fit(data)
        refinement = data["refinement"]
        if refinement is not None:  # its times are kept under "timing"
            timing = data["timing"]
            refinement = dict(refinement)
            refinement.setdefault("wall_time", _float(timing.get("refine")))
            refinement.setdefault("compile_time", _float(timing.get("refine_compile")))
        return cls(
            params={k: _float(v) for k, v in data["params"].items()},
            names=tuple(data["names"]),
            fixed={k: _float(v) for k, v in data["fixed"].items()},
            model=build_model(data["model_description"]),
            cost=_float(data["cost"]),
            cost_search=_float(data["cost_search"]),
            intervals={k: (_float(v[0]), _float(v[1])) for k, v in data["intervals"].items()},
            std={k: _float(v) for k, v in data["std"].items()},
            covariance=_matrix(data["covariance"]),
            correlation=_matrix(data["correlation"]),
            noise={k: _float(v) for k, v in data["noise"].items()},
            poorly_identifiable=tuple(data["poorly_identifiable"]),
            warnings=tuple(data["warnings"]),
            history=History.from_dict(data["history"]),
            refinement=None if refinement is None else Refinement.from_dict(refinement),
            method=str(data["method"]),
            seed=int(data["seed"]),
            settings=dict(data["settings"]),
            timing={k: _float(v) for k, v in data["timing"].items()},
            record_names=tuple(data["record_names"]),
            level=float(data.get("level", 0.95)),
            identifiability=_identifiability(data.get("identifiability", {})),
            provenance=dict(data.get("provenance", {})),
            unidentifiable=tuple(data.get("unidentifiable", ())),
            robust_intervals={k: (_float(v[0]), _float(v[1]))
                              for k, v in data.get("robust_intervals", {}).items()},
            robust_std={k: _float(v) for k, v in data.get("robust_std", {}).items()},
            residual_checks=dict(data.get("residual_checks", {})),
            initial_state=str(data.get("initial_state", "rest")),
            initial_states={r: {k: _float(v) for k, v in z.items()}
                            for r, z in data.get("initial_states", {}).items()},
            initial_state_intervals={
                r: {k: (_float(v[0]), _float(v[1])) for k, v in z.items()}
                for r, z in data.get("initial_state_intervals", {}).items()},
        )

    @classmethod
    def from_json(cls, path: str | os.PathLike) -> Fit:
        """Read a fit written by :meth:`to_json`; errors name the file."""
        path = Path(path)
        try:
            data = json.loads(path.read_text(encoding="utf-8"))
        except (json.JSONDecodeError, UnicodeDecodeError) as exc:
            raise ValueError(f"{path}: not a JSON file ({exc})") from None
        except RecursionError:
            raise ValueError(f"{path}: JSON nested too deeply") from None
        if not isinstance(data, dict):
            raise ValueError(f"{path}: not a jaxflex fit (expected a JSON object)")
        try:
            return cls.from_dict(data)
        except (KeyError, TypeError, ValueError, OverflowError) as exc:
            message = exc.args[0] if exc.args else exc
            raise ValueError(f"{path}: {message}") from None


# ------------------------------------------------------------------------------ fit file schema

_REFINEMENT_TIMES = ("wall_time", "compile_time")


class _Invalid(ValueError):
    pass


def _is_number(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def _number_field(nullable: bool = True, finite: bool = False):
    def check(v: Any, at: str) -> None:
        if v is None and nullable:
            return
        if not _is_number(v) or (finite and not math.isfinite(v)):
            what = "a finite number" if finite else "a number" + (" or null" if nullable else "")
            raise _Invalid(f"field {at!r}: expected {what}, got {_show(v)}")
    return check


def _typed(kind: type | tuple[type, ...], label: str):
    def check(v: Any, at: str) -> None:
        if not isinstance(v, kind) or isinstance(v, bool) and kind is not bool:
            raise _Invalid(f"field {at!r}: expected {label}, got {_show(v)}")
    return check


def _list_of(item, length: int | None = None):
    def check(v: Any, at: str) -> None:
        if not isinstance(v, list):
            raise _Invalid(f"field {at!r}: expected a list, got {_show(v)}")
        if length is not None and len(v) != length:
            raise _Invalid(f"field {at!r}: expected {length} values, got {len(v)}")
        for i, x in enumerate(v):
            item(x, f"{at}[{i}]")
    return check


def _object_of(value, keys: Sequence[str] | None = None):
    def check(v: Any, at: str) -> None:
        if not isinstance(v, dict):
            raise _Invalid(f"field {at!r}: expected an object, got {_show(v)}")
        missing = [k for k in keys or () if k not in v]
        if missing:
            raise _Invalid(f"field {at!r}: lacks {missing}")
        for k, x in v.items():
            value(x, f"{at}.{k}")
    return check


def _record(schema: Mapping[str, Any], optional: Sequence[str] = ()):
    """An object with the given fields (``optional`` ones may be absent; others are free)."""
    def check(v: Any, at: str) -> None:
        if not isinstance(v, dict):
            raise _Invalid(f"field {at!r}: expected an object, got {_show(v)}")
        missing = [k for k in schema if k not in v and k not in optional]
        if missing:
            raise _Invalid(f"field {at!r}: lacks {missing}" if at else f"fit lacks field(s) "
                           f"{missing}")
        for k, sub in schema.items():
            if k in v:
                sub(v[k], f"{at}.{k}" if at else k)
    return check


def _matrix_field(v: Any, at: str) -> None:
    _list_of(_list_of(_number_field()))(v, at)
    if any(len(row) != len(v) for row in v):
        raise _Invalid(f"field {at!r}: expected a square matrix, got rows of lengths "
                       f"{sorted({len(row) for row in v})} for {len(v)} rows")


def _n_elements(v: Any, at: str) -> None:
    if not (isinstance(v, int) and not isinstance(v, bool) and 1 <= v <= MAX_ELEMENTS):
        raise _Invalid(f"field {at!r}: expected a whole number in [1, {MAX_ELEMENTS}], "
                       f"got {_show(v)}")


def _one_of(*allowed: Any):
    def check(v: Any, at: str) -> None:
        if v not in allowed:
            raise _Invalid(f"field {at!r}: expected one of {list(allowed)}, got {_show(v)}")
    return check


def _registered_strategy(v: Any, at: str) -> None:
    """A fit's method: the name of a registered strategy (a user's own once registered)."""
    if v not in STRATEGIES:
        raise _Invalid(f"field {at!r}: expected one of {sorted(STRATEGIES)}, got {_show(v)} "
                       "(register a strategy of one's own with jaxflex.evolve.STRATEGIES)")


def _nullable(check_value):
    def check(v: Any, at: str) -> None:
        if v is not None:
            check_value(v, at)
    return check


def _show(v: Any) -> str:
    text = json.dumps(v) if not isinstance(v, float) or math.isfinite(v) else repr(v)
    return text if len(text) <= 40 else text[:37] + "..."


_STRINGS = _list_of(_typed(str, "a string"))
_NUMBERS = _list_of(_number_field())
_PARAMS = _object_of(_number_field(nullable=False, finite=True))
def _rig(v: Any, at: str) -> None:
    """The fit's rig: a legacy description (testbed, effects) or an arm-file form."""
    if isinstance(v, dict) and "link" in v:
        from jaxflex.arm import arm_from_dict

        arm_from_dict(v, f"field {at!r}")
    else:
        _LEGACY_MODEL(v, at)


_LEGACY_MODEL = _record({
    "testbed": _record({"n_elements": _n_elements}, optional=("n_elements",)),
    "effects": _list_of(_record({"name": _typed(str, "a string"),
                                 "settings": _typed(dict, "an object")},
                                optional=("settings",))),
    "n_substeps": _typed(int, "a whole number"),
    "n_modes": _nullable(_typed(int, "a whole number")),
}, optional=("n_modes",))
FIT_SCHEMA = _record({
    "format": _one_of(*_FORMATS),
    "params": _PARAMS,
    "names": _STRINGS,
    "fixed": _PARAMS,
    "model_description": _rig,
    "cost": _number_field(),
    "cost_search": _number_field(),
    "intervals": _object_of(_list_of(_number_field(), length=2)),
    "std": _object_of(_number_field()),
    "covariance": _matrix_field,
    "correlation": _matrix_field,
    "noise": _object_of(_number_field()),
    "poorly_identifiable": _STRINGS,
    "warnings": _STRINGS,
    "history": _record({"best": _NUMBERS, "mean": _NUMBERS, "best_params": _object_of(_NUMBERS)}),
    "refinement": _nullable(_record({
        "start": _PARAMS, "end": _PARAMS, "cost_start": _number_field(),
        "cost_end": _number_field(), "accepted": _typed(bool, "true or false"),
        "result": _typed(str, "a string"), "message": _typed(str, "a string"),
        "steps": _typed(int, "a whole number"), "n_starts": _typed(int, "a whole number"),
        "wall_time": _number_field(), "compile_time": _number_field(),
    }, optional=_REFINEMENT_TIMES)),
    "method": _registered_strategy,
    "seed": _typed(int, "a whole number"),
    "settings": _typed(dict, "an object"),
    "timing": _object_of(_number_field()),
    "record_names": _STRINGS,
    "level": _number_field(nullable=False, finite=True),
    "identifiability": _record({"eigenvalues": _NUMBERS, "eigenvectors": _matrix_field},
                               optional=("eigenvalues", "eigenvectors")),
    "provenance": _typed(dict, "an object"),
    "unidentifiable": _STRINGS,
    "robust_intervals": _object_of(_list_of(_number_field(), length=2)),
    "robust_std": _object_of(_number_field()),
    "residual_checks": _typed(dict, "an object"),
    "initial_state": _one_of(*_initial.INITIAL_STATES),
    "initial_states": _object_of(_object_of(_number_field())),
    "initial_state_intervals": _object_of(_object_of(_list_of(_number_field(), length=2))),
}, optional=("level", "identifiability", "provenance", "unidentifiable", "robust_intervals",
             "robust_std", "residual_checks", "initial_state", "initial_states",
             "initial_state_intervals"))
"""The fit file, field by field: each entry checks one field and names it when it is wrong."""


def check_fit(data: Any) -> None:
    """Check the contents of a fit file against :data:`FIT_SCHEMA` and its own consistency
    (identified names among the parameters, matrices the size of the names); a ValueError
    names the first wrong field."""
    if not isinstance(data, dict):
        raise ValueError(f"not a jaxflex fit (expected a JSON object, got {_show(data)})")
    if data.get("format") not in _FORMATS:
        raise ValueError(f"not a jaxflex fit (format {data.get('format')!r}, "
                         f"expected {FIT_FORMAT!r})")
    FIT_SCHEMA(data, "")
    unknown = [n for n in data["names"] if n not in data["params"]]
    if unknown:
        raise ValueError(f"field 'names': {unknown} not among the 'params'")
    n = len(data["names"])
    for key in ("covariance", "correlation"):
        if len(data[key]) not in (0, n):
            raise ValueError(f"field {key!r}: expected {n} x {n} (one row per name), "
                             f"got {len(data[key])} rows")
    if not 0 < data.get("level", 0.95) < 1:
        raise ValueError(f"field 'level': expected a number in (0, 1), got {data['level']!r}")


def parameter_units(model: Model) -> dict[str, str]:
    """Each parameter's unit: the base model's and its effects' (:class:`ParameterSpec.unit`)."""
    from jaxflex.parameters import BASE_PARAMETERS

    units = {s.name: s.unit for s in BASE_PARAMETERS}
    units.update({s.name: s.unit for s in model.space.specs})
    return units


def parameter_table(params: Mapping[str, float], intervals: Mapping[str, tuple[float, float]],
                    units: Mapping[str, str], *, level: float = 0.95,
                    robust: Mapping[str, tuple[float, float]] | None = None,
                    unidentifiable: Sequence[str] = (), poorly: Sequence[str] = (),
                    started: Mapping[str, float] | None = None) -> list[str]:
    """The lines of a parameter table: value, ``level`` interval, relative half-width (and the
    robust one beside it) and unit of each of ``params``; a parameter without an interval is
    held (``(fixed)``), or, named in ``started``, was fitted from that start without one."""
    pct = f"{100 * level:g} %"
    robust = robust or {}
    lines = [f"{'parameter':<10} {'value':>12} {pct + ' interval':>29} {'±%':>8}"
             + (f" {'robust ±%':>10}" if robust else "") + "  unit"]
    for n, value in params.items():
        unit = units.get(n, "")
        if n in unidentifiable:
            lines.append(f"{n:<10} {value:>12.6g}  not identifiable from these records"
                         f"  {unit}")
        elif n in intervals:
            lo, hi = intervals[n]
            rel = _half_width_percent(value, lo, hi)
            flag = "  poorly identifiable" if n in poorly else ""
            extra = ""
            if robust and n in robust:
                extra = f" {_half_width_percent(value, *robust[n]):>10.3g}"
            lines.append(f"{n:<10} {value:>12.6g} [{lo:>12.6g}, {hi:>12.6g}] {rel:>8.3g}{extra}  "
                         f"{unit}{flag}")
        elif started and n in started:
            lines.append(f"{n:<10} {value:>12.6g} {f'(started at {started[n]:.3g})':>29} "
                         f"{'':>8}  {unit}")
        else:
            lines.append(f"{n:<10} {value:>12.6g} {'(fixed)':>29} {'':>8}  {unit}")
    return lines


def load_fit(path: str | os.PathLike) -> Fit:
    """Read a fit file written by :meth:`Fit.to_json` (or ``jaxflex identify --out``)."""
    return Fit.from_json(path)


def _half_width_percent(value: float, lo: float, hi: float) -> float:
    """Half the interval's width in percent of the value (NaN at a zero value)."""
    return 50.0 * (hi - lo) / abs(value) if value else math.nan


def _float(value: Any) -> float:
    return math.nan if value is None else float(value)


def _identifiability(data: Mapping[str, Any]) -> dict[str, Any]:
    out = dict(data)
    if "eigenvalues" in out:
        out["eigenvalues"] = _array(out["eigenvalues"])
    if "eigenvectors" in out:
        out["eigenvectors"] = _matrix(out["eigenvectors"])
    return out


def _array(value: Any) -> np.ndarray:
    """A 1-D float array from a JSON list (null → NaN)."""
    return np.array([_float(v) for v in value], dtype=np.float64)


def _matrix(value: Any) -> np.ndarray:
    """A 2-D float array from a JSON list of lists (null → NaN; [] → shape (0, 0))."""
    rows = [[_float(v) for v in row] for row in value]
    return np.array(rows, dtype=np.float64).reshape(len(rows), len(rows[0]) if rows else 0)


__all__ = [
    "FIT_FORMAT",
    "FIT_SCHEMA",
    "Fit",
    "History",
    "build_model",
    "check_fit",
    "describe_model",
    "load_fit",
    "parameter_table",
    "parameter_units",
]
