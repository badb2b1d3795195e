"""The documentation agrees with the project: every notebook on the home page, one Python
version, the stylesheet that keeps code on the page registered, and every generated part of the
pages (figures, command help, claim rules, the rig-file reference) current in the files, so that
GitHub shows what the site shows."""

from __future__ import annotations

import re
import tomllib
from pathlib import Path

import yaml
from helpers import docs_module

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


def test_every_generated_part_of_the_pages_is_current_in_the_file():
    """What ``python docs/generated.py`` writes is what is committed; no page keeps a marker
    or placeholder that only the site's build would fill."""
    generated = docs_module("generated")
    assert set(generated.PAGES) == set(PAGES)
    names, values = set(), set()
    for page in PAGES:
        text = page.read_text(encoding="utf-8")
        assert generated.regenerate(text) == text, f"{page.name}: run python docs/generated.py"
        assert "{{" not in text and "<!-- benchmark:" not in text, page.name
        names |= {m.group(2) for m in generated.BLOCK.finditer(text)}
        values |= {m.group(2).split("/")[0] for m in generated.VALUE.finditer(text)}
    assert names == set(generated.BLOCKS), sorted(set(generated.BLOCKS) ^ names)
    assert {"real_rig", "substeps", "gpu_h200"} <= values
    assert generated.main(["--check"]) == 0


def test_a_placeholder_reads_the_same_on_github_and_on_the_site():
    """The value is in the file between its markers; the site shows the same text without
    them."""
    generated = docs_module("generated")
    text = (ROOT / "docs" / "real-rigs.md").read_text(encoding="utf-8")
    tables = generated.benchmark_tables
    j_h = tables.formatted(tables.lookup("real_rig/physical_offset/parameters/J_h"), ".2g")
    assert (f"J_h = <!-- value: real_rig/physical_offset/parameters/J_h | .2g -->{j_h}"
            "<!-- end value --> kg m²") in text
    site = generated.for_the_site(text)
    assert f"J_h = {j_h} kg m²" in site and "<!--" not in site
    cli = generated.for_the_site((ROOT / "docs" / "cli.md").read_text(encoding="utf-8"))
    assert "## `jaxflex identify`" in cli and "usage: jaxflex identify" in cli
    stale = "x <!-- value: real_rig/physical/n_parameters | d -->7<!-- end value -->"
    assert generated.regenerate(stale) == stale.replace("-->7<", "-->6<")


def test_the_rig_file_page_describes_every_key_the_reader_reads():
    """Every key ``arm_from_dict`` looks up, for every drive and sensor, has a unit and a
    meaning on the page, and no note describes a key it no longer reads."""
    rig_file = docs_module("rig_file")
    assert rig_file.described() == (set(), set())
    keys = rig_file.read_keys()
    assert keys["sensors.rezero"].default is True
    assert keys["link.clamp_offset"].limit == "≥ 0"
    assert keys["simulation.n_elements"].limit == "1 to 1000"
    assert keys["drive.saturation"].default is rig_file.OPTIONAL
    assert keys["sensors.counts_per_revolution"].tables == {"encoder"}
    assert keys["sensors.x"].tables == {"strain_gauge", "accelerometer", "deflection"}
    page = (ROOT / "docs" / "rig-file.md").read_text(encoding="utf-8")
    for key in ("noise", "resolution", "reading_unit", "rezero", "counts_per_revolution",
                "clamp_offset", "friction_smoothing", "torque_per_unit", "saturation"):
        assert f"| `{key}` |" in page, key
    # a sensor's defaults are its class's fields' (an encoder's resolution: one count)
    assert "| `noise` | number, ≥ 0 | channel's | `0` |" in page
    assert "| `resolution` | number, ≥ 0 | channel's | per type |" in page
    nav = yaml.safe_load((ROOT / "mkdocs.yml").read_text(encoding="utf-8"))["nav"]
    assert {"Rig file": "rig-file.md"} in nav
