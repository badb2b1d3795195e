"""Checks of scalar arguments shared by the modules that read and process records: each failure
is one line naming the argument and the value given."""

from __future__ import annotations

import math


def finite_float(value: object, name: str, *, minimum: float | None = None,
                 strict: bool = False) -> float:
    """``value`` as a finite float, optionally ``>= minimum`` (``> minimum`` if ``strict``).

    The error message names the argument ``name``.
    """
    try:
        x = float(value)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        raise ValueError(f"{name}={value!r} must be a number") from None
    if not math.isfinite(x):
        raise ValueError(f"{name}={value!r} must be finite")
    if minimum is not None and (x <= minimum if strict else x < minimum):
        raise ValueError(f"{name}={value!r} must be {'>' if strict else '>='} {minimum!r}")
    return x


def positive(value: object, name: str) -> float:
    """``value`` as a finite float above zero; the error message names the argument ``name``."""
    return finite_float(value, name, minimum=0.0, strict=True)


def shown(value: object) -> str:
    """``value`` as an error message shows a wrong argument: ``123 (int)``, ``None``."""
    return "None" if value is None else f"{value!r} ({type(value).__name__})"


def raised(exc: BaseException, limit: int = 300) -> str:
    """An exception as one line of an error message: ``TypeError: words`` with its whitespace
    collapsed and cut to ``limit`` characters (JAX's own messages run over many lines)."""
    words = " ".join(str(exc).split())
    shown_words = words if len(words) <= limit else words[: limit - 3] + "..."
    return f"{type(exc).__name__}: {shown_words}"
