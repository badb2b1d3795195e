"""Compare the model with measured records: the paper's validation metrics, FRFs and a table.

Each record's measured torque drives the model (from rest, zero-order hold, see
:func:`jaxflex.simulation.simulate`) and the simulated outputs are set against the measured ones:

* **time domain** — per output, the NRMSE ``100·rms(y − ŷ)/rms(y)`` (%) and the held-out
  relative error ``‖y − ŷ‖/‖y‖`` (a fraction, as the dVRK identification package reports it),
  both over ``0 ≤ t ≤ t_end`` (the spec's 2 s);
* **frequency domain** — the H1 estimate of the FRF torque → tip acceleration from the measured
  and from the simulated tip acceleration (the same estimator on the same torque, so both carry
  the same record truncation and friction nonlinearity), and the NRMSE of ``|H|`` over
  ``0 < f ≤ f_max`` (15 Hz).

The 0.3 s reference inputs have spectral nulls inside the band (a pulse at multiples of 3.33 Hz,
a half sine at 5, 8.33, 11.7 and 15 Hz, a triangle at 6.67 and 13.3 Hz). There H1 divides the
sensor noise by almost no input, and those few bins dominate the magnitude NRMSE. The reported
``frf_nrmse`` therefore uses only the *compared* bins: for a single-segment (transient) estimate,
bins whose input power is within ``min_input_db`` (−30 dB) of the band maximum; for a Welch
estimate with several segments, bins whose coherence is at least ``min_coherence``. The raw
definition over every bin of the band is kept as ``frf_nrmse_raw``.
"""

from __future__ import annotations

import dataclasses
import math
import warnings
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np
from jaxtyping import ArrayLike, Bool, Complex, Float

from jaxflex._io import provenance, to_jsonable
from jaxflex.comparison_table import format_table
from jaxflex.data import KNOWN_UNITS, OUTPUT_COLUMNS, Dataset, Record
from jaxflex.diagnosis.frf import LINK_OUTPUTS
from jaxflex.initial import (
    DEFAULT_MODES,
    check_initial_state,
    coordinate_names,
    simulate_started,
    started_states,
)
from jaxflex.metrics import frf_nrmse, h1_frf, nrmse, relative_error, spectral_window
from jaxflex.modal import free_hub_modes
from jaxflex.model import Model
from jaxflex.objective import (
    check_channels,
    check_inputs,
    check_records,
    fitted_channels,
    record_tuple,
)
from jaxflex.simulation import Outputs

ROLES = ("fit", "held-out")
"""A record was used to fit the parameters, or held out to validate them."""
DEFAULT_T_END = 2.0
"""Time-domain metrics cover ``0 ≤ t ≤ 2 s`` of each record (the spec's window)."""

if TYPE_CHECKING:
    from jaxflex.identification import Fit



@dataclass(frozen=True)
class FRFSettings:
    """How FRFs are estimated and which bins the FRF NRMSE compares.

    ``nperseg``/``window`` go to :func:`jaxflex.metrics.h1_frf` (``None``: the whole record as
    one boxcar segment, right for the transient reference tests). With one segment, bins whose
    input power lies more than ``-min_input_db`` dB below the band maximum are left out; with
    several segments, bins whose coherence is below ``min_coherence``. ``None`` switches a
    criterion off; both off gives the raw definition.
    """

    f_max: float = 15.0
    nperseg: int | None = None
    window: str | None = None
    min_input_db: float | None = -30.0
    min_coherence: float | None = 0.5

    def __post_init__(self) -> None:
        if not (math.isfinite(self.f_max) and self.f_max > 0):
            raise ValueError(f"f_max={self.f_max!r} must be a positive frequency (Hz)")
        if self.min_input_db is not None and not (
            math.isfinite(self.min_input_db) and self.min_input_db <= 0
        ):
            raise ValueError(f"min_input_db={self.min_input_db!r} must be <= 0 dB (or None)")
        if self.min_coherence is not None and not 0 <= self.min_coherence <= 1:
            raise ValueError(f"min_coherence={self.min_coherence!r} must lie in [0, 1] (or None)")

    @property
    def single_segment(self) -> bool:
        return self.nperseg is None

    def describe(self) -> str:
        """One sentence saying which bins are compared."""
        band = f"0 < f <= {self.f_max:g} Hz"
        if self.single_segment and self.min_input_db is not None:
            rule = f"bins with input power within {-self.min_input_db:g} dB of the band maximum"
        elif not self.single_segment and self.min_coherence is not None:
            rule = f"bins with coherence >= {self.min_coherence:g}"
        else:
            rule = "every bin"
        return f"|H| NRMSE over {band}, {rule}"


@dataclass(frozen=True, eq=False)
class FRF:
    """H1 estimates torque → tip acceleration of one record, measured and simulated.

    Arrays cover the whole one-sided frequency grid; ``compared`` marks the bins the FRF NRMSE
    uses (inside ``0 < f ≤ f_max``, finite, and passing the input-power / coherence test).
    """

    freqs: Float[np.ndarray, " k"]  # Hz
    measured: Complex[np.ndarray, " k"]  # (m/s²)/(N m)
    model: Complex[np.ndarray, " k"]
    coherence: Float[np.ndarray, " k"]
    compared: Bool[np.ndarray, " k"]
    f_max: float

    @property
    def band(self) -> Bool[np.ndarray, " k"]:
        """Bins with ``0 < f ≤ f_max``."""
        return (self.freqs > 0) & (self.freqs <= self.f_max)


@dataclass(frozen=True, eq=False)
class RecordComparison:
    """Validation metrics of the model on one record (one row of the table)."""

    name: str
    role: str  # "fit" or "held-out"
    # per output the record logs (one it does not log has no entry): percent, NaN if the
    # measured output is zero throughout (no motion: see rms_error)
    nrmse: dict[str, float]
    relative_error: dict[str, float]  # per output, fraction (likewise)
    frf_nrmse: float  # percent, compared bins only (NaN if none)
    frf_nrmse_raw: float  # percent, every bin of the band (NaN if one is not finite)
    frf_bins: tuple[int, int]  # (compared, in band)
    noise_floor: dict[str, float]  # percent NRMSE that the sensor noise alone gives; {} if unknown
    measured_peaks_hz: tuple[float, ...]  # prominent maxima of |H_measured| (compared bins)
    model_peaks_hz: tuple[float, ...]  # the same for |H_model|
    frf: FRF = field(repr=False)
    rms_error: dict[str, float] = field(default_factory=dict)  # per output, in its own unit
    still: tuple[str, ...] = ()  # outputs measured zero throughout (no motion): NRMSE NaN

    def to_dict(self) -> dict[str, Any]:
        """Plain JSON-ready values (FRF arrays left out)."""
        return {
            "name": self.name,
            "role": self.role,
            "nrmse_percent": dict(self.nrmse),
            "relative_error": dict(self.relative_error),
            "frf_nrmse_percent": self.frf_nrmse,
            "frf_nrmse_raw_percent": self.frf_nrmse_raw,
            "frf_bins_compared": self.frf_bins[0],
            "frf_bins_in_band": self.frf_bins[1],
            "noise_floor_percent": dict(self.noise_floor),
            "measured_frf_peaks_hz": list(self.measured_peaks_hz),
            "model_frf_peaks_hz": list(self.model_peaks_hz),
            "rms_error": dict(self.rms_error),
            "no_motion": list(self.still),
        }


@dataclass(frozen=True, eq=False)
class Comparison:
    """The model against a set of records: one :class:`RecordComparison` per record, the
    simulated outputs, and the model's resonances. Index it by record name or position."""

    rows: tuple[RecordComparison, ...]
    records: tuple[Record, ...]
    simulated: tuple[Outputs, ...]
    params: dict[str, float]
    effects: tuple[str, ...]
    resonances_hz: tuple[float, ...]  # free-hub natural frequencies of the model, up to Nyquist
    t_end: float | None
    frf_settings: FRFSettings
    noise: dict[str, float] = field(default_factory=dict)  # encoder_counts, accel_sigma if known
    channels: tuple[str, ...] = OUTPUT_COLUMNS  # the channels compared, in their units below
    units: dict[str, str] = field(default_factory=dict)
    link: str = "tip_acceleration"  # the FRF's output
    input_name: str = "torque"
    # where each record not at rest started (its coordinates by name: jaxflex.initial), and,
    # for a held-out record whose state was estimated, the lead-in (s) it was estimated from
    initial_states: dict[str, dict[str, float]] = field(default_factory=dict)
    lead_ins: dict[str, float] = field(default_factory=dict)

    def __len__(self) -> int:
        return len(self.rows)

    def __getitem__(self, key: int | str) -> RecordComparison:
        return self.rows[self._index(key)]

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(r.name for r in self.rows)

    def record(self, key: int | str) -> Record:
        """The measured record of one row."""
        return self.records[self._index(key)]

    def outputs(self, key: int | str) -> Outputs:
        """Simulated outputs of one record."""
        return self.simulated[self._index(key)]

    def prediction(self, key: int | str) -> Record:
        """The model's prediction of one record, as a record (measured torque, simulated
        outputs; the other simulated signals as extra columns)."""
        i = self._index(key)
        out, record = self.simulated[i], self.records[i]
        columns = {"time": record.time, record.input_name: record.input}
        columns |= {n: np.asarray(out.channel(n)) for n in (*OUTPUT_COLUMNS, *_EXTRA_OUTPUTS)}
        columns |= {c: np.asarray(out.channel(c)) for c in self.channels}
        return record.with_columns(columns, note="simulated").replace(
            name=f"{self.rows[i].name}_model",
            metadata={"model": "jaxflex", "effects": ", ".join(self.effects) or "none"},
            source=None,
        )

    def mean(self, metric: str = "nrmse", role: str | None = "held-out") -> dict[str, float]:
        """Mean of a per-output metric ('nrmse' or 'relative_error') over the records of a role
        (``None``: all records) that log the output; NaN where none does."""
        if metric not in ("nrmse", "relative_error"):
            raise ValueError(f"metric={metric!r} must be 'nrmse' or 'relative_error'")
        rows = [r for r in self.rows if role is None or r.role == role]
        values = {o: [getattr(r, metric)[o] for r in rows if o in r.nrmse] for o in self.channels}
        return {o: float(np.mean(v)) if v else math.nan for o, v in values.items()}

    @property
    def model_resonances_hz(self) -> tuple[float, ...]:
        """The resonances of the model as fitted: the peaks of its simulated FRFs, where its hub
        inertia, friction and the hub's real boundary act as in the records (a hub held by
        friction rings lower than the free-hub modes of :attr:`resonances_hz`)."""
        return merged_peaks(p for r in self.rows for p in r.model_peaks_hz)

    def table(self) -> str:
        """The Table-3-style text table: one row per record, then notes on the definitions."""
        return format_table(self)

    def __str__(self) -> str:
        return self.table()

    def to_dict(self) -> dict[str, Any]:
        """Everything but the arrays, as plain JSON values (NaN as None, with provenance)."""
        return to_jsonable(
            {
                "params": dict(self.params),
                "effects": list(self.effects),
                "model_resonances_hz": list(self.resonances_hz),
                "channels": {c: self.units.get(c, "") for c in self.channels},
                "settings": {
                    "t_end_s": self.t_end,
                    "frf": {
                        "f_max_hz": self.frf_settings.f_max,
                        "nperseg": self.frf_settings.nperseg,
                        "window": self.frf_settings.window,
                        "min_input_db": self.frf_settings.min_input_db,
                        "min_coherence": self.frf_settings.min_coherence,
                        "compared_bins": self.frf_settings.describe(),
                    },
                    "noise": dict(self.noise),
                },
                "records": [r.to_dict() for r in self.rows],
                "initial_states": dict(self.initial_states),
                "lead_in_s": dict(self.lead_ins),
                "mean_held_out": {
                    "nrmse_percent": self.mean("nrmse"),
                    "relative_error": self.mean("relative_error"),
                },
                "provenance": provenance(),
            }
        )

    def _index(self, key: int | str) -> int:
        if isinstance(key, str):
            if key not in self.names:
                raise KeyError(
                    f"no record named {key!r} in the comparison; records: {list(self.names)}"
                )
            return self.names.index(key)
        if not -len(self.rows) <= key < len(self.rows):
            raise IndexError(f"record index {key} out of range for {len(self.rows)} record(s)")
        return key % len(self.rows)


_EXTRA_OUTPUTS = ("joint_velocity", "tip_deflection", "root_strain", "joint_torque")


# --- the comparison -----------------------------------------------------------------------------


def compare(
    records: Record | Iterable[Record],
    model: Model,
    params: Mapping[str, ArrayLike],
    *,
    fit_names: Iterable[str] = (),
    t_end: float | None = DEFAULT_T_END,
    frf: FRFSettings | None = None,
    encoder_counts: int | None = None,
    accel_sigma: float | None = None,
    channels: Sequence[str] | None = None,
    initial_states: Mapping[str, Sequence[float]] | None = None,
    initial_state: str = "rest",
    initial_modes: int = DEFAULT_MODES,
) -> Comparison:
    """Simulate ``model`` at ``params`` under each record's input and compute every metric.

    ``channels`` are the outputs or sensor channels compared (default: those the model fits,
    :func:`jaxflex.objective.fitted_channels`), each in its own unit; the FRF runs from the
    input to the first channel on the link.

    Records named in ``fit_names`` get the role 'fit', the others 'held-out'. ``t_end`` bounds
    the time-domain window (``None``: the whole record). ``frf`` sets the FRF estimate and the
    bins its NRMSE compares (default: leave out bins with input power more than 30 dB below
    the band maximum, see :class:`FRFSettings`; ``frf_nrmse_raw`` keeps every bin). Give the
    sensor noise (``encoder_counts`` per revolution, accelerometer ``accel_sigma`` in m/s²) when
    it is known, e.g. for synthetic records, to report the noise floor next to each metric; a
    rig's sensors state their own (their resolution and noise).

    A record named in ``initial_states`` (a fit's :attr:`~jaxflex.identification.Fit.
    initial_states`) starts from its coordinates (:mod:`jaxflex.initial`); the others start at
    rest, or, with ``initial_state`` ``"estimate"`` or ``"periodic"``, from their own state
    at ``params`` (``initial_modes`` modes).
    """
    check_records(records, "compare")
    dataset = record_tuple(records)  # one sampling rate or several
    names = [r.name for r in dataset]
    twice = sorted({n for n in names if names.count(n) > 1})
    if twice:
        raise ValueError(f"record name(s) {twice} appear twice; records need distinct names")
    fit_names = {fit_names} if isinstance(fit_names, str) else set(fit_names)
    unknown = sorted(fit_names - set(names))
    if unknown:
        raise ValueError(
            f"fit_names {unknown} are not records of the comparison; records: {names}"
        )
    if t_end is not None and not (math.isfinite(t_end) and t_end > 0):
        raise ValueError(f"t_end={t_end!r} must be a positive time in seconds (or None)")
    settings = FRFSettings() if frf is None else frf
    model.space.validate(params)
    values = {k: float(np.asarray(v)) for k, v in params.items()}
    check_inputs(dataset, model)
    channels = fitted_channels(dataset, model) if channels is None else check_channels(
        channels, model)
    for c in channels:
        if not any(c in r.columns for r in dataset):
            dataset[0].channel(c)  # a KeyError naming the record, the channel and its columns
    logged = [tuple(c for c in channels if c in r.columns) for r in dataset]
    for record, own in zip(dataset, logged, strict=True):
        if not own:
            raise ValueError(f"record {record.name!r} logs none of the compared channels "
                             f"{list(channels)}; its columns are {list(record.columns)}")
    link = link_channel(model, channels)
    sigma = {s.channel: s.noise_std for s in model.sensors
             if s.noise_std > 0 and s.channel in channels}

    check_initial_state(initial_state)
    held_out = [r.name for r in dataset if r.name not in fit_names]
    states, lead_ins = started_states(model, values, dataset, channels, initial_state,
                                      initial_modes, initial_states, held_out)
    outputs = simulate_started(model, values, dataset, channels, initial_state, initial_modes,
                               states)
    rows, simulated = [], []
    for record, out, own in zip(dataset, outputs, logged, strict=True):
        role = "fit" if record.name in fit_names else "held-out"
        row = compare_record(record, out, role, t_end, settings, encoder_counts, accel_sigma,
                             own, link)
        if sigma:
            window = _time_window(record, t_end)
            floor = {c: _percent_of_rms(s, record.channel(c)[window])
                     for c, s in sigma.items() if c in own}
            if link in sigma and link in own and settings.single_segment \
                    and row.frf.compared.any():
                floor["frf"] = _frf_noise_floor(record, row.frf, settings, sigma[link])
            row = dataclasses.replace(row, noise_floor=row.noise_floor | floor)
        rows.append(row)
        simulated.append(out)

    nyquist = 0.5 / max(r.dt for r in dataset)
    freqs = np.asarray(free_hub_modes(model.structure(values)).frequencies_hz)
    noise = {
        k: v
        for k, v in (("encoder_counts", encoder_counts), ("accel_sigma", accel_sigma))
        if v is not None
    } | {f"{c} sigma": s for c, s in sigma.items()}
    return Comparison(
        rows=tuple(rows),
        records=dataset,
        simulated=tuple(simulated),
        params=values,
        effects=model.effect_names,
        resonances_hz=tuple(float(f) for f in freqs if f <= nyquist),
        t_end=t_end,
        frf_settings=settings,
        noise=noise,
        channels=tuple(channels),
        units=channel_units(model, (*channels, dataset[0].input_name)),
        link=link,
        input_name=dataset[0].input_name,
        initial_states={n: dict(zip(coordinate_names((len(z) - 2) // 2), map(float, z),
                                    strict=True)) for n, z in states.items()},
        lead_ins=lead_ins,
    )


def link_channel(model: Model, channels: Sequence[str]) -> str:
    """The channel the FRF compares: the first link sensor's, or the first link output
    (:data:`~jaxflex.diagnosis.frf.LINK_OUTPUTS`), else the first channel."""
    on_link = [s.channel for s in model.sensors if s.position is not None]
    return next((c for c in channels if c in on_link or c in LINK_OUTPUTS), channels[0])


def channel_units(model: Model, channels: Sequence[str]) -> dict[str, str]:
    """Each channel's unit: its sensor's, the drive's for the input column, or the simulator
    output's."""
    own = {model.drive.name: model.drive.unit} | {s.channel: s.channel_unit for s in model.sensors}
    return {c: own.get(c, KNOWN_UNITS.get(c, "")) for c in channels}


def fit_and_validate(
    records: Iterable[Record],
    fit_names: str | Iterable[str],
    validate_names: str | Iterable[str] | None = None,
    *,
    t_end: float | None = DEFAULT_T_END,
    frf: FRFSettings | None = None,
    encoder_counts: int | None = None,
    accel_sigma: float | None = None,
    **identify_kwargs: Any,
) -> tuple[Fit, Comparison]:
    """Identify on the records named ``fit_names``, then compare on those and the held-out ones.

    ``validate_names`` defaults to every other record. ``identify_kwargs`` go to
    :func:`jaxflex.identification.identify` (model, method, seed, generations, ...); the comparison
    keywords go to :func:`compare`. Returns ``(fit, comparison)``.
    """
    from jaxflex.identification import identify

    dataset = records if isinstance(records, Dataset) else Dataset(list(records))
    fit_set, rest = dataset.split(fit_names)
    if not len(fit_set):
        raise ValueError("fit_names must name at least one record")
    held_out = rest if validate_names is None else dataset.split(validate_names)[0]
    overlap = sorted(set(fit_set.names) & set(held_out.names))
    if overlap:
        raise ValueError(
            f"records {overlap} are both fitted and held out; a held-out record "
            "must not be used in the fit"
        )
    fit = identify(fit_set, **identify_kwargs)
    comparison = compare(
        Dataset([*fit_set, *held_out]),
        fit.model,
        fit.params,
        fit_names=fit_set.names,
        t_end=t_end,
        frf=frf,
        encoder_counts=encoder_counts,
        accel_sigma=accel_sigma,
    )
    return fit, comparison


def noise_floor(
    record: Record,
    encoder_counts: int | None = 4096,
    accel_sigma: float | None = 0.05,
    *,
    t_end: float | None = DEFAULT_T_END,
) -> dict[str, float]:
    """The NRMSE (%) that the sensor noise alone gives on ``record``, per output.

    Encoder quantisation with step ``q = 2π/counts`` has rms ``q/√12``; white accelerometer noise
    has rms ``σ``. Each is divided by the rms of the measured output over the time window (the
    NRMSE's normaliser). A perfect model cannot score below these on average; the relative
    error floor is the same number divided by 100. ``None`` leaves an output out.
    """
    window = _time_window(record, t_end)
    floor = {}
    if encoder_counts is not None:
        if (
            isinstance(encoder_counts, bool)
            or int(encoder_counts) != encoder_counts
            or (encoder_counts < 1)
        ):
            raise ValueError(f"encoder_counts={encoder_counts!r} must be a positive integer")
        step = 2.0 * math.pi / encoder_counts
        if record.joint_angle is not None:
            floor["joint_angle"] = _percent_of_rms(step / math.sqrt(12.0),
                                                   record.joint_angle[window])
    if accel_sigma is not None:
        if not (math.isfinite(accel_sigma) and accel_sigma >= 0):
            raise ValueError(f"accel_sigma={accel_sigma!r} must be >= 0 m/s^2")
        if record.tip_acceleration is not None:
            floor["tip_acceleration"] = _percent_of_rms(accel_sigma,
                                                        record.tip_acceleration[window])
    return floor


# --- per record ---------------------------------------------------------------------------------


def compare_record(
    record: Record,
    out: Outputs,
    role: str,
    t_end: float | None,
    settings: FRFSettings,
    encoder_counts: int | None,
    accel_sigma: float | None,
    outputs: Sequence[str] = OUTPUT_COLUMNS,
    link: str | None = None,
) -> RecordComparison:
    """The model's outputs ``out`` against one record in the role ``role`` (``"fit"`` or
    ``"held-out"``): NRMSE, relative error and RMS error (in the output's unit) per output of
    ``outputs`` that the record logs (the others are left out) over the first ``t_end``
    seconds, the FRFs from the torque to the first link output
    (:data:`~jaxflex.diagnosis.frf.LINK_OUTPUTS`, or ``link``; none where the record does not
    log it) under ``settings``, and the noise floor of the given sensor noise (``None``:
    unknown). An output measured zero throughout (no motion) has no NRMSE (NaN, with a
    warning): its RMS error says how far the model moved. One row of :class:`Comparison`;
    discovery scores its steps with it too."""
    window = _time_window(record, t_end)
    outputs = [o for o in outputs if o in record.columns]
    if not outputs:
        raise ValueError(f"record {record.name!r} logs none of the outputs compared; its "
                         f"columns are {list(record.columns)}")
    errors, relative, rms, still = {}, {}, {}, []
    for name in outputs:
        measured, simulated = record.channel(name)[window], np.asarray(out.channel(name))[window]
        rms[name] = float(np.sqrt(np.mean(np.square(simulated - measured))))
        if not np.any(measured):  # e.g. an input too weak to break the joint free
            warnings.warn(
                f"record {record.name!r}: measured {name} is zero throughout the time window "
                f"(no motion); its NRMSE and relative error are undefined (NaN), its RMS error "
                f"is {rms[name]:.3g}",
                stacklevel=3,
            )
            errors[name] = relative[name] = math.nan
            still.append(name)
            continue
        errors[name] = nrmse(measured, simulated)
        relative[name] = relative_error(measured, simulated)

    if link is None:
        link = next((c for c in LINK_OUTPUTS if c in outputs), outputs[0])
    frf = _frf(record, np.asarray(out.channel(link)), settings, link)
    band = frf.band
    floor = noise_floor(record, encoder_counts, accel_sigma, t_end=t_end)
    if accel_sigma is not None and settings.single_segment and frf.compared.any():
        floor["frf"] = _frf_noise_floor(record, frf, settings, accel_sigma)
    magnitude = np.abs(frf.measured)
    return RecordComparison(
        name=record.name,
        role=role,
        nrmse=errors,
        relative_error=relative,
        frf_nrmse=_safe_frf_nrmse(frf, frf.compared, settings.f_max),
        frf_nrmse_raw=_safe_frf_nrmse(frf, band, settings.f_max),
        frf_bins=(int(frf.compared.sum()), int(band.sum())),
        noise_floor=floor,
        measured_peaks_hz=_peaks(frf.freqs, magnitude, frf.compared),
        model_peaks_hz=_peaks(frf.freqs, np.abs(frf.model), frf.compared),
        frf=frf,
        rms_error=rms,
        still=tuple(still),
    )


def _frf(record: Record, simulated: np.ndarray, settings: FRFSettings,
         output: str = "tip_acceleration") -> FRF:
    """H1 FRFs torque → ``output``, measured and simulated, and the bins to compare; none
    (NaN, no bin compared) where the record does not log ``output`` or it does not move."""
    kw = {"nperseg": settings.nperseg, "window": settings.window}
    fs = record.sample_rate
    logged = output in record.columns
    reading = record.channel(output) if logged else simulated
    freqs, measured, coherence = h1_frf(record.input, reading, fs, **kw)
    _, model, _ = h1_frf(record.input, simulated, fs, **kw)
    if not (logged and np.any(np.abs(measured[np.isfinite(measured)]) > 0)):
        measured = np.full_like(measured, np.nan)
        coherence = np.full_like(coherence, np.nan)
    band = (freqs > 0) & (freqs <= settings.f_max)
    compared = band & np.isfinite(measured) & np.isfinite(model)
    if settings.single_segment and settings.min_input_db is not None:
        power = _input_power(record.input, settings.window)
        peak = power[compared].max() if compared.any() else 0.0
        compared &= power >= peak * 10.0 ** (settings.min_input_db / 10.0)
    if not settings.single_segment and settings.min_coherence is not None:
        compared &= np.nan_to_num(coherence) >= settings.min_coherence
    for a in (freqs, measured, model, coherence, compared):
        a.flags.writeable = False
    return FRF(freqs, measured, model, coherence, compared, float(settings.f_max))


def _input_power(torque: np.ndarray, window: str | None) -> np.ndarray:
    """``|X_k|²`` of the one-segment estimate (mean removed, windowed), as h1_frf forms it."""
    taper = spectral_window(window or "boxcar", torque.size)
    return np.abs(np.fft.rfft((torque - torque.mean()) * taper)) ** 2


def _frf_noise_floor(record: Record, frf: FRF, settings: FRFSettings, accel_sigma: float) -> float:
    """FRF NRMSE (%) that white noise of the link channel (σ) alone gives on the compared bins.

    Noise of variance ``σ²`` adds ``N_k/X_k`` to each bin, with ``E|N_k|² = σ² Σ w²``; to first
    order it changes ``|H|`` by the component along ``H``, of variance ``σ² Σ w² / (2|X_k|²)``.
    """
    taper = spectral_window(settings.window or "boxcar", record.n_samples)
    power = _input_power(record.input, settings.window)[frf.compared]
    spread = accel_sigma**2 * np.sum(taper**2) / (2.0 * power)
    return _percent_of_rms(math.sqrt(float(np.mean(spread))), np.abs(frf.measured[frf.compared]))


def _safe_frf_nrmse(frf: FRF, bins: np.ndarray, f_max: float) -> float:
    """FRF magnitude NRMSE on ``bins``; NaN where there is none or a bin is not finite."""
    h_meas, h_model = frf.measured[bins], frf.model[bins]
    if not bins.any() or not (np.all(np.isfinite(h_meas)) and np.all(np.isfinite(h_model))):
        return math.nan
    return frf_nrmse(frf.freqs[bins], h_meas, h_model, f_max=f_max)


PEAK_MIN_DB = 6.0
"""An FRF peak must stand at least this many dB above the valleys around it (prominence)."""
PEAK_SHARE = 0.6
"""... and at least this share of the most prominent peak's prominence (in dB): the noise of a
measured FRF makes dozens of local maxima, and a one-resonance arm shows one peak."""


def _peaks(freqs: np.ndarray, magnitude: np.ndarray, valid: np.ndarray) -> tuple[float, ...]:
    """Frequencies of the prominent maxima of ``magnitude`` among the valid bins (prominence in
    dB over the valid bins only, at least :data:`PEAK_MIN_DB` and :data:`PEAK_SHARE` of the
    largest), refined by a parabola through the log-magnitudes of three adjacent bins where
    both neighbours are valid."""
    from scipy.signal import find_peaks

    bins = np.flatnonzero(valid & (magnitude > 0) & np.isfinite(magnitude))
    if bins.size < 3:
        return ()
    level = 20.0 * np.log10(magnitude[bins])
    found, props = find_peaks(level, prominence=PEAK_MIN_DB)
    if not found.size:
        return ()
    keep = props["prominences"] >= PEAK_SHARE * props["prominences"].max()
    out = []
    for i in bins[found[keep]]:
        f = float(freqs[i])
        if 0 < i < magnitude.size - 1 and valid[i - 1 : i + 2].all():
            a, b, c = np.log(magnitude[i - 1 : i + 2])
            if b > a and b > c:
                f += float(0.5 * (a - c) / (a - 2.0 * b + c) * (freqs[i + 1] - freqs[i]))
        out.append(f)
    return tuple(out)


# --- helpers ------------------------------------------------------------------------------------


def _time_window(record: Record, t_end: float | None) -> np.ndarray:
    """Samples with ``0 ≤ t − t₀ ≤ t_end`` (all samples for ``None``)."""
    if t_end is None:
        return np.ones(record.n_samples, dtype=bool)
    return record.time - record.time[0] <= t_end + 1e-9 * record.dt


def _percent_of_rms(noise_rms: float, measured: np.ndarray) -> float:
    """``noise_rms`` in percent of the RMS of ``measured``; NaN where that is zero (no motion:
    no percentage of it is defined)."""
    rms = float(np.sqrt(np.mean(np.square(measured))))
    return 100.0 * noise_rms / rms if rms > 0 else math.nan


def merged_peaks(peaks: Iterable[float], rtol: float = 0.03) -> tuple[float, ...]:
    """Peak frequencies of several records as one list: ascending, those within ``rtol`` of
    the previous one's group averaged into one."""
    groups: list[list[float]] = []
    for f in sorted(peaks):
        if groups and f <= groups[-1][0] * (1.0 + rtol):
            groups[-1].append(f)
        else:
            groups.append([f])
    return tuple(float(np.mean(g)) for g in groups)

__all__ = [
    "DEFAULT_T_END",
    "FRF",
    "ROLES",
    "Comparison",
    "FRFSettings",
    "RecordComparison",
    "compare",
    "compare_record",
    "fit_and_validate",
    "noise_floor",
]
