"""The discover notebook runs top to bottom (with the reduced budgets of JAXFLEX_FAST=1)."""

from __future__ import annotations

from pathlib import Path

import nbformat
import pytest
from nbclient import NotebookClient

NOTEBOOK = Path(__file__).resolve().parents[1] / "notebooks" / "discover.ipynb"


def test_discover_notebook_executes(monkeypatch, tmp_path):
    monkeypatch.setenv("JAXFLEX_FAST", "1")
    monkeypatch.setenv("MPLBACKEND", "Agg")
    nb = nbformat.read(NOTEBOOK, as_version=4)
    client = NotebookClient(
        nb, kernel_name="python3", timeout=600, resources={"metadata": {"path": str(tmp_path)}}
    )
    client.execute()
    outputs = [o for cell in nb.cells if cell.cell_type == "code" for o in cell.outputs]
    assert not [o for o in outputs if o.output_type == "error"]
    text = "".join(o.get("text", "") for o in outputs if o.output_type == "stream")
    assert "base + payload" in text  # the hidden payload is found
    assert "UNEXPLAINED" in text  # drag is not in the library: said so
    assert "c_q = 0.0" in text  # the user's own effect is fitted ...
    last = "".join(o.get("text", "") for o in nb.cells[-1].outputs)
    assert last.count("consistent with noise") == 2 and "NOT" not in last  # ... to the noise
    images = [o for o in outputs if "image/png" in o.get("data", {})]
    assert len(images) >= 3


pytestmark = pytest.mark.filterwarnings("ignore::DeprecationWarning")
