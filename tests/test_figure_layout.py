"""Figures reviewed as a set: no text of a figure overlaps another, none is cut by its edge.

Every figure the demo writes (the comparison report: a time figure per record and the FRF;
the discovery report: the error falling, the diagnosis pages, a before/after overlay; the
fit's convergence and intervals) and the report of a real rig (``validate --report`` on the
Quanser ROTFLEX records, skipped without the data) is drawn at its default size with the Agg
canvas, and the window extent of every visible text (titles, axis labels, tick labels, legend
entries, annotations) is checked against every other and against the figure's edge.

The figures come from the functions the reports call, on small objects built here: the
comparison at the true parameters instead of a demo fit, a diagnosis of a model with a wrong
parameter instead of a discovery run (its figures draw the same objects).
"""

from __future__ import annotations

import dataclasses
import itertools

import numpy as np
import pytest
from helpers import ARMS, REAL_DATA_DIR
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.text import Text

import jaxflex  # noqa: F401  (float64)
from jaxflex.comparison import compare
from jaxflex.demo import FIT_ON, NOISE
from jaxflex.model import Model
from jaxflex.synthetic import make_records, true_parameters

TOLERANCE = -2.0
"""Pixels two text boxes may share before they count as overlapping: none, touching is enough."""


def _visible(text: Text) -> bool:
    return text.get_visible() and bool(text.get_text().strip()) and text.get_alpha() != 0


def _texts(fig) -> list[tuple[str, Text]]:
    """Every drawn text of ``fig`` with a name saying where it is."""
    out = []
    for t in fig.texts:  # the suptitle among them
        out.append(("suptitle" if t is fig._suptitle else "figure text", t))
    for i, ax in enumerate(fig.axes):
        where = f"axes {i}"
        for t in (ax.title, ax._left_title, ax._right_title):
            out.append((f"{where} title", t))
        out.append((f"{where} x label", ax.xaxis.label))
        out.append((f"{where} y label", ax.yaxis.label))
        for axis, name in ((ax.xaxis, "x"), (ax.yaxis, "y")):
            lo, hi = sorted(axis.get_view_interval())
            for tick in axis.get_major_ticks() + axis.get_minor_ticks():
                if lo - 1e-9 * abs(hi - lo) <= tick.get_loc() <= hi + 1e-9 * abs(hi - lo):
                    for label in (tick.label1, tick.label2):
                        out.append((f"{where} {name} tick", label))
        for t in ax.texts:
            out.append((f"{where} text", t))
        legend = ax.get_legend()
        if legend is not None and legend.get_visible():
            for t in legend.get_texts():
                out.append((f"{where} legend", t))
            out.append((f"{where} legend title", legend.get_title()))
    for legend in fig.legends:
        for t in legend.get_texts():
            out.append(("figure legend", t))
    return [(w, t) for w, t in out if _visible(t)]


def layout_problems(fig) -> list[str]:
    """Pairs of overlapping texts, and texts cut by the figure's edge, in words."""
    canvas = FigureCanvasAgg(fig)  # jaxflex figures carry no canvas of their own
    canvas.draw()
    renderer = canvas.get_renderer()
    boxes = [(w, t, t.get_window_extent(renderer)) for w, t in _texts(fig)]
    problems = []
    edge = fig.bbox
    for where, text, box in boxes:
        if (box.x0 < edge.x0 - TOLERANCE or box.y0 < edge.y0 - TOLERANCE
                or box.x1 > edge.x1 + TOLERANCE or box.y1 > edge.y1 + TOLERANCE):
            problems.append(f"{where} {text.get_text()!r} cut by the figure's edge")
    for (w1, t1, b1), (w2, t2, b2) in itertools.combinations(boxes, 2):
        dx = min(b1.x1, b2.x1) - max(b1.x0, b2.x0)
        dy = min(b1.y1, b2.y1) - max(b1.y0, b2.y0)
        if dx > TOLERANCE and dy > TOLERANCE:
            problems.append(f"{w1} {t1.get_text()!r} overlaps {w2} {t2.get_text()!r}")
    return problems


def assert_readable(fig, name: str) -> None:
    problems = layout_problems(fig)
    assert not problems, f"{name}:\n  " + "\n  ".join(problems)


# ------------------------------------------------------------------------------ the demo


@pytest.fixture(scope="module")
def demo_comparison():
    records = make_records(seed=0)
    return compare(records, Model(), true_parameters(), fit_names=[FIT_ON], **NOISE)


def test_the_checker_finds_overlaps_and_cut_labels():
    from jaxflex.plots._style import new_figure

    fig, axes = new_figure(1, 1, figsize=(4.0, 3.0))
    ax = axes[0, 0]
    ax.text(0.5, 0.5, "first")
    ax.text(0.5, 0.5, "second")
    ax.text(1.5, 0.5, "far outside the figure", transform=ax.transAxes)
    problems = layout_problems(fig)
    assert any("'first' overlaps" in p and "'second'" in p for p in problems)
    assert any("cut by the figure's edge" in p for p in problems)


def test_demo_comparison_figures(demo_comparison):
    from jaxflex.plots.compare import plot_frf, plot_time

    for i, name in enumerate(demo_comparison.names):
        assert_readable(plot_time(demo_comparison, i), f"{name}_time")
    assert_readable(plot_frf(demo_comparison), "frf")


def test_demo_discovery_figures():
    """The discovery report's figures on a base model with a wrong parameter."""
    from jaxflex.diagnosis import diagnose
    from jaxflex.plots.diagnose import plot_diagnosis, plot_error_falling, plot_overlay
    from jaxflex.simulation import simulate

    records = make_records(seed=0)
    model, truth = Model(), true_parameters()
    wrong = {**truth, "J_h": 1.1 * float(truth["J_h"])}
    before = [simulate(model, wrong, r.torque) for r in records]
    after = [simulate(model, truth, r.torque) for r in records]
    units = {"joint_angle": "rad", "tip_acceleration": "m/s^2"}
    base = plot_diagnosis(diagnose(records, before), units=units)
    assert_readable(base, "diagnosis_base")
    assert_readable(plot_diagnosis(diagnose(records, after), units=units), "diagnosis_final")
    spectra = [ax for ax in base.axes if ax.get_xlabel().startswith("frequency (Hz)")]
    assert [ax.get_ylabel() for ax in spectra] == ["PSD (rad²/Hz)", "PSD ((m/s^2)²/Hz)"]
    assert not any("-0 " in t.get_text() for t in base.axes[-1].get_yticklabels())
    assert_readable(
        plot_overlay(records[0], before[0], after[0], labels=("base", "base + payload"),
                     outputs=list(units), units=units, role="fitted"),
        "before_after",
    )
    assert_readable(
        plot_error_falling(
            ["base", "base + payload", "base + payload + delay"],
            {"joint_angle": [20.0, 3.0, 2.9], "tip_acceleration": [60.0, 9.0, 8.5]},
            noise_floor={"joint_angle": 2.5, "tip_acceleration": 8.0},
            frf_nrmse=[40.0, 6.0, 5.5],
            holdout={"joint_angle": [25.0, 4.0, 3.8], "tip_acceleration": [70.0, 10.0, 9.0]},
        ),
        "error_falling",
    )


def test_fit_figure():
    """``identify --plot``: convergence and intervals, with robust and unidentifiable ones."""
    from jaxflex.identification import Fit, History
    from jaxflex.plots.identify import plot_fit

    params = {k: float(v) for k, v in true_parameters().items()}
    # the ends (as factors of the value) of a fit to the ROTFLEX square wave: its figure cut
    # the title and crowded the ticks before they were fixed; b_v and alpha unidentifiable
    nominal = {"E": (0.994, 1.006), "J_h": (0.976, 1.024), "b_v": (1e-40, 1e40),
               "tau_c": (0.977, 1.023), "alpha": (1e-30, 1e30), "beta": (0.79, 1.26)}
    wide = {"E": (0.972, 1.028), "J_h": (0.86, 1.16), "b_v": (1e-40, 1e40),
            "tau_c": (0.65, 1.54), "alpha": (1e-30, 1e30), "beta": (0.76, 1.31)}
    intervals = {k: (params[k] * lo, params[k] * hi) for k, (lo, hi) in nominal.items()}
    robust = {k: (params[k] * lo, params[k] * hi) for k, (lo, hi) in wide.items()}
    spread = {"E": 0.002, "J_h": 0.004, "b_v": 0.4, "tau_c": 0.008, "alpha": 0.0, "beta": 0.09}
    best = np.geomspace(0.2, 0.07, 7)  # minor-tick labels on the log axis, as on the rig
    fit = Fit(
        params=params, names=tuple(params), fixed={}, model=Model(), cost=1e-4,
        cost_search=1e-3, intervals=intervals, std={}, covariance=np.zeros((0, 0)),
        correlation=np.zeros((0, 0)), noise={}, poorly_identifiable=("alpha", "b_v", "beta"),
        warnings=(), history=History(best, 2 * best, {k: np.full(7, v) for k, v in
                                                      params.items()}),
        refinement=None, method="de", seed=0, settings={}, timing={}, record_names=("a",),
        unidentifiable=("b_v", "alpha"), robust_intervals=robust,
        residual_checks={"conditional": True, "white": False},
    )
    assert_readable(plot_fit(fit, params), "fit")
    assert_readable(plot_fit(dataclasses.replace(fit, robust_intervals={}, residual_checks={}),
                             params), "fit without robust intervals")
    tiny = {k: (v * (1 - s / 100), v * (1 + s / 100)) for (k, v), s in zip(
        params.items(), spread.values(), strict=True)}  # a clean fit: ±0.002 % to ±0.4 %
    tiny["alpha"] = (0.9999 * params["alpha"], 1.0001 * params["alpha"])
    assert_readable(plot_fit(dataclasses.replace(fit, intervals=tiny, robust_intervals=tiny,
                                                 unidentifiable=()), params), "clean fit")


# ------------------------------------------------------------------------------ an invented rig

INVENTED_RIG = """\
name = "strip"
description = "0.6 m aluminium strip, voltage amplifier, gauge at 0.05 m, accelerometer at 0.4 m"

[link]
length = 0.6
width = 0.03
thickness = 0.002
density = 2700.0

[simulation]
n_elements = 4

[sampling]
dt = 0.002
duration = 1.2

[parameters]
E = { reference = 7.0e10, lower = 5.0e10, upper = 9.0e10 }
J_h = { reference = 0.002, lower = 5e-4, upper = 5e-3 }
b_v = { reference = 0.005, lower = 1e-4, upper = 0.05 }
tau_c = { reference = 0.01, lower = 1e-3, upper = 0.05 }
alpha = { reference = 0.5, fixed = true }
beta = { reference = 1e-4, fixed = true }

[drive]
type = "voltage"
resistance = 2.6
torque_constant = 7.68e-3
back_emf_constant = 7.68e-3
gear_ratio = 70.0
gearbox_efficiency = 0.90
motor_efficiency = 0.69

[[sensors]]
type = "encoder"
channel = "angle"
counts_per_revolution = 2048

[[sensors]]
type = "strain_gauge"
channel = "strain"
x = 0.05
noise = 2e-6

[[sensors]]
type = "accelerometer"
channel = "acc"
x = 0.4
noise = 0.05
"""


@pytest.fixture(scope="module")
def invented(tmp_path_factory):
    """Two logged records of the invented rig (voltage drive, a gauge and an accelerometer
    part-way along the link) compared with the rig at a hub inertia 30 % off."""
    from jaxflex.arm import load_arm
    from jaxflex.measured import logged_record
    from jaxflex.signals import reference_input

    path = tmp_path_factory.mktemp("rig") / "strip.toml"
    path.write_text(INVENTED_RIG)
    rig = load_arm(path)
    truth = {k: float(v) for k, v in rig.space.reference().items()}
    records = []
    for seed, (name, volts) in enumerate((("triangular", 3.0), ("pulse", 4.0))):
        _, u = reference_input(name, volts, 1.2, 0.002)
        u = np.concatenate([np.zeros(50), u])
        records.append(logged_record(rig, truth, 0.002 * np.arange(u.size), u, seed=seed,
                                     name=name))
    wrong = truth | {"J_h": 1.3 * truth["J_h"]}
    return rig, compare(records, rig, wrong, fit_names=["triangular"], t_end=None)


def _legends_off_the_data(fig) -> list[str]:
    """Legends that cover some axes' plotting area."""
    canvas = FigureCanvasAgg(fig)
    canvas.draw()
    renderer = canvas.get_renderer()
    legends = [(f"axes {i} legend", ax.get_legend()) for i, ax in enumerate(fig.axes)]
    legends += [("figure legend", lg) for lg in fig.legends]
    out = []
    for where, legend in legends:
        if legend is None:
            continue
        box = legend.get_window_extent(renderer)
        for i, ax in enumerate(fig.axes):
            if box.overlaps(ax.bbox):
                out.append(f"{where} covers axes {i}")
    return out


def test_invented_rig_validate_figures(invented):
    from jaxflex.plots.compare import plot_frf, plot_time

    _, comparison = invented
    for i, name in enumerate(comparison.names):
        assert_readable(plot_time(comparison, i), f"{name}_time")
    frf = plot_frf(comparison)
    assert_readable(frf, "frf")
    magnitude, phase = frf.axes
    assert magnitude.get_ylabel() == "|H| (dB re 1 m/m / V)"  # strain per volt: the drive's unit
    for line in phase.get_lines():
        y = np.asarray(line.get_ydata(), dtype=float)
        y = y[np.isfinite(y)]
        if y.size > 1 and line.get_linestyle() == "-":  # the model: unwrapped, no 360° jump
            assert np.all(np.abs(np.diff(y)) < 180.0), y
    assert "floor FRF %" in comparison.table()  # the accelerometer's noise gives its floor
    assert max(len(ln) for ln in comparison.table().splitlines()) <= 100


def test_invented_rig_diagnosis_figure(invented):
    from jaxflex.diagnosis import diagnose
    from jaxflex.plots.diagnose import plot_diagnosis

    rig, comparison = invented
    diagnosis = diagnose([comparison.record(i) for i in range(len(comparison))],
                         [comparison.outputs(i) for i in range(len(comparison))],
                         channels=comparison.channels)
    page = plot_diagnosis(diagnosis, units=comparison.units, input_name="voltage",
                          input_unit=rig.drive.unit)
    assert_readable(page, "diagnosis")
    assert not _legends_off_the_data(page)
    titles = [ax.get_title() for ax in page.axes]
    assert {"angle vs voltage (V)", "strain vs voltage (V)", "acc vs voltage (V)"} <= set(titles)
    assert not any("torque" in ax.get_xlabel() for ax in page.axes)


def test_invented_rig_discovery_figures(invented):
    from jaxflex.plots.diagnose import plot_error_falling, plot_overlay

    _, comparison = invented
    labels = ("base, nothing added",
              "base + payload + motor lag + joint stiffness + torque offset + sensor gain acc")
    overlay = plot_overlay(comparison.record(1), comparison.outputs(1), comparison.outputs(1),
                           labels=labels, outputs=comparison.channels, units=comparison.units,
                           role="held out")
    assert_readable(overlay, "pulse_before_after")
    assert not _legends_off_the_data(overlay)
    steps = ["base", "base + payload", "base + payload + motor lag + joint stiffness"]
    falling = plot_error_falling(
        steps, {"angle": [20.0, 3.0, 2.9], "strain": [30.0, 5.0, 4.9], "acc": [60.0, 9.0, 8.5]},
        noise_floor={"angle": 2.5, "strain": 4.5, "acc": 8.0}, frf_nrmse=[40.0, 6.0, 5.5],
        holdout={"angle": [25.0, 4.0, 3.8], "strain": [33.0, 6.0, 5.0],
                 "acc": [70.0, 10.0, 9.0]})
    assert_readable(falling, "error_falling")
    assert not _legends_off_the_data(falling)
    colours = {line.get_label(): line.get_color() for line in falling.axes[0].get_lines()}
    nrmse = [colours[f"{c} NRMSE"] for c in ("angle", "strain", "acc")]
    assert len(set(nrmse)) == 3  # a colour per channel


def test_intervals_label_a_far_robust_end_as_it_is_on_even_ticks():
    """A robust interval reaching +4.4e7 % is labelled so, not by where its bar is cut; the
    symmetric-log axis ticks the same decades on both sides, evenly."""
    from jaxflex.identification import Fit, History
    from jaxflex.plots.identify import plot_intervals

    params = {"E": 7.0e10, "J_h": 0.002, "b_v": 0.005}
    intervals = {"E": (6.9e10, 7.1e10), "J_h": (0.0019, 0.0021), "b_v": (0.004, 0.006)}
    robust = intervals | {"b_v": (0.005 * 1e-6, 0.005 * (1 + 4.4e5))}  # -100 % / +4.4e7 %
    fit = Fit(
        params=params, names=tuple(params), fixed={}, model=Model(), cost=1e-4,
        cost_search=1e-3, intervals=intervals, std={}, covariance=np.zeros((0, 0)),
        correlation=np.zeros((0, 0)), noise={}, poorly_identifiable=("b_v",), warnings=(),
        history=History(np.ones(2), np.ones(2), {k: np.full(2, v) for k, v in params.items()}),
        refinement=None, method="de", seed=0, settings={}, timing={}, record_names=("a",),
        robust_intervals=robust,
    )
    fig = plot_intervals(fit)
    assert_readable(fig, "intervals")
    ax = fig.axes[0]
    labels = [t.get_text() for t in ax.get_yticklabels()]
    assert any("robust −100/+4.4e7 %" in t for t in labels), labels
    ticks = [t for t in ax.get_xticks() if t != 0]
    exponents = sorted({round(np.log10(abs(t))) for t in ticks})
    positive = sorted(round(np.log10(t)) for t in ticks if t > 0)
    negative = sorted(round(np.log10(-t)) for t in ticks if t < 0)
    assert negative == positive[:len(negative)]  # the same decades on both sides
    assert len({b - a for a, b in itertools.pairwise(exponents)}) <= 1  # evenly spaced


# ------------------------------------------------------------------------------ a real rig


def test_real_rig_report_figures():
    from jaxflex import datasets
    from jaxflex.arm import load_arm
    from jaxflex.plots.compare import plot_frf, plot_time

    try:
        records = datasets.load("quanser_rotflex", REAL_DATA_DIR)
    except datasets.DataUnavailable as err:
        pytest.skip(f"real-rig data unavailable ({err})")
    rig = load_arm(ARMS / "quanser_rotflex.toml")
    comparison = compare(list(records.values()), rig, rig.space.reference(),
                         fit_names=[next(iter(records))])
    for i, name in enumerate(comparison.names):
        assert_readable(plot_time(comparison, i), f"{name}_time")
    assert_readable(plot_frf(comparison), "frf")
    one_peak = [len(row.measured_peaks_hz) for row in comparison]
    assert max(one_peak) <= 1, one_peak  # one resonance in the band: at most one peak
    # discover's diagnosis page on the rig's own channels
    from jaxflex.diagnosis import diagnose
    from jaxflex.plots.diagnose import plot_diagnosis

    diagnosis = diagnose([comparison.record(i) for i in range(len(comparison))],
                         [comparison.outputs(i) for i in range(len(comparison))],
                         channels=comparison.channels)
    page = plot_diagnosis(diagnosis, units=comparison.units)
    assert_readable(page, "diagnosis")
    assert not any(t.get_text().startswith("angle -0") for t in page.axes[-1].get_yticklabels())
