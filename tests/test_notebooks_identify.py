"""The identification notebook runs top to bottom (with the reduced budgets of JAXFLEX_FAST=1)."""

from __future__ import annotations

from pathlib import Path

import nbformat
import pytest
from nbclient import NotebookClient

NOTEBOOK = Path(__file__).resolve().parents[1] / "notebooks" / "identify.ipynb"


def test_identify_notebook_executes(monkeypatch, tmp_path):
    monkeypatch.setenv("JAXFLEX_FAST", "1")
    monkeypatch.setenv("MPLBACKEND", "Agg")  # headless: %matplotlib inline still shows figures
    nb = nbformat.read(NOTEBOOK, as_version=4)
    client = NotebookClient(
        nb, kernel_name="python3", timeout=600, resources={"metadata": {"path": str(tmp_path)}}
    )
    client.execute()
    outputs = [o for cell in nb.cells if cell.cell_type == "code" for o in cell.outputs]
    assert not [o for o in outputs if o.output_type == "error"]
    text = "".join(o.get("text", "") for o in outputs if o.output_type == "stream")
    assert "refinement: successful" in text
    assert "coverage per parameter" in text
    weak = [line for line in text.splitlines() if line.startswith("poorly identifiable:")]
    assert weak and "'beta'" in weak[0]  # encoder-only data cannot pin the damping
    images = [o for o in outputs if "image/png" in o.get("data", {})]
    assert len(images) >= 3  # records, convergence curves, intervals


pytestmark = pytest.mark.filterwarnings("ignore::DeprecationWarning")
