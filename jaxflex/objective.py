"""The identification objective: weighted least squares between simulated and measured outputs.

For records ``r = 1..R`` with ``n_r`` samples and output channels ``c`` (joint angle, tip
acceleration) with weights ``w_c`` (``W_r = Σ_c w_c`` over the channels record ``r`` logs), the
residual vector stacks

    e_rct = s_rc · (ŷ_rc(t; θ) − y_rc(t)),      s_rc = √(w_c / (W_r·R·n_r)) / rms(y_rc),

so the cost ``Σ e²`` is the weighted mean over records and channels of the squared normalised
RMS error (``NRMSE²``, as a fraction): every channel counts in proportion to its weight whatever
its unit, and every record counts the same whatever its length and whichever of the channels
it logs (a channel a record does not log adds zeros with ``s_rc = 0``: :meth:`Objective.
observed`). Weights can instead follow the
channels' measurement noise ``σ_c`` (:func:`noise_weights`): ``w_c = mean_r ms(y_rc)/σ_c²``, the
signal-to-noise power: on one record ``e`` is then ``(ŷ − y)/σ_c`` up to one common factor.
The residual vector (for least squares) and the scalar cost (for the evolutionary search)
share :meth:`Objective.residuals`.

Parameters can be evaluated from physical values or from the unit box ``u`` that the search and
the refinement work in (:mod:`jaxflex.parameters`). Only the free parameters are searched;
``fixed`` ones keep their given values.

Records of equal length are stacked and simulated by one ``vmap`` (:func:`per_record`; a
group of one record without it); groups of different length are simulated one after another
inside the same traced function.

Records start at rest, or, for records logged in motion, from an initial state that is a
function of the parameters (estimated from each record's own residuals, or its periodic steady
state: :mod:`jaxflex.initial`), so the cost stays a function of the parameters alone.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Mapping, Sequence
from typing import TypeVar

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float, Scalar, Shaped

from jaxflex import fused
from jaxflex._arguments import shown
from jaxflex.data import OUTPUT_COLUMNS, Dataset, Record
from jaxflex.evolve._base import sanitize_fitness
from jaxflex.initial import (
    DEFAULT_MODES,
    check_initial_modes,
    check_initial_state,
    check_record_length,
    estimate_state,
    input_period,
    periodic_state,
    simulate_from,
)
from jaxflex.model import Model
from jaxflex.noise import Noise, noise_levels
from jaxflex.parallel import population_vmap
from jaxflex.parameters import ParameterSpace, ParameterSpec, Params
from jaxflex.simulation import OUTPUT_NAMES, read_channels, simulate_core

Records = Dataset | Record | Iterable[Record]
"""What functions that take measurements accept: a data set, one record or records."""

_T = TypeVar("_T")


def per_record(fn: Callable[..., _T], *group: Shaped[Array, "R ..."]) -> _T:
    """``jax.vmap(fn)(*group)``: ``fn`` on each row of a group of records (arrays with a row per
    record). A group of one record runs ``fn`` on its row unbatched, the row axis put back:
    batching the time loop (every loop and custom derivative inside it batched anew) costs
    more tracing than the loop itself, about half a second per compiled program."""
    if all(a.shape[0] == 1 for a in group):
        return jax.tree.map(lambda y: y[None], fn(*(a[0] for a in group)))
    return jax.vmap(fn)(*group)


def as_dataset(records: Records) -> Dataset:
    """A :class:`Dataset` from a data set, one record or an iterable of records.

    Records with different sampling intervals are refused (by :class:`Dataset`).
    """
    _records_first(records)
    if isinstance(records, Dataset):
        dataset = records
    elif isinstance(records, Record):
        dataset = Dataset([records])
    else:
        dataset = Dataset(list(records))
    if len(dataset) == 0:
        raise ValueError("no records given: identification needs at least one record")
    return dataset


class Objective(eqx.Module):
    """Normalised residuals and cost of a model over a set of records (see the module doc).

    Build it with :func:`build_objective`. All methods are pure and traceable: use them inside
    ``jit``/``vmap``/``grad``. The instance is a pytree, so two objectives with equally shaped
    records share compiled code.
    """

    model: Model
    specs: tuple[ParameterSpec, ...] = eqx.field(static=True)  # free parameters, search bounds
    fixed: dict[str, Array]
    channels: tuple[str, ...] = eqx.field(static=True)
    weights: Float[Array, " C"]  # a runtime value: other weights reuse the compiled code
    record_names: tuple[str, ...] = eqx.field(static=True)
    groups: tuple[tuple[int, ...], ...] = eqx.field(static=True)  # record indices per length
    dt: float = eqx.field(static=True)
    torque: tuple[Float[Array, "R n"], ...]  # per group
    measured: tuple[Float[Array, "R C n"], ...]  # per group
    scale: tuple[Float[Array, "R C"], ...]  # per group, s_rc of the module doc
    # where each record starts (jaxflex.initial): its option, the modes it sets, and for
    # "periodic" the input's period in samples per group (records are grouped by it too)
    initial_state: str = eqx.field(static=True, default="rest")
    initial_modes: int = eqx.field(static=True, default=0)
    periods: tuple[int, ...] = eqx.field(static=True, default=())

    # --- coordinates -----------------------------------------------------------------------
    @property
    def space(self) -> ParameterSpace:
        """The free parameters with their search bounds."""
        return ParameterSpace(self.specs)

    @property
    def names(self) -> tuple[str, ...]:
        """Names of the free parameters, in search order."""
        return tuple(s.name for s in self.specs)

    @property
    def dim(self) -> int:
        return len(self.specs)

    @property
    def size(self) -> int:
        """Length of the residual vector."""
        return sum(int(np.prod(m.shape)) for m in self.measured)

    def full(self, free: Mapping[str, ArrayLike]) -> Params:
        """Free values plus the fixed ones: a parameter set for the model."""
        return {**self.fixed, **{k: jnp.asarray(v) for k, v in free.items()}}

    def from_unit(self, u: Float[ArrayLike, " d"]) -> Params:
        return self.space.from_unit(u)

    # --- residuals and cost ----------------------------------------------------------------
    def _read(self, full: Params, out) -> Float[Array, "C n"]:
        """The fitted channels of one record's outputs, after the effects' calibrations."""
        return read_channels(self.model, full, out, self.channels)

    def simulate(self, params: Mapping[str, ArrayLike]) -> tuple[Float[Array, "R C n"], ...]:
        """Simulated output channels per group of equally long records (free params only),
        each record from its initial state (:meth:`initial_states`)."""
        if self.initial_state != "rest":
            return self.simulate_from(params, self.initial_states(params))
        full = self.full(params)

        def one(torque):
            return self._read(full, simulate_core(self.model, full, torque, self.dt))

        return tuple(per_record(one, torque) for torque in self.torque)

    def simulate_from(self, params: Mapping[str, ArrayLike],
                      states: Sequence[Float[Array, "R c"]]) -> tuple[Float[Array, "R C n"], ...]:
        """Simulated output channels per group, each record from the given coordinates
        (:mod:`jaxflex.initial`; a row per record of the group)."""
        full = self.full(params)

        def one(torque, z):
            return self._read(full, simulate_from(self.model, full, torque, self.dt, z,
                                                  self.initial_modes))

        return tuple(per_record(one, torque, z)
                     for torque, z in zip(self.torque, states, strict=True))

    def initial_states(self, params: Mapping[str, ArrayLike]) -> tuple[Float[Array, "R c"], ...]:
        """Each record's initial coordinates at ``params`` (a row per record of each group):
        zero at rest, else estimated from its residuals or periodic (:mod:`jaxflex.initial`)."""
        modes = self.initial_modes
        if self.initial_state == "rest":
            return tuple(jnp.zeros((t.shape[0], 2 + 2 * modes)) for t in self.torque)
        full = self.full(params)
        periods = self.periods or (0,) * len(self.torque)

        def one(torque, y, s, period):
            def residual(z, full):
                y_sim = self._read(full, simulate_from(self.model, full, torque, self.dt, z,
                                                       modes))
                return (s[:, None] * (y_sim - y)).reshape(-1)

            if self.initial_state == "estimate":
                time = self.dt * jnp.arange(torque.shape[0])
                return estimate_state(residual, full, modes, time)
            return periodic_state(self.model, full, torque, self.dt, modes, period, residual)

        return tuple(
            per_record(lambda t, y, s, period=period: one(t, y, s, period), torque, y, s)
            for torque, y, s, period in zip(self.torque, self.measured, self.scale, periods,
                                            strict=True)
        )

    def residuals(self, params: Mapping[str, ArrayLike]) -> Float[Array, " N"]:
        """The normalised, weighted residual vector ``e`` (free parameters in physical units)."""
        return self._stacked(self.simulate(params))

    def residuals_from(self, params: Mapping[str, ArrayLike],
                       states: Sequence[Float[Array, "R c"]]) -> Float[Array, " N"]:
        """The residual vector with each record started from the given coordinates."""
        return self._stacked(self.simulate_from(params, states))

    def _stacked(self, simulated: tuple[Array, ...]) -> Float[Array, " N"]:
        parts = [
            (s[..., None] * (y_sim - y)).reshape(-1)
            for y_sim, y, s in zip(simulated, self.measured, self.scale, strict=True)
        ]
        return jnp.concatenate(parts)

    def cost(self, params: Mapping[str, ArrayLike]) -> Scalar:
        """``Σ e²``: the weighted mean squared NRMSE (a fraction, not percent)."""
        r = self.residuals(params)
        return jnp.sum(r**2)

    def unit_residuals(self, u: Float[Array, " d"]) -> Float[Array, " N"]:
        return self.residuals(self.from_unit(u))

    def unit_cost(self, u: Float[Array, " d"]) -> Scalar:
        return self.cost(self.from_unit(u))

    def fitness(self, population: Float[Array, "P d"]) -> Float[Array, " P"]:
        """Cost of every unit-box candidate in one call: vmapped and split across the host's
        cores (:mod:`jaxflex.parallel`), or on a GPU one kernel per group of equally long records
        for the whole population, where the model allows it and the records start at rest
        (:mod:`jaxflex.fused`); non-finite → ``+inf``."""
        if self.initial_state == "rest" and fused.preferred(self.model):
            return sanitize_fitness(self._fused_costs(population))
        return sanitize_fitness(population_vmap(self.unit_cost, population))

    def _fused_costs(self, population: Float[Array, "P d"]) -> Float[Array, " P"]:
        full = jax.vmap(lambda u: self.full(self.from_unit(u)))(population)
        count = population.shape[0]

        def group(torque):  # (P, R, C, n): the group's records side by side in one kernel
            records = torque.shape[0]
            every = jax.tree.map(lambda v: jnp.tile(v, records), full)  # record-major lanes
            outputs = fused.simulate_fused(self.model, every, jnp.repeat(torque, count, 0),
                                           self.dt)
            read = jax.vmap(self._read)(every, outputs)
            return jnp.swapaxes(read.reshape(records, count, *read.shape[1:]), 0, 1)

        simulated = [group(torque) for torque in self.torque]
        return jax.vmap(lambda *groups: jnp.sum(self._stacked(groups) ** 2))(*simulated)

    # --- layout (NumPy, for noise estimates and reports) ------------------------------------
    def layout(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Per residual element: record index, channel index and its scale ``s_rc`` (0 where
        the record does not log the channel: :meth:`observed`)."""
        records, channels, scales = [], [], []
        for group, measured, scale in zip(self.groups, self.measured, self.scale, strict=True):
            r, c, n = measured.shape
            idx_r = np.broadcast_to(np.asarray(group)[:, None, None], (r, c, n))
            idx_c = np.broadcast_to(np.arange(c)[None, :, None], (r, c, n))
            records.append(idx_r.reshape(-1))
            channels.append(idx_c.reshape(-1))
            scales.append(np.broadcast_to(np.asarray(scale)[..., None], (r, c, n)).reshape(-1))
        return np.concatenate(records), np.concatenate(channels), np.concatenate(scales)

    def observed(self) -> np.ndarray:
        """Per residual element, whether it is measured: a record that does not log a fitted
        channel holds zeros for it, with scale 0, so those elements are always 0 and carry no
        information (noise levels and degrees of freedom count only the observed ones)."""
        return self.layout()[2] > 0


def check_channels(
    channels: str | Sequence[str], model: Model | None = None
) -> tuple[str, ...]:
    """``channels`` as a tuple of distinct simulator outputs or ``model``'s sensor channels
    (one-line error naming the bad one)."""
    channels = (channels,) if isinstance(channels, str) else tuple(channels)
    if not channels or len(set(channels)) != len(channels):
        raise ValueError(f"channels must name distinct outputs, got {channels}")
    own = () if model is None else model.channels
    for c in channels:
        if c not in OUTPUT_NAMES and c not in own:
            sensors = f"; sensor channels: {own}" if own else ""
            raise ValueError(
                f"channel {c!r} is not a simulated output; outputs: {OUTPUT_NAMES}{sensors}"
            )
    return channels


def fitted_channels(records: Records, model: Model) -> tuple[str, ...]:
    """The channels fitted unless told: each sensor channel of the rig that some record holds
    (a record may hold any subset; what it lacks is not fitted there), or, for a rig without
    sensors, those of :data:`~jaxflex.records.OUTPUT_COLUMNS` that some record holds."""
    dataset = record_tuple(records)
    candidates = model.channels or OUTPUT_COLUMNS
    found = tuple(c for c in candidates if any(c in r.columns for r in dataset))
    if not found and not model.channels:  # records of other outputs only (a deflection)
        candidates = tuple(c for c in OUTPUT_NAMES if c != "joint_torque")
        found = tuple(c for c in candidates if any(c in r.columns for r in dataset))
    if not found:
        what = "sensor channels" if model.channels else "fitted outputs"
        raise ValueError(
            f"the records hold none of rig {model.name!r}'s {what} {list(candidates)}; "
            f"record {dataset[0].name!r} has columns {list(dataset[0].columns)}"
        )
    return found


def check_records(records: Records, function: str) -> None:
    """A TypeError naming ``function`` and its ``records`` argument unless it is a Record, a
    Dataset or an iterable of records."""
    if isinstance(records, (Record, Dataset)):
        return
    _records_first(records, function)
    if isinstance(records, (str, bytes, Mapping)) or not isinstance(records, Iterable):
        raise TypeError(f"{function}: records must be a Record, a Dataset or records, got "
                        f"{shown(records)}")
    for i, record in enumerate(records if isinstance(records, Sequence) else ()):
        if not isinstance(record, Record):
            raise TypeError(f"{function}: records[{i}] must be a Record, got {shown(record)}")


def _records_first(records: object, function: str = "") -> None:
    """A TypeError if a model stands where the records go: every function that takes
    measurements takes them first, then the model (``compare(records, model, params)``)."""
    if isinstance(records, Model):
        where = f"{function}: " if function else ""
        raise TypeError(f"{where}the records come first, then the model: "
                        f"{function or 'f'}(records, model, ...); got a Model as the records")


def record_tuple(records: Records) -> tuple[Record, ...]:
    """One record or several as a tuple (any sampling intervals; at least one record)."""
    _records_first(records)
    records = (records,) if isinstance(records, Record) else tuple(records)
    if not records:
        raise ValueError("no records given: at least one record is needed")
    return records


def held_fixed(
    model: Model,
    fixed: Mapping[str, ArrayLike] | None,
    bounds: Mapping[str, tuple[float, float]] | None,
) -> dict[str, ArrayLike]:
    """The parameters held fixed: the rig's own (at their reference values) unless ``bounds``
    frees one, then ``fixed`` (which overrides them)."""
    own = {k: v for k, v in model.fixed_values.items() if k not in (bounds or {})}
    return own | dict(fixed or {})


def check_inputs(records: Records, model: Model) -> None:
    """Every record logs the input the rig's drive reads (one line naming the record)."""
    for r in record_tuple(records):
        if r.input_name != model.drive.name:
            raise ValueError(
                f"record {r.name!r} logs {r.input_name!r} but rig {model.name!r} has a "
                f"{model.drive.name} drive, which reads a {model.drive.name!r} column"
            )


def check_weights(weights: Mapping[str, float] | None, channels: Sequence[str]) -> tuple:
    """The weight of each of ``channels`` (default 1), validated: one line naming the channel."""
    weights = {} if weights is None else dict(weights)
    unknown = sorted(set(weights) - set(channels))
    if unknown:
        raise ValueError(f"weights given for channel(s) {unknown} not fitted; channels: {channels}")
    values = []
    for c in channels:
        w = weights.get(c, 1.0)
        try:
            w = float(w)
        except (TypeError, ValueError):
            raise ValueError(f"weight of channel {c!r} must be a number, got {w!r}") from None
        if not (math.isfinite(w) and w >= 0):
            raise ValueError(f"weight of channel {c!r} must be finite and >= 0, got {w!r}")
        values.append(w)
    if not any(w > 0 for w in values):
        given = dict(zip(channels, values, strict=True))
        raise ValueError(f"at least one channel weight must be positive, got {given}")
    return tuple(values)


def noise_weights(records: Records, noise: Noise,
                  channels: Sequence[str] = OUTPUT_COLUMNS) -> dict[str, float]:
    """Channel weights from noise levels (a white σ or a :class:`NoiseLevel` per channel):
    ``w_c = mean_r ms(y_rc) / σ_c²`` over the records that hold the channel, which makes the
    objective's residual ``(ŷ − y)/σ_c`` up to one common factor (module docstring). Every
    channel in ``channels`` needs a level."""
    levels = noise_levels(noise, channels)
    missing = [c for c in channels if c not in levels]
    if missing:
        raise ValueError(f"noise level missing for channel(s) {missing}: give one for every "
                         f"fitted channel {list(channels)}")
    dataset = as_dataset(records)
    return {c: float(np.mean([np.mean(r.channel(c) ** 2) for r in dataset if c in r.columns]))
            / levels[c].sigma**2 for c in channels}


def free_specs(
    space: ParameterSpace,
    bounds: Mapping[str, tuple[float, float]] | None,
    fixed: Mapping[str, ArrayLike] | None,
) -> tuple[tuple[ParameterSpec, ...], dict[str, Array]]:
    """The free parameters of ``space`` (``bounds`` applied) and the ``fixed`` values, both
    validated with one-line errors naming the parameter (identify's and discover's check)."""
    fixed = dict(fixed or {})
    bounds = dict(bounds or {})
    for label, given in (("fixed", fixed), ("bounds", bounds)):
        unknown = sorted(set(given) - set(space.names))
        if unknown:
            raise ValueError(
                f"{label} names unknown parameter(s) {unknown}; known parameters: "
                f"{list(space.names)}"
            )
    both = sorted(set(fixed) & set(bounds))
    if both:
        raise ValueError(f"parameter(s) {both} are fixed and also given bounds; choose one")
    for name, pair in bounds.items():
        try:
            lower, upper = (float(v) for v in pair)
        except (TypeError, ValueError):
            raise ValueError(
                f"bounds for {name} must be a pair (lower, upper), got {pair!r}"
            ) from None
        if not lower < upper:  # ParameterSpec checks too; this names the argument
            raise ValueError(
                f"bounds for {name}: lower bound {lower!r} must be below upper bound {upper!r}"
            )
    space = space.with_bounds({k: tuple(map(float, v)) for k, v in bounds.items()})
    values = {}
    for name, value in fixed.items():
        value = np.asarray(value, dtype=np.float64)
        if value.shape != () or not np.isfinite(value):
            raise ValueError(f"fixed value of {name} must be one finite number, got {value!r}")
        _check_held(space[name], float(value))
        values[name] = jnp.asarray(value)
    free = tuple(s for s in space.specs if s.name not in fixed)
    if not free:
        raise ValueError("every parameter is fixed: nothing left to identify")
    return free, values


def _check_held(spec: ParameterSpec, value: float) -> None:
    """A parameter is held within the rig's bounds for it, at its reference value (the rig's
    own fixed value) or at its null (the effect off)."""
    if spec.lower <= value <= spec.upper or value in (spec.reference, spec.null):
        return
    raise ValueError(
        f"fixed value {spec.name}={value!r} lies outside the rig's bounds [{spec.lower!r}, "
        f"{spec.upper!r}] {spec.unit} for {spec.name}; hold it within them, or widen them "
        "in the arm file"
    )


def logged_weight(record: Record, channels: Sequence[str], weights: Sequence[float]) -> float:
    """``W_r``, the weight of the fitted ``channels`` that ``record`` logs (module doc); a record
    that logs none of them (or only channels of weight 0) is refused, naming it."""
    total = sum(w for c, w in zip(channels, weights, strict=True) if c in record.columns)
    if not total > 0:
        raise ValueError(
            f"record {record.name!r} logs none of the fitted channels {list(channels)}; its "
            f"columns are {list(record.columns)}"
        )
    return total


def build_objective(
    records: Records,
    model: Model | None = None,
    *,
    weights: Mapping[str, float] | None = None,
    channels: Sequence[str] | None = None,
    fixed: Mapping[str, ArrayLike] | None = None,
    bounds: Mapping[str, tuple[float, float]] | None = None,
    noise: Noise | None = None,
    initial_state: str = "rest",
    initial_modes: int = DEFAULT_MODES,
) -> Objective:
    """The objective of ``model`` (default: the reference testbed) over ``records``.

    ``weights`` maps channel → weight (default 1 each), or ``noise`` maps channel → noise level
    and the weights follow from it (:func:`noise_weights`); ``fixed`` maps parameter → value held
    fixed (besides the rig's own fixed parameters, unless ``bounds`` frees one); ``bounds`` maps
    parameter → ``(lower, upper)`` replacing its search bounds. ``channels`` defaults to
    :func:`fitted_channels`; a record that lacks a fitted channel adds no residual for it, and
    its other channels share its weight (module doc).
    Channels of weight 0 are left out of the objective altogether. ``initial_state`` says where
    each record starts: ``"rest"``, ``"estimate"`` (its state estimated with the parameters) or
    ``"periodic"`` (the cyclic steady state of its periodic input), the latter two setting the
    ``initial_modes`` lowest modes (:mod:`jaxflex.initial`). Every argument is validated
    and errors name the record, channel or parameter at fault.
    """
    check_records(records, "build_objective")
    model = Model() if model is None else model
    if not isinstance(model, Model):
        raise TypeError(f"model must be a jaxflex Model, got {type(model).__name__}")
    dataset = as_dataset(records)
    check_inputs(dataset, model)
    channels = fitted_channels(dataset, model) if channels is None else check_channels(
        channels, model)
    for c in channels:
        if not any(c in r.columns for r in dataset):
            dataset[0].channel(c)  # a KeyError naming the record, the channel and its columns
    fixed = held_fixed(model, fixed, bounds)
    if noise is not None:
        if weights is not None:
            raise ValueError("give channel weights or noise levels, not both")
        weights = noise_weights(dataset, noise, channels)
    weight_values = check_weights(weights, channels)
    # a channel of weight 0 adds nothing: leave it out of the simulation and the residuals
    channels, weight_values = zip(
        *((c, w) for c, w in zip(channels, weight_values, strict=True) if w > 0), strict=True
    )
    specs, fixed_values = free_specs(model.space, bounds, fixed)
    model.space.validate({**model.space.reference(), **fixed_values})
    initial_state = check_initial_state(initial_state)
    modes = 0 if initial_state == "rest" else check_initial_modes(initial_modes, model)
    if initial_state != "rest":
        for record in dataset:
            check_record_length(record, model, modes, initial_state)
    periods = [input_period(r) if initial_state == "periodic" else 0 for r in dataset]

    n_records = len(dataset)
    lengths: dict[tuple[int, int], list[int]] = {}  # records of one length (and period)
    for i, record in enumerate(dataset):
        lengths.setdefault((record.n_samples, periods[i]), []).append(i)
    torque, measured, scale = [], [], []
    for (n, _), members in lengths.items():
        ys, ss = [], []
        for i in members:
            record = dataset[i]
            total = logged_weight(record, channels, weight_values)
            row, srow = [], []
            for c, w in zip(channels, weight_values, strict=True):
                if c not in record.columns:  # not logged here: no residual
                    row.append(np.zeros(n))
                    srow.append(0.0)
                    continue
                y = record.channel(c)
                rms = float(np.sqrt(np.mean(y**2)))
                if not rms > 0:
                    raise ValueError(
                        f"record {record.name!r}: channel {c!r} is identically zero; it cannot "
                        "be normalised by its RMS (drop the channel or the record)"
                    )
                row.append(y)
                srow.append(math.sqrt(w / (total * n_records * n)) / rms)
            ys.append(row)
            ss.append(srow)
        torque.append(jnp.asarray(np.stack([dataset[i].input for i in members])))
        measured.append(jnp.asarray(np.asarray(ys)))
        scale.append(jnp.asarray(np.asarray(ss)))
    return Objective(
        model=model,
        specs=specs,
        fixed=fixed_values,
        channels=channels,
        weights=jnp.asarray(weight_values),
        record_names=dataset.names,
        groups=tuple(tuple(m) for m in lengths.values()),
        dt=dataset.dt,
        torque=tuple(torque),
        measured=tuple(measured),
        scale=tuple(scale),
        initial_state=initial_state,
        initial_modes=modes,
        periods=tuple(p for _, p in lengths) if initial_state == "periodic" else (),
    )


__all__ = ["Objective", "as_dataset", "build_objective", "check_channels",
           "check_inputs", "check_records", "check_weights", "fitted_channels", "free_specs",
           "held_fixed", "logged_weight", "noise_weights", "per_record", "record_tuple"]
