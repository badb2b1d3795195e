"""Comparison figures: written as real images of the expected size, labelled, never overwritten."""

from __future__ import annotations

import json

import matplotlib.image as mpimg
import numpy as np
import pytest
from matplotlib.figure import Figure

from jaxflex._io import OutputExistsError
from jaxflex.comparison import compare
from jaxflex.model import Model
from jaxflex.parameters import reference_parameters
from jaxflex.plots import save_figure
from jaxflex.plots.compare import plot_frf, plot_time, save_report
from jaxflex.synthetic import make_records


@pytest.fixture(scope="module")
def comparison():
    records = make_records(inputs=("triangular", "pulse"), seed=1)
    return compare(
        records,
        Model(),
        reference_parameters(),
        fit_names=["triangular"],
        encoder_counts=4096,
        accel_sigma=0.05,
    )


def assert_image(path, width_px: int, height_px: int) -> np.ndarray:
    """The PNG at ``path`` has the given pixel size and is not blank."""
    image = mpimg.imread(path)
    assert image.shape[:2] == (height_px, width_px)
    rgb = image[..., :3]
    assert rgb.var() > 1e-3
    assert np.mean(rgb.min(axis=-1) < 0.9) > 0.01  # more than a few non-white pixels
    return image


def test_time_figure_png_has_size_and_content(comparison, tmp_path):
    fig = plot_time(comparison, "pulse", figsize=(6.0, 5.0), dpi=80)
    assert isinstance(fig, Figure)
    path = save_figure(fig, tmp_path / "time.png")
    assert_image(path, 480, 400)
    labels = [ax.get_ylabel().replace("\n", " ") for ax in fig.axes]  # unit on a 2nd line
    assert labels == [
        "joint angle (rad)",
        "residual (rad)",
        "tip acceleration (m/s^2)",
        "residual (m/s^2)",
    ]
    assert fig.axes[-1].get_xlabel() == "time (s)"
    assert "pulse (held-out)" in fig.get_suptitle()
    legend = [t.get_text() for t in fig.axes[2].get_legend().get_texts()]
    assert legend[1] == f"model (NRMSE {comparison['pulse'].nrmse['tip_acceleration']:.3g} %)"
    # the residual drawn is measured minus model
    record, out = comparison.record("pulse"), comparison.outputs("pulse")
    drawn = fig.axes[3].get_lines()[0].get_ydata()
    np.testing.assert_allclose(drawn, record.tip_acceleration - np.asarray(out.tip_acceleration))


def test_time_figure_from_a_record_and_outputs(comparison):
    record, out = comparison.record(0), comparison.outputs(0)
    fig = plot_time(record, simulated=out, outputs="tip_acceleration")
    assert len(fig.axes) == 2
    with pytest.raises(ValueError, match="simulated="):
        plot_time(record)
    with pytest.raises(ValueError, match="unknown output"):
        plot_time(record, simulated=out, outputs=("tip_accel",))


def test_frf_figure_marks_resonances_and_range(comparison, tmp_path):
    fig = plot_frf(comparison, "pulse", figsize=(7.0, 5.0), dpi=90)
    path = save_figure(fig, tmp_path / "frf.png")
    assert_image(path, 630, 450)
    mag, phase = fig.axes
    assert mag.get_xlim() == (0.0, 15.0) and phase.get_xlabel() == "frequency (Hz)"
    assert "dB" in mag.get_ylabel() and "deg" in phase.get_ylabel()
    # the resonances of the model as fitted: its FRF's peaks, not the free-hub modes
    visible = [f for f in comparison["pulse"].model_peaks_hz if f <= 15.0]
    assert visible
    vertical = [ln.get_xdata()[0] for ln in mag.get_lines() if ln.get_linestyle() == "--"]
    assert vertical == pytest.approx(visible)
    assert f" {visible[0]:.2f} Hz" in [t.get_text() for t in mag.texts]
    # all records in one figure, with a wider band on request
    fig_all = plot_frf(comparison, f_max=25.0)
    assert fig_all.axes[0].get_xlim() == (0.0, 25.0)
    texts = [t.get_text() for t in fig_all.axes[0].get_legend().get_texts()]
    assert "measured triangular" in texts and "model pulse" in texts


def test_pdf_output(comparison, tmp_path):
    path = save_figure(plot_frf(comparison), tmp_path / "frf.pdf")
    assert path.read_bytes()[:5] == b"%PDF-" and path.stat().st_size > 1000


def test_save_figure_refuses_to_overwrite(comparison, tmp_path):
    path = tmp_path / "fig.png"
    path.write_bytes(b"user data")
    with pytest.raises(OutputExistsError, match="overwrite"):
        save_figure(plot_frf(comparison), path)
    assert path.read_bytes() == b"user data"
    save_figure(plot_frf(comparison, dpi=50), path, overwrite=True)
    assert_image(path, 400, 300)
    assert [p.name for p in tmp_path.iterdir()] == ["fig.png"]  # no temporary left behind
    with pytest.raises(ValueError, match="'.jpeg'"):
        save_figure(plot_frf(comparison), tmp_path / "fig.jpeg")


def test_report_writes_everything_once(comparison, tmp_path):
    out = tmp_path / "report"
    paths = save_report(comparison, out, dpi=50)
    names = sorted(p.name for p in paths)
    assert names == sorted(
        ["table.txt", "comparison.json", "triangular_time.png", "pulse_time.png", "frf.png"]
    )
    assert (out / "table.txt").read_text() == comparison.table()
    assert json.loads((out / "comparison.json").read_text())["records"][1]["name"] == "pulse"
    assert_image(out / "pulse_time.png", 400, 325)
    before = {p.name: p.stat().st_mtime_ns for p in out.iterdir()}
    with pytest.raises(OutputExistsError):
        save_report(comparison, out)
    assert {p.name: p.stat().st_mtime_ns for p in out.iterdir()} == before
    save_report(comparison, out, overwrite=True, dpi=50)
