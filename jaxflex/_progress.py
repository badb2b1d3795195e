"""Progress of long loops (generations, seeds, design iterations, discovery steps), one rule.

Progress is shown only when the caller asks for it (``progress=True`` in the public functions;
on the command line, unless ``--quiet``), and then :func:`progress_mode` decides how:

- in a terminal or in Jupyter, a bar through ``tqdm.auto`` (a widget in Jupyter, a text bar on
  stderr in a terminal);
- otherwise (stderr redirected to a file or a pipe: a log, CI), one line on stderr per finished
  stage (:class:`Progress` loops and :func:`stage` lines), never a bar's carriage returns;
- ``JAXFLEX_PROGRESS=1`` forces the bar, ``JAXFLEX_PROGRESS=0`` silences everything (it keeps
  CI logs and test output quiet).
"""

from __future__ import annotations

import os
import sys
import time
from collections.abc import Iterable, Iterator
from typing import Generic, Literal, TextIO, TypeVar

from tqdm import std
from tqdm.auto import tqdm

T = TypeVar("T")

ENVIRONMENT_SWITCH = "JAXFLEX_PROGRESS"
"""Environment variable: ``1`` (``true``, ``yes``, ``on``) forces bars, ``0`` (``false``,
``no``, ``off``) turns all progress output off; unset, the stream decides."""
_ON = {"1", "true", "yes", "on"}
_OFF = {"0", "false", "no", "off"}

Mode = Literal["bar", "lines", "off"]


def progress_mode(enabled: bool = True, stream: TextIO | None = None) -> Mode:
    """How progress the caller asked for (``enabled``) is shown on ``stream`` (stderr): a
    ``"bar"`` on a terminal or in Jupyter, ``"lines"`` elsewhere, ``"off"`` when not asked for;
    ``JAXFLEX_PROGRESS`` overrides the stream's choice."""
    if not enabled:
        return "off"
    value = os.environ.get(ENVIRONMENT_SWITCH, "").strip().lower()
    if value in _OFF:
        return "off"
    if value in _ON or _interactive(sys.stderr if stream is None else stream):
        return "bar"
    return "lines"


def _interactive(stream: TextIO) -> bool:
    """True on a terminal, and in a Jupyter kernel (where ``tqdm.auto`` draws a widget)."""
    try:
        if stream.isatty():
            return True
    except (AttributeError, ValueError):  # no isatty, or a closed stream
        pass
    ipython = sys.modules.get("IPython")
    shell = ipython.get_ipython() if ipython is not None else None
    return shell is not None and "IPKernelApp" in getattr(shell, "config", {})


def stage(message: str, enabled: bool = True) -> None:
    """One line on stderr saying a stage is done, when progress is shown (above a running bar,
    which it does not break)."""
    mode = progress_mode(enabled)
    if mode == "bar":
        std.tqdm.write(message, file=sys.stderr)
    elif mode == "lines":
        print(message, file=sys.stderr, flush=True)


class Progress(Generic[T]):
    """Wrap an iterable: a ``tqdm.auto`` bar labelled ``label``, or lines (:func:`progress_mode`).

    ``enabled=False`` makes it a plain pass-through. Call :meth:`set_message` after each item to
    show e.g. the best cost so far as the bar's postfix. As lines, the loop writes one line when
    it ends (``label: done/total in T s, message``). With ``each_stage``, each item is a stage of
    its own (a run of a study, a discovery step): :meth:`set_message` reports it done, as one
    line of its own, so a loop that stops early counts the item it stopped at.
    """

    def __init__(
        self,
        iterable: Iterable[T],
        *,
        total: int | None = None,
        label: str = "",
        enabled: bool = True,
        each_stage: bool = False,
    ) -> None:
        self.mode = progress_mode(enabled)
        self._iterable = iterable
        self._label = label
        self._total = total if total is not None else _length(iterable)
        self._each_stage = each_stage
        self._message = ""
        self._done = 0
        self._counted = True
        self._bar = None
        if self.mode == "bar":
            options = {"total": self._total, "desc": label or None, "dynamic_ncols": True}
            try:
                self._bar = tqdm(**options)
            except ImportError:  # Jupyter without ipywidgets: no widget, a text bar instead
                self._bar = std.tqdm(**options)

    @property
    def enabled(self) -> bool:
        return self.mode != "off"

    def set_message(self, message: str) -> None:
        """Show ``message`` after the bar (refreshed with the bar's own rate limit); with
        ``each_stage``, report the current item done with it."""
        self._message = message
        if self._bar is not None:
            self._bar.set_postfix_str(message, refresh=False)
        if self._each_stage:
            if self.mode == "lines":
                print(f"{self._label} {self._done + 1}{self._of()}: {message}", file=sys.stderr,
                      flush=True)
            self._count()

    def __iter__(self) -> Iterator[T]:
        start = time.perf_counter()
        try:
            for item in self._iterable:
                self._counted = False
                yield item
                self._count()
        finally:
            if self._bar is not None:
                self._bar.close()
            elif self.mode == "lines":
                seconds = time.perf_counter() - start
                line = f"{self._label}: {self._done}{self._of()} in {seconds:.1f} s"
                if self._message and not self._each_stage:
                    line += f", {self._message}"
                print(line, file=sys.stderr, flush=True)

    def _count(self) -> None:
        """The current item is done (once)."""
        if not self._counted:
            self._counted = True
            self._done += 1
            if self._bar is not None:
                self._bar.update(1)

    def _of(self) -> str:
        return "" if self._total is None else f"/{self._total}"


def _length(iterable: Iterable) -> int | None:
    try:
        return len(iterable)  # type: ignore[arg-type]
    except TypeError:
        return None
