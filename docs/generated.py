"""The generated parts of the README and the documentation pages, written into the files, so
that a page reads the same on GitHub as on the site and none goes stale.

- A block ``<!-- generated: NAME -->`` … ``<!-- end generated -->`` holds what
  :data:`BLOCKS` ``[NAME]`` writes: a table of measured figures (``docs/benchmark_tables.py``),
  each command's ``--help`` (from the parser), the rules of discover's claims (from
  ``jaxflex.discovery.explain.RULES``) or the rig-file reference (``docs/rig_file.py``).
- An inline ``<!-- value: FILE/KEY/... | SPEC -->…<!-- end value -->`` holds one value of
  ``benchmarks/results/FILE.json``, formatted by ``SPEC``
  (:func:`benchmark_tables.formatted`).

``python docs/generated.py`` rewrites every page (:data:`PAGES`); ``--check`` only says which
are stale (the tests run it). The site's hooks fill the same blocks and drop the markers.
"""

from __future__ import annotations

import argparse
import importlib.util
import os
import re
import sys
from collections.abc import Callable
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
"""The pages with generated parts (any of them may have some)."""
HELP_WIDTH = "100"
"""The width each command's ``--help`` is wrapped to."""

BLOCK = re.compile(r"(<!-- generated: (\w+) -->\n)(.*?)(<!-- end generated -->)", re.S)
VALUE = re.compile(r"(<!-- value: ([^|>]+?)\s*(?:\|\s*([^>]*?)\s*)?-->)(.*?)(<!-- end value -->)")
MARKERS = re.compile(
    r"<!-- (?:generated: \w+|end generated) -->\n?|<!-- (?:value: [^>]*|end value) -->")


def _load(name: str):
    """``docs/NAME.py``, loaded by path (``docs`` is no package)."""
    if str(ROOT) not in sys.path:
        sys.path.insert(0, str(ROOT))  # the tree being documented
    spec = importlib.util.spec_from_file_location(f"jaxflex_docs_{name}",
                                                  Path(__file__).with_name(f"{name}.py"))
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # its dataclasses look their module up
    spec.loader.exec_module(module)
    return module


benchmark_tables = _load("benchmark_tables")
rig_file = _load("rig_file")


def commands() -> str:
    """Each command's ``--help`` under its own heading."""
    from jaxflex.cli import build_parser

    sub = next(a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction))
    columns = os.environ.get("COLUMNS")
    os.environ["COLUMNS"] = HELP_WIDTH  # argparse wraps to the terminal width
    try:
        sections = [
            f"## `jaxflex {name}`\n\n```text\n{parser.format_help()}```\n"
            for name, parser in sub.choices.items()
        ]
    finally:
        if columns is None:
            del os.environ["COLUMNS"]
        else:
            os.environ["COLUMNS"] = columns
    return "\n".join(sections)


def claim_rules() -> str:
    """A table of :data:`jaxflex.discovery.explain.RULES`: claim, what it says, when."""
    from jaxflex.discovery.explain import RULES

    rows = ["| claim | what it says | made only when |", "|---|---|---|"]
    for rule in RULES.values():
        rows.append(f"| `{rule.name}` | {rule.says} | {rule.when} |".replace("\n", " "))
    return "\n".join(rows) + "\n"


BLOCKS: dict[str, Callable[[], str]] = benchmark_tables.TABLES | {
    "commands": commands,
    "claim_rules": claim_rules,
    "rig_file": rig_file.reference,
}
"""Each generated block by its name."""


def regenerate(text: str) -> str:
    """``text`` with every generated block and value written afresh."""
    text = BLOCK.sub(lambda m: m.group(1) + BLOCKS[m.group(2)]() + m.group(4), text)
    return VALUE.sub(lambda m: m.group(1) + benchmark_tables.formatted(
        benchmark_tables.lookup(m.group(2)), m.group(3) or "") + m.group(5), text)


def for_the_site(text: str) -> str:
    """``text`` regenerated, without its markers (for the site's renderer)."""
    return MARKERS.sub("", regenerate(text))


def main(argv: list[str]) -> int:
    stale = []
    for page in PAGES:
        text = page.read_text(encoding="utf-8")
        current = regenerate(text)
        if current != text:
            stale.append(page)
            if "--check" not in argv:
                page.write_text(current, encoding="utf-8")
    if "--check" in argv and stale:
        names = ", ".join(str(p.relative_to(ROOT)) for p in stale)
        print(f"stale generated parts in {names}; run python docs/generated.py")
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
