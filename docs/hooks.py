"""MkDocs hooks: the API reference must document every public name; the command-line page
shows each command's ``--help``, generated from the parser so that it never goes stale.

A public name is one listed in ``__all__`` of ``jaxflex`` or of any public module or subpackage
(or, for a module without ``__all__``, any name it defines without a leading underscore). Each
must be rendered by some ``::: module`` (or ``::: module.name``) block of ``docs/api/``; a
missing one is a warning, so ``mkdocs build --strict`` fails.
"""

from __future__ import annotations

import argparse
import importlib
import inspect
import logging
import os
import pkgutil
import re
import sys
from pathlib import Path

log = logging.getLogger("mkdocs.hooks.api_coverage")
BLOCK = re.compile(r"^:::\s+([\w.]+)", re.M)
NOT_API = ("jaxflex.cli",)  # the command line has its own page
COMMANDS_MARKER = "<!-- commands -->"
HELP_WIDTH = "100"


def on_config(config):
    sys.path.insert(0, str(Path(config.config_file_path).parent))  # the tree being documented
    documented = set()
    for page in sorted(Path(config["docs_dir"], "api").glob("*.md")):
        documented.update(BLOCK.findall(page.read_text(encoding="utf-8")))
    rendered: set[int] = set()
    for path in documented:
        try:
            rendered.update(id(obj) for obj in _public(importlib.import_module(path)).values())
        except ModuleNotFoundError:  # one object: module.name
            module, _, name = path.rpartition(".")
            rendered.add(id(getattr(importlib.import_module(module), name)))
    for module in _public_modules():
        missing = [n for n, obj in _public(module).items() if id(obj) not in rendered]
        if missing:
            log.warning(
                f"API reference: {module.__name__} names {missing} that no ::: block in "
                "docs/api/ renders"
            )
    return config


def _public_modules():
    package = importlib.import_module("jaxflex")
    yield package
    for info in pkgutil.walk_packages(package.__path__, "jaxflex."):
        parts = info.name.split(".")
        if any(p.startswith("_") for p in parts) or info.name.startswith(NOT_API):
            continue
        yield importlib.import_module(info.name)


def _public(module) -> dict[str, object]:
    """The names a reader of ``module`` may use: ``__all__``, else its own public definitions."""
    names = getattr(module, "__all__", None)
    if names is not None:
        return {n: getattr(module, n) for n in names}
    return {
        n: obj
        for n, obj in list(vars(module).items())
        if not n.startswith("_")
        and not inspect.ismodule(obj)
        and getattr(obj, "__module__", module.__name__) == module.__name__
    }


def on_page_markdown(markdown, page, config, files):
    if COMMANDS_MARKER not in markdown:
        return markdown
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
    return markdown.replace(COMMANDS_MARKER, "\n".join(sections))
