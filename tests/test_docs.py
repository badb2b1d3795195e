"""The documentation agrees with the project: every notebook on the home page, one Python
version, and the stylesheet that keeps code on the page registered."""

from __future__ import annotations

import re
import tomllib
from pathlib import Path

import yaml
from helpers import benchmark_tables

ROOT = Path(__file__).resolve().parents[1]
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]


def test_every_notebook_is_linked_from_the_home_page():
    home = (ROOT / "docs" / "index.md").read_text(encoding="utf-8")
    linked = set(re.findall(r"\]\(notebooks/([\w-]+)\.ipynb\)", home))
    notebooks = {p.stem for p in (ROOT / "notebooks").glob("*.ipynb")}
    assert notebooks and notebooks <= linked, sorted(notebooks - linked)


def test_one_python_version_everywhere():
    """The Python the pages ask for is the one pyproject.toml requires."""
    project = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))["project"]
    required = project["requires-python"].removeprefix(">=")
    stated = {(page.name, version) for page in PAGES
              for version in re.findall(r"Python (?:≥|>=) ?(\d+\.\d+)", page.read_text("utf-8"))}
    assert stated and {version for _, version in stated} == {required}, sorted(stated)


def test_code_scrolls_instead_of_running_off_the_page():
    """The extra stylesheet is registered, exists, and lets notebook code cells scroll."""
    config = yaml.safe_load((ROOT / "mkdocs.yml").read_text(encoding="utf-8"))
    sheets = [ROOT / "docs" / name for name in config["extra_css"]]
    assert sheets and all(sheet.is_file() for sheet in sheets)
    rules = " ".join(sheet.read_text(encoding="utf-8") for sheet in sheets)
    editor = re.search(r"\.jp-InputArea-editor\s*\{([^}]*)\}", rules)
    assert editor and "overflow-x: auto" in editor.group(1)


def test_every_figure_on_the_pages_comes_from_a_results_file():
    """Each table marker and value placeholder of the pages resolves in
    ``benchmarks/results``."""
    tables = benchmark_tables()
    used = set()
    for page in (ROOT / "docs").glob("*.md"):
        text = page.read_text(encoding="utf-8")
        for name in tables.MARKER.findall(text):
            assert name in tables.TABLES, (page.name, name)
            assert "|---" in tables.TABLES[name](), (page.name, name)
        for path, spec in tables.VALUE.findall(text):
            used.add(path.split("/")[0])
            assert tables.formatted(tables.lookup(path), spec), (page.name, path)
    assert used, "no page reads a figure from benchmarks/results"
