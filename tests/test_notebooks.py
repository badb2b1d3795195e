"""Every notebook runs top to bottom (with the reduced budgets of JAXFLEX_FAST=1) and shows
what it promises: its printed conclusions and its inline figures."""

from __future__ import annotations

import ast
import importlib
from dataclasses import dataclass
from pathlib import Path

import nbformat
import pytest
from nbclient import NotebookClient

NOTEBOOKS = Path(__file__).resolve().parents[1] / "notebooks"

pytestmark = pytest.mark.filterwarnings("ignore::DeprecationWarning")


@dataclass
class Executed:
    """A notebook after execution: its printed text, inline images and cells."""

    text: str
    images: int
    cells: list


def run_notebook(name: str, monkeypatch, tmp_path, timeout: int = 600) -> Executed:
    """Execute ``notebooks/<name>.ipynb`` headless in ``tmp_path``; fail on any error output."""
    monkeypatch.setenv("JAXFLEX_FAST", "1")
    monkeypatch.setenv("MPLBACKEND", "Agg")  # headless, as in CI: %matplotlib inline still shows
    nb = nbformat.read(NOTEBOOKS / f"{name}.ipynb", as_version=4)
    client = NotebookClient(
        nb, kernel_name="python3", timeout=timeout, resources={"metadata": {"path": str(tmp_path)}}
    )
    client.execute()
    outputs = [o for cell in nb.cells if cell.cell_type == "code" for o in cell.outputs]
    errors = [o for o in outputs if o.output_type == "error"]
    assert not errors, errors
    text = "".join(o.get("text", "") for o in outputs if o.output_type == "stream")
    images = sum("image/png" in o.get("data", {}) for o in outputs)
    return Executed(text=text, images=images, cells=nb.cells)


def test_notebooks_use_public_names_only():
    """A notebook imports what a user would: names of ``jaxflex.__all__``, figures of
    ``jaxflex.plots.__all__``, and ``jaxflex.refine.refine``, the one public function that shares
    its module's name (so it cannot be a top-level name)."""
    allowed = {"jaxflex", "jaxflex.plots"}
    seen = set()
    for path in sorted(NOTEBOOKS.glob("*.ipynb")):
        nb = nbformat.read(path, as_version=4)
        code = "\n".join(c.source for c in nb.cells if c.cell_type == "code")
        code = "\n".join(line for line in code.splitlines() if not line.startswith("%"))
        for node in ast.walk(ast.parse(code)):
            if isinstance(node, ast.ImportFrom) and node.module.startswith("jaxflex"):
                module = importlib.import_module(node.module)
                for alias in node.names:
                    where = f"{path.name}: from {node.module} import {alias.name}"
                    assert alias.name in module.__all__, where
                    own = node.module.rpartition(".")[2] == alias.name
                    assert node.module in allowed or own, where
                    seen.add(node.module)
            elif isinstance(node, ast.Import):
                names = [a.name for a in node.names]
                assert all(n == "jaxflex" or not n.startswith("jaxflex") for n in names), names
    assert {"jaxflex", "jaxflex.plots"} <= seen


def test_identify_notebook(monkeypatch, tmp_path):
    run = run_notebook("identify", monkeypatch, tmp_path)
    assert "refinement: successful" in run.text
    assert "coverage per parameter" in run.text
    weak = [line for line in run.text.splitlines() if line.startswith("poorly identifiable:")]
    assert weak and "'beta'" in weak[0]  # encoder-only data cannot pin the damping
    assert run.images >= 3  # records, convergence curves, intervals


def test_compare_notebook(monkeypatch, tmp_path):
    run = run_notebook("compare", monkeypatch, tmp_path)
    assert "held-out" in run.text and "floor %" in run.text  # the sensor noise's floors
    assert any(line.split()[2:4] == ["tip", "acc"] for line in run.text.splitlines()
               if "held-out" in line)  # a row per record and channel
    assert run.images >= 3  # time and FRF figures


def test_discover_notebook(monkeypatch, tmp_path):
    run = run_notebook("discover", monkeypatch, tmp_path)
    assert "base + payload" in run.text  # the hidden payload is found
    assert "UNEXPLAINED" in run.text  # drag is not in the library: said so
    assert "c_q = 0.0" in run.text  # the user's own effect is fitted ...
    drag = next(c for c in run.cells if "with_drag" in c.source)
    last = "".join(o.get("text", "") for o in drag.outputs)
    assert last.count("consistent with noise") == 2 and "NOT" not in last  # ... to the noise
    # the cogging torque outside the library, named by the missing torque's map
    mapped = next(ln for ln in run.text.splitlines() if "the missing torque looks like" in ln)
    assert "*sin(8*theta)" in mapped and "a function of state and input" in mapped
    assert run.images >= 4


def test_design_notebook(monkeypatch, tmp_path):
    run = run_notebook("design", monkeypatch, tmp_path)
    assert "rigid estimate from" in run.text and "active constraints: b_v >= 0" in run.text
    assert "narrower" in run.text and "triangular" in run.text
    assert run.images >= 2  # the design and the interval figures


def test_real_rig_notebook(monkeypatch, tmp_path):
    from jaxflex import datasets

    try:
        datasets.fetch("quanser_rotflex")
    except datasets.DataUnavailable as err:
        pytest.skip(f"real-rig data unavailable: JAXFLEX_DATA_DIR unset and no network ({err})")
    run = run_notebook("real_rig", monkeypatch, tmp_path)
    assert "square_wave" in run.text and "random_985" in run.text and "tau_0 = " in run.text
    assert "black box, order" in run.text
    assert "added: torque_offset" in run.text  # discover's first effect on the rig
    assert run.images >= 3  # the two runs, the held-out comparison, discover's error falling
