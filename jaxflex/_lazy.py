"""A package's names imported on first use (PEP 562), so that importing the package loads none
of the libraries its modules compute with (the command line's ``--help`` stays fast)."""

from __future__ import annotations

from collections.abc import Mapping, MutableMapping
from typing import Any


def lazy_attribute(package: str, name: str, sources: Mapping[str, tuple[str, str]],
                   namespace: MutableMapping[str, Any]) -> Any:
    """``name`` of ``package``: the attribute ``sources[name] = (module, attribute)``, else the
    submodule ``package.name``; kept in ``namespace`` (the package's globals) once imported."""
    from importlib import import_module
    from importlib.util import find_spec

    if name in sources:
        module, attribute = sources[name]
        value = getattr(import_module(module), attribute)
    elif not name.startswith("__") and find_spec(f"{package}.{name}") is not None:
        value = import_module(f"{package}.{name}")
    else:
        raise AttributeError(f"module {package!r} has no attribute {name!r}")
    namespace[name] = value
    return value
