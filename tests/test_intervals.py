"""Intervals that say what they assume: robust (HAC) intervals beside the nominal ones, the
residual checks that label the nominal ones conditional on the model, unidentifiable
parameters reported as such, and the figure that shows all three.

One fit of the reference model to records of an arm with a 5 g payload (the effect missing
from the model: 24 % rms NRMSE, smooth residuals) serves every test; the correct-model case
is checked beside the coverage test of ``tests/test_identify.py``.
"""

import json
import math

import numpy as np
import pytest

import jaxflex  # noqa: F401  (float64)
from jaxflex.effects import get_effect
from jaxflex.identification import Fit, identify
from jaxflex.model import Model
from jaxflex.synthetic import make_records

TRUTH = {k: float(v) for k, v in Model().space.reference().items()}
BOUNDS = {k: (v / 1.5, v * 1.5) for k, v in TRUTH.items()}
FACTORS = (1.04, 0.96, 1.2, 0.97, 1.1, 0.9)
START = {k: v * f for (k, v), f in zip(TRUTH.items(), FACTORS, strict=True)}


@pytest.fixture(scope="module")
def misfit():
    """The reference model fitted to records of the arm with a payload it does not have."""
    records = make_records(Model(effects=(get_effect("payload"),)), {"m_p": 0.005}, seed=0)
    return identify(records, generations=1, population=4, init_population=START,
                    bounds=BOUNDS, seed=0)


def test_a_missing_effect_widens_the_robust_intervals_and_labels_the_nominal_ones(misfit):
    fit = misfit
    assert fit.nrmse > 10  # far above the noise (about 0.7 % here)
    checks = fit.residual_checks
    assert not checks["white"] and fit.model_conditional
    rho = max(c["lag1"] for c in checks["channels"].values())
    assert rho > 0.95  # smooth residuals: the model error, not the noise
    # The robust intervals are wider for every parameter, by more than 3 and by less than the
    # factor √((1+ρ)/(1−ρ)) that an AR(1) residual with that lag-1 correlation would imply
    # (the Bartlett estimate is truncated at a quarter record).
    limit = math.sqrt((1 + rho) / (1 - rho))
    for name in fit.names:
        lo, hi = fit.intervals[name]
        rlo, rhi = fit.robust_intervals[name]
        assert rlo < lo and hi < rhi, name
        assert 3.0 < checks["widening"][name] < limit, (name, checks["widening"][name], limit)
    # the nominal intervals miss the truth that the robust ones catch for most parameters
    nominal = sum(lo <= TRUTH[n] <= hi for n, (lo, hi) in fit.intervals.items())
    robust = sum(lo <= TRUTH[n] <= hi for n, (lo, hi) in fit.robust_intervals.items())
    assert robust > nominal
    # said in words
    text = fit.summary()
    assert "CONDITIONAL on the model" in text and "robust ±%" in text
    assert any("assume the model is right and the noise white" in w for w in fit.warnings)


def test_fit_files_keep_the_new_fields_and_old_files_still_load(misfit, tmp_path):
    path = misfit.to_json(tmp_path / "fit.json")
    again = Fit.from_json(path)
    for name, ends in misfit.robust_intervals.items():
        assert again.robust_intervals[name] == pytest.approx(ends, rel=1e-12)
    assert again.model_conditional and again.unidentifiable == misfit.unidentifiable
    assert again.residual_checks["channels"] == misfit.residual_checks["channels"]
    # a file written before these fields existed
    data = json.loads(path.read_text())
    for key in ("unidentifiable", "robust_intervals", "robust_std", "residual_checks"):
        del data[key]
    old = Fit.from_dict(data)
    assert not old.robust_intervals and not old.model_conditional
    assert "not checked" in old.summary()


def test_an_unidentifiable_parameter_is_reported_as_such_not_as_numbers(misfit):
    """An interval of decades is replaced by words in the summary and flagged in the JSON."""
    import dataclasses

    fit = dataclasses.replace(
        misfit,
        intervals={**misfit.intervals, "alpha": (2.6e-42, 5.6e35)},
        unidentifiable=("alpha",),
    )
    line = next(s for s in fit.summary().splitlines() if s.startswith("alpha"))
    assert "not identifiable from these records" in line and "e-42" not in line
    assert fit.to_dict()["unidentifiable"] == ["alpha"]


def test_interval_figure_is_readable(misfit):
    """Percent of the estimate on a symmetric-log axis, robust beneath, unidentifiable marked."""
    import dataclasses

    from jaxflex.plots.identify import plot_intervals

    fit = dataclasses.replace(
        misfit, intervals={**misfit.intervals, "alpha": (2.6e-42, 5.6e35)},
        unidentifiable=("alpha",),
    )
    fig = plot_intervals(fit, TRUTH)
    ax = fig.axes[0]
    assert ax.get_xscale() == "symlog"
    labels = [t.get_text() for t in ax.get_yticklabels()]
    assert any("alpha" in t and "not identifiable" in t for t in labels)
    assert sum("robust" in t for t in labels) == len(fit.names) - 1
    assert "conditional" in ax.get_title()
    # every drawn bar lies within the axis (nothing runs off to 1e35)
    lo, hi = ax.get_xlim()
    for line in ax.get_lines():
        x = np.asarray(line.get_xdata(), dtype=float)
        assert np.all((x >= lo) & (x <= hi)), line
