"""Progress of long loops (generations, seeds, design iterations) through ``tqdm.auto``.

In Jupyter the bar is a widget (a text bar if ipywidgets is missing), in a terminal a text bar
on stderr. It is off unless the caller asks for it (``progress=True`` in the public functions),
and ``JAXFLEX_PROGRESS=0`` in the environment turns every bar off, which keeps CI logs and test
output quiet.
"""

from __future__ import annotations

import os
from collections.abc import Iterable, Iterator
from typing import Generic, TypeVar

from tqdm import std
from tqdm.auto import tqdm

T = TypeVar("T")

ENVIRONMENT_SWITCH = "JAXFLEX_PROGRESS"
"""Environment variable: ``0`` (or ``false``, ``no``, ``off``) turns all progress bars off."""


def progress_allowed() -> bool:
    """False when ``JAXFLEX_PROGRESS`` says off (``0``, ``false``, ``no``, ``off``)."""
    value = os.environ.get(ENVIRONMENT_SWITCH, "1").strip().lower()
    return value not in {"0", "false", "no", "off"}


class Progress(Generic[T]):
    """Wrap an iterable with a ``tqdm.auto`` bar labelled ``label``.

    ``enabled=False`` (or ``JAXFLEX_PROGRESS=0``) makes it a plain pass-through. Call
    :meth:`set_message` after each item to show e.g. the best cost so far as the bar's postfix.
    """

    def __init__(
        self,
        iterable: Iterable[T],
        *,
        total: int | None = None,
        label: str = "",
        enabled: bool = True,
    ) -> None:
        options = {
            "total": total,
            "desc": label or None,
            "disable": not (enabled and progress_allowed()),
            "dynamic_ncols": True,
        }
        try:
            self._bar = tqdm(iterable, **options)
        except ImportError:  # Jupyter without ipywidgets: no widget, a text bar instead
            self._bar = std.tqdm(iterable, **options)

    @property
    def enabled(self) -> bool:
        return not self._bar.disable

    def set_message(self, message: str) -> None:
        """Show ``message`` after the bar (refreshed with the bar's own rate limit)."""
        if self.enabled:
            self._bar.set_postfix_str(message, refresh=False)

    def __iter__(self) -> Iterator[T]:
        try:
            yield from self._bar
        finally:
            self._bar.close()
