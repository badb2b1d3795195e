"""A minimal progress bar for long loops (generations, seeds), written to stderr."""

from __future__ import annotations

import sys
import time
from collections.abc import Iterable, Iterator
from typing import TypeVar

T = TypeVar("T")


class Progress:
    """Wrap an iterable and redraw one status line per item: ``label  37/100 [####  ] 2.1s  msg``.

    Silent when ``enabled`` is false or stderr is not a terminal and ``force`` is not set, so
    tests and notebooks stay quiet; call :meth:`set_message` to show e.g. the best objective.
    """

    def __init__(
        self,
        iterable: Iterable[T],
        *,
        total: int | None = None,
        label: str = "",
        enabled: bool = True,
        force: bool = False,
        width: int = 24,
    ) -> None:
        self._iterable = iterable
        self._total = total if total is not None else _length(iterable)
        self._label = label
        self._enabled = enabled and (force or sys.stderr.isatty())
        self._width = width
        self._message = ""

    def set_message(self, message: str) -> None:
        self._message = message

    def __iter__(self) -> Iterator[T]:
        start = time.perf_counter()
        count = 0
        for item in self._iterable:
            yield item
            count += 1
            if self._enabled:
                self._draw(count, time.perf_counter() - start)
        if self._enabled:
            sys.stderr.write("\n")
            sys.stderr.flush()

    def _draw(self, count: int, elapsed: float) -> None:
        if self._total:
            filled = int(self._width * count / self._total)
            bar = "#" * filled + " " * (self._width - filled)
            where = f"{count}/{self._total} [{bar}]"
        else:
            where = f"{count}"
        sys.stderr.write(f"\r{self._label} {where} {elapsed:6.1f}s {self._message}\x1b[K")
        sys.stderr.flush()


def _length(iterable: Iterable) -> int | None:
    try:
        return len(iterable)  # type: ignore[arg-type]
    except TypeError:
        return None
