"""MkDocs hooks: the API reference must document every public name, its overview table is
generated from ``jaxflex.__all__``, the command-line page shows each command's ``--help``
(generated from the parser), the effects page the rules of discover's claims (from
``jaxflex.discovery.explain.RULES``) and every measured figure comes from its results file
(``docs/benchmark_tables.py``), so that none goes stale.

A public name is one listed in ``__all__`` of ``jaxflex`` or of any public module or subpackage
(or, for a module without ``__all__``, any name it defines without a leading underscore). Each
must be rendered by some ``::: module`` (or ``::: module.name``) block of ``docs/api/``; a
missing one is a warning, so ``mkdocs build --strict`` fails.
"""

from __future__ import annotations

import argparse
import importlib.util
import logging
import os
import re
import sys
from pathlib import Path

import griffe
from mkdocs.structure.files import File

log = logging.getLogger("mkdocs.hooks.jaxflex")
BLOCK = re.compile(r"^:::\s+([\w.]+)", re.M)
NOT_API = "jaxflex.cli"  # the command line has its own page
OVERVIEW_MARKER = "<!-- jaxflex.__all__ -->"
COMMANDS_MARKER = "<!-- commands -->"
RULES_MARKER = "<!-- discover claim rules -->"
HELP_WIDTH = "100"

_package: griffe.Module | None = None


def _load_benchmark_tables():
    """``docs/benchmark_tables.py``, loaded by path (``docs`` is no package)."""
    path = Path(__file__).with_name("benchmark_tables.py")
    spec = importlib.util.spec_from_file_location("jaxflex_docs_benchmark_tables", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


benchmark_tables = _load_benchmark_tables()


def on_config(config):
    global _package
    root = Path(config.config_file_path).parent
    sys.path.insert(0, str(root))  # the tree being documented
    _package = griffe.load(
        "jaxflex",
        search_paths=[str(root)],
        extensions=griffe.load_extensions(str(root / "docs" / "griffe_roles.py")),
    )
    rendered: set[str] = set()
    for page in sorted(Path(config["docs_dir"], "api").glob("*.md")):
        for path in BLOCK.findall(page.read_text(encoding="utf-8")):
            obj = _package[path.removeprefix("jaxflex.")] if path != "jaxflex" else _package
            rendered.add(_canonical(obj))
            if obj.is_module:
                rendered.update(_canonical(m) for m in _public_members(obj))
    for module in _public_modules(_package):
        missing = [m.name for m in _public_members(module) if _canonical(m) not in rendered]
        if missing:
            log.warning(
                f"API reference: {module.path} names {missing} that no ::: block in docs/api/ "
                "renders"
            )
    return config


def on_files(files, config):
    """The figures the benchmarks draw (``benchmarks/results/*.png``) served under ``assets/``,
    so that a page shows the file the benchmark wrote, not a copy."""
    root = Path(config.config_file_path).parent
    for figure in sorted((root / "benchmarks" / "results").glob("*.png")):
        files.append(File.generated(config, f"assets/{figure.name}", abs_src_path=str(figure)))
    return files


def on_page_markdown(markdown, page, config, files):
    if OVERVIEW_MARKER in markdown:
        markdown = markdown.replace(OVERVIEW_MARKER, _overview())
    if COMMANDS_MARKER in markdown:
        markdown = markdown.replace(COMMANDS_MARKER, _commands())
    if RULES_MARKER in markdown:
        markdown = markdown.replace(RULES_MARKER, _claim_rules())
    return benchmark_tables.fill_values(benchmark_tables.fill_tables(markdown))


def _claim_rules() -> str:
    """A table of :data:`jaxflex.discovery.explain.RULES`: claim, what it says, when."""
    from jaxflex.discovery.explain import RULES

    rows = ["| claim | what it says | made only when |", "|---|---|---|"]
    for rule in RULES.values():
        rows.append(f"| `{rule.name}` | {rule.says} | {rule.when} |".replace("\n", " "))
    return "\n".join(rows) + "\n"


def _overview() -> str:
    """A table of ``jaxflex.__all__``: name (linked), defining module, docstring summary."""
    rows = ["| name | defined in | what it is |", "|---|---|---|"]
    for member in _public_members(_package):
        target = _public_path(member)
        docstring = member.final_target.docstring if member.is_alias else member.docstring
        summary = docstring.value.split("\n\n")[0].replace("\n", " ") if docstring else ""
        summary = summary.replace("|", r"\|")
        module = target.rpartition(".")[0]
        rows.append(f"| [`{member.name}`][{target}] | `{module}` | {summary} |")
    return "\n".join(rows) + "\n"


def _commands() -> str:
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


def _public_modules(module: griffe.Module):
    yield module
    for member in module.modules.values():
        if not member.name.startswith("_") and not member.path.startswith(NOT_API):
            yield from _public_modules(member)


def _public_members(module: griffe.Module) -> list[griffe.Object | griffe.Alias]:
    """What mkdocstrings renders for ``module`` (``filters: public``): ``__all__`` if the
    module has one, else the public names it defines (not its imports, not submodules).

    A name of ``__all__`` that griffe sees as a submodule is the function the package
    re-exports under its module's name (``jaxflex.simulation`` → ``jaxflex.simulation.simulate``).
    """
    exports = _export_names(module)
    members = []
    for member in module.members.values():
        if not member.is_public:
            continue
        if member.is_module:
            if member.name in exports and member.name in member.members:
                members.append(member.members[member.name])
            continue
        members.append(member)
    order = {name: i for i, name in enumerate(exports)}
    return sorted(members, key=lambda m: order.get(m.name, len(order)))


def _export_names(module: griffe.Module) -> list[str]:
    return [e if isinstance(e, str) else e.name for e in module.exports or ()]


def _public_path(obj: griffe.Object | griffe.Alias) -> str:
    """The last path along ``obj``'s chain of imports that has no private part: where the
    reference renders it (``jaxflex.AbstractEffect`` → ``jaxflex.effects.AbstractEffect``, not
    ``._base``)."""
    public = obj.path
    while obj.is_alias:
        obj = obj.target
        if not any(part.startswith("_") for part in obj.path.split(".")):
            public = obj.path
    return public


def _canonical(obj: griffe.Object | griffe.Alias) -> str:
    return obj.final_target.path if obj.is_alias else obj.path
