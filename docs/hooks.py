"""MkDocs hooks: the API reference must document every public name, its overview table is
generated from ``jaxflex.__all__``, and the generated parts of every page (each command's
``--help``, the rules of discover's claims, the rig-file reference, every measured figure:
``docs/generated.py``) are filled afresh and their markers dropped, so that none goes stale.

A public name is one listed in ``__all__`` of ``jaxflex`` or of any public module or subpackage
(or, for a module without ``__all__``, any name it defines without a leading underscore). Each
must be rendered by some ``::: module`` (or ``::: module.name``) block of ``docs/api/``; a
missing one is a warning, so ``mkdocs build --strict`` fails.
"""

from __future__ import annotations

import importlib.util
import logging
import re
import sys
from pathlib import Path

import griffe
from mkdocs.structure.files import File

log = logging.getLogger("mkdocs.hooks.jaxflex")
BLOCK = re.compile(r"^:::\s+([\w.]+)", re.M)
NOT_API = "jaxflex.cli"  # the command line has its own page
OVERVIEW_MARKER = "<!-- jaxflex.__all__ -->"

_package: griffe.Module | None = None


def _load_generated():
    """``docs/generated.py``, loaded by path (``docs`` is no package)."""
    path = Path(__file__).with_name("generated.py")
    spec = importlib.util.spec_from_file_location("jaxflex_docs_generated", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


generated = _load_generated()


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
    return generated.for_the_site(markdown)


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
