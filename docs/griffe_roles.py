"""Griffe extension: the docstrings' reST roles (``:func:`x```) as Markdown for mkdocstrings,
and ``#:`` comments above a module constant as its docstring (the Sphinx convention).

jaxflex's docstrings name other objects with Sphinx roles, which Markdown would show verbatim.
A role whose target is a jaxflex object the API reference renders becomes a cross-reference to
its entry (resolved from the docstring's own scope, as Sphinx would); any other target
(another library's object, a private helper, a name outside its module's ``__all__``) becomes
inline code.
"""

from __future__ import annotations

import re

import griffe

ROLE = re.compile(r":(?:func|class|meth|mod|data|attr|obj|exc):`~?([^`]+)`")


SHOWN_SPECIAL = {"__call__"}
"""Special methods the reference shows; the others (``__repr__``, ``__len__``, ...) are
implementation detail for a reader of the API."""


class RestRoles(griffe.Extension):
    """Rewrite the roles of every docstring in the package once it is loaded, and hide special
    methods from the reference."""

    def on_package(self, *, pkg: griffe.Module, **kwargs: object) -> None:
        for obj in _walk(pkg):
            if obj.is_attribute and obj.docstring is None and obj.parent.is_module:
                comment = _comment_docstring(obj)
                if comment:
                    obj.docstring = griffe.Docstring(comment, parent=obj)
            if obj.name.startswith("__") and obj.name.endswith("__") and obj.parent is not None:
                if obj.parent.is_class and obj.name not in SHOWN_SPECIAL:
                    obj.public = False
            if obj.docstring is not None:
                obj.docstring.value = ROLE.sub(
                    lambda m, obj=obj: _reference(obj, pkg, m.group(1)), obj.docstring.value
                )


def _comment_docstring(obj: griffe.Object) -> str:
    """The ``#:`` comment lines right above ``obj``'s assignment, joined."""
    lines = obj.parent.lines
    text: list[str] = []
    row = obj.lineno - 2  # the line above, 0-based
    while row >= 0 and lines[row].strip().startswith("#:"):
        text.insert(0, lines[row].strip()[2:].strip())
        row -= 1
    return " ".join(text)


def _walk(obj: griffe.Object):
    yield obj
    for member in obj.members.values():
        if not member.is_alias:
            yield from _walk(member)


def _reference(obj: griffe.Object, pkg: griffe.Module, target: str) -> str:
    path = _public_path(obj, pkg, target)
    return f"[`{target}`][{path}]" if path else f"`{target}`"


def _public_path(obj: griffe.Object, pkg: griffe.Module, target: str) -> str | None:
    """The canonical path of ``target`` as seen from ``obj`` if it is public jaxflex API."""
    head, _, rest = target.partition(".")
    if head == pkg.name:
        candidates = [target]
    else:
        candidates = []
        for scope in (obj, obj.parent, obj.module):
            if scope is None:
                continue
            try:
                candidates.append(scope.resolve(head) + (f".{rest}" if rest else ""))
            except (griffe.NameResolutionError, AttributeError, KeyError):
                continue
    for path in candidates:
        found = _lookup(pkg, path)
        if found is not None:
            return found
    return None


def _lookup(pkg: griffe.Module, path: str) -> str | None:
    if not path.startswith(pkg.name + "."):
        return None
    try:
        found = pkg[path[len(pkg.name) + 1 :]]
        if found.is_alias:
            found = found.final_target
    except (KeyError, griffe.AliasResolutionError, griffe.CyclicAliasError):
        return None
    if any(part.startswith("_") for part in found.path.split(".")) or not _exported(found):
        return None
    return found.path


def _exported(obj: griffe.Object) -> bool:
    """Whether the API reference renders ``obj``: every module on its path that declares
    ``__all__`` lists the next name (mkdocstrings' ``filters: public``)."""
    child, parent = obj, obj.parent
    while parent is not None:
        exports = parent.exports if parent.is_module else None
        if exports is not None:
            names = {e if isinstance(e, str) else getattr(e, "name", str(e)) for e in exports}
            if child.name not in names:
                return False
        child, parent = parent, parent.parent
    return True
