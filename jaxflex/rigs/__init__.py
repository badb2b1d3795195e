"""The arm files that ship with jaxflex, by name: ``jaxflex.load_arm("quanser_rotflex")``.

Each packaged rig is one arm file here, ``jaxflex/rigs/<name>.toml`` (see :mod:`jaxflex.arm`
for the format), installed with the package so that a rig can be named wherever an arm file can
be given. ``jaxflex arms list`` lists them and ``jaxflex arms show NAME > my_rig.toml`` starts a
file of one's own from one of them.

A value given for an arm (:func:`locate`) is a path when it has a path separator or ends in
``.toml``, or when it is an existing file whose name no packaged rig has; anything else names a
packaged rig. A packaged rig's bare name means the packaged rig even beside a file of that name
(a warning says so, and how to read the file: ``./NAME``).
"""

from __future__ import annotations

import difflib
import os
from importlib import resources
from pathlib import Path

from jaxflex.arm import ArmError

SUFFIX = ".toml"
"""The ending of an arm file's name."""


def packaged_arms() -> tuple[str, ...]:
    """The names of the packaged arm files, sorted."""
    folder = resources.files(__name__)
    return tuple(sorted(
        p.name.removesuffix(SUFFIX) for p in folder.iterdir() if p.name.endswith(SUFFIX)
    ))


def arm_path(name: str) -> Path:
    """The file of the packaged arm ``name``; an unknown name is an :class:`ArmError` that
    lists the packaged ones."""
    if name not in packaged_arms():
        raise _unknown(name, "no packaged arm of that name")
    return Path(str(resources.files(__name__) / f"{name}{SUFFIX}"))


def is_arm_name(value: str | os.PathLike) -> bool:
    """Whether ``value`` names a packaged arm rather than a file: it has no path separator,
    does not end in ``.toml``, and is a packaged arm's name or no existing file."""
    text = os.fspath(value)
    separators = {os.sep, os.altsep or os.sep, "/"}
    return (not any(s in text for s in separators) and not text.lower().endswith(SUFFIX)
            and (text in packaged_arms() or not os.path.isfile(text)))


def locate(value: str | os.PathLike) -> Path:
    """The arm file ``value`` stands for: a packaged arm's file for a name, else the path."""
    if not is_arm_name(value):
        return Path(value)
    name = os.fspath(value)
    if name in packaged_arms() and os.path.isfile(name):
        import warnings

        warnings.warn(f"{name}: the packaged rig of that name, not the file {name} in this "
                      f"folder; write ./{name} to read the file", stacklevel=2)
    if name not in packaged_arms():
        raise _unknown(name, "neither an arm file nor a packaged arm",
                       f"; a file's path needs a '/' or the suffix {SUFFIX}")
    return arm_path(name)


def _unknown(name: str, what: str, note: str = "") -> ArmError:
    """One line: ``name`` is ``what``, the closest packaged name, and every packaged name."""
    known = packaged_arms()
    close = difflib.get_close_matches(name, known, n=1, cutoff=0.6)
    hint = f" (did you mean {close[0]!r}?)" if close else ""
    return ArmError(f"{name}: {what}{hint}; packaged arms: {', '.join(known)}{note}")


__all__ = ["arm_path", "is_arm_name", "locate", "packaged_arms"]
