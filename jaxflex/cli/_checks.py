"""What every command checks before it computes: all of its outputs together, its size, and
its fit files.

:func:`check_outputs` refuses, before any work, an output that cannot be written (a directory,
an existing file without ``--overwrite``, an unsupported suffix, a directory that is not
writable or is a file), two outputs of one command naming the same file, and an output that
is one of the command's inputs. :func:`check_size` refuses a run whose arrays would not fit in
memory or would run for hours: the limit is :data:`DEFAULT_MAX_SAMPLES` samples of the reference
10-element beam, raised with ``--max-samples`` or the environment variable
``JAXFLEX_MAX_SAMPLES``.
"""

from __future__ import annotations

import argparse
import math
import os
from collections.abc import Callable, Iterable, Sequence
from pathlib import Path
from typing import Any

from jaxflex._io import OutputError, check_writable, same_file
from jaxflex.cli import UsageError

DEFAULT_MAX_SAMPLES = 2_000_000
"""Largest run (samples × elements / 10) without asking: 2000 s at 1 kHz (about 2.5 GB by
:func:`memory_estimate`)."""
MAX_SAMPLES_ENV = "JAXFLEX_MAX_SAMPLES"
FIGURE_SUFFIXES = (".png", ".pdf", ".svg")
RECORD_SUFFIXES = (".csv", ".npz")
JSON_SUFFIXES = (".json",)
MAX_SEED = 2**32 - 1

Target = tuple[str, "str | os.PathLike | None", "Sequence[str] | None"]
"""(option, path or None when not given, allowed suffixes or None for any)."""


def check_outputs(
    targets: Iterable[Target], *, overwrite: bool, inputs: Iterable[str | os.PathLike] = ()
) -> list[Path]:
    """Check every output of a command at once; returns their paths (None targets skipped)."""
    inputs = [i for i in inputs if i is not None]
    checked: list[tuple[str, Path]] = []
    for option, path, suffixes in targets:
        if path is None:
            continue
        try:
            p = check_writable(path, overwrite, suffixes=suffixes)
        except OutputError as exc:
            raise UsageError(f"{option} {exc}") from None
        for other_option, other in checked:
            if same_file(p, other):
                raise UsageError(
                    f"{option} {p}: {other_option} writes the same file; give each output its "
                    "own name"
                )
        for source in inputs:
            if same_file(p, source):
                raise UsageError(
                    f"{option} {p}: is an input of this command; write the output elsewhere"
                )
        checked.append((option, p))
    return [p for _, p in checked]


def check_directory(option: str, directory: str | os.PathLike) -> Path:
    """An output directory: may not exist yet, but must not be a file."""
    directory = Path(directory)
    if directory.exists() and not directory.is_dir():
        raise UsageError(f"{option} {directory}: exists and is not a directory")
    return directory


def max_samples(option: int | None = None) -> int:
    """The size limit: ``--max-samples``, else ``$JAXFLEX_MAX_SAMPLES``, else the default."""
    if option is not None:
        return option
    text = os.environ.get(MAX_SAMPLES_ENV)
    if text is None:
        return DEFAULT_MAX_SAMPLES
    try:
        value = int(float(text))
    except ValueError:
        raise UsageError(f"{MAX_SAMPLES_ENV}={text!r} is not a number") from None
    if value < 1:
        raise UsageError(f"{MAX_SAMPLES_ENV}={text!r} must be >= 1")
    return value


def check_size(n_samples: float, what: str, *, n_elements: int = 10, limit: int) -> None:
    """Refuse a run of ``n_samples`` samples of an ``n_elements`` beam above ``limit``."""
    size = float(n_samples) * max(1.0, n_elements / 10)
    if not math.isfinite(size) or size > limit:
        gigabytes = memory_estimate(n_samples, n_elements) / 1e9
        raise UsageError(
            f"{what}: {float(n_samples):.3g} samples of a {n_elements}-element beam is above "
            f"the size limit of {limit:.3g} (about {gigabytes:.3g} GB of memory); raise it with "
            f"--max-samples or {MAX_SAMPLES_ENV} if this is meant"
        )


def memory_estimate(n_samples: float, n_elements: int) -> float:
    """Rough bytes of a simulation: per sample the beam's state (positions and velocities of
    its 2·(n_elements + 1) degrees of freedom) and the outputs, in float64, held about three
    times over (trajectory, derivatives, results)."""
    return 3 * 8 * (4 * n_elements + 12) * float(n_samples)


def add_max_samples(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--max-samples", type=positive_int, metavar="N",
        help=f"size limit, samples x elements/10 (default: ${MAX_SAMPLES_ENV} or "
             f"{DEFAULT_MAX_SAMPLES})",
    )


def _converted(text: str, convert: Callable[[str], Any], kind: str):
    """``convert(text)``, or argparse's error saying what ``text`` is not."""
    try:
        return convert(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not {kind}") from None


def seed(text: str) -> int:
    """argparse type of a random seed: an integer in [0, 2**32 - 1]."""
    value = _converted(text, int, "a whole number")
    if not 0 <= value <= MAX_SEED:
        raise argparse.ArgumentTypeError(f"{text} must lie in [0, {MAX_SEED}]")
    return value


def positive_int(text: str) -> int:
    """argparse type of a count >= 1."""
    value = _converted(text, int, "a whole number")
    if value < 1:
        raise argparse.ArgumentTypeError(f"{text} must be >= 1")
    return value


def positive_float(text: str) -> float:
    """argparse type of a finite number > 0."""
    value = _converted(text, float, "a number")
    if not (math.isfinite(value) and value > 0):
        raise argparse.ArgumentTypeError(f"{text} must be a finite number > 0")
    return value


def read_fit(option: str, path: str | os.PathLike, *, plain_parameters: bool = False):
    """(model, parameters, fit or None) from a fit file, checked field by field against
    :data:`jaxflex.identification.FIT_SCHEMA` before the model is built (its size counts too).

    With ``plain_parameters``, a JSON object mapping parameter names to numbers is a fit of the
    reference model too.
    """
    import json

    from jaxflex.identification import Fit, load_fit
    from jaxflex.model import Model

    path = Path(path)
    if not path.is_file():
        raise UsageError(f"{option} {path}: fit file not found (write one with `jaxflex identify`)")
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (json.JSONDecodeError, UnicodeDecodeError, RecursionError) as exc:
        raise UsageError(f"{option} {path}: not valid JSON ({exc})") from None
    fit: Fit | None = None
    try:
        if plain_parameters and _is_parameter_object(data):
            model, params = Model(), {k: float(v) for k, v in data.items()}
        else:
            fit = load_fit(path)
            model, params = fit.model, fit.params
        model.space.validate(params)  # unknown, missing or out-of-range parameters
    except (ValueError, KeyError, TypeError) as exc:
        message = str(exc.args[0] if isinstance(exc, KeyError) and exc.args else exc)
        message = message.removeprefix(f"{path}: ")
        raise UsageError(f"{option} {path}: cannot use the fit: {message}") from None
    return model, params, fit


def _is_parameter_object(data: object) -> bool:
    return isinstance(data, dict) and bool(data) and all(
        isinstance(v, (int, float)) and not isinstance(v, bool) for v in data.values()
    )


__all__ = [
    "DEFAULT_MAX_SAMPLES", "MAX_SAMPLES_ENV", "add_max_samples", "check_directory",
    "check_outputs", "check_size", "max_samples", "memory_estimate", "positive_float",
    "positive_int", "read_fit", "seed",
]
