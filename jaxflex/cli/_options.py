"""The fitting options shared by ``identify``, ``study`` and ``discover``, defined once.

``--effect NAME`` adds a physical effect to the model; ``--bound NAME=LO:HI``, ``--fix
NAME=VALUE``, ``--weight CHANNEL=W`` and ``--noise CHANNEL=SIGMA`` become the ``bounds``,
``fixed``, ``weights`` and ``noise`` keywords of :func:`jaxflex.identification.identify` and
:func:`jaxflex.discovery.discover`. Each repeatable ``NAME=VALUE`` option is one row
of :data:`PAIR_OPTIONS` (a :class:`PairOption`): adding one is one row. :func:`fit_keywords`
passes on only the keywords the called function accepts, and refuses an option given to a
function without it.
"""

from __future__ import annotations

import argparse
import inspect
import math
from collections.abc import Callable
from typing import Any, NamedTuple

from jaxflex.cli import UsageError

INITIAL_STATES = ("rest", "estimate", "periodic")
"""``--initial-state``'s choices: :data:`jaxflex.initial.INITIAL_STATES` (named here, so that
``--help`` loads no JAX)."""
INITIAL_MODES = 2
"""``--initial-modes``'s default: :data:`jaxflex.initial.DEFAULT_MODES`."""
MAX_BOUND_DECADES = 12
"""Widest ``--bound`` (upper/lower) accepted: beyond it candidates overflow the simulation."""


def finite_number(text: str, label: str) -> float:
    """``text`` as a finite float; a UsageError naming ``label`` otherwise."""
    try:
        value = float(text)
    except ValueError:
        raise UsageError(f"{label}: {text!r} is not a number") from None
    if not math.isfinite(value):
        raise UsageError(f"{label}: {text!r} must be finite")
    return value


def _positive(text: str, label: str) -> float:
    value = finite_number(text, label)
    if value <= 0:
        raise UsageError(f"{label}: {text!r} must be > 0")
    return value


def _noise_level(text: str, label: str):
    """A white-noise level (:class:`jaxflex.diagnosis.NoiseLevel`) of standard deviation TEXT."""
    from jaxflex.noise import NoiseLevel

    return NoiseLevel(sigma=_positive(text, label))


def _interval(text: str, label: str) -> tuple[float, float]:
    lo, sep, hi = text.partition(":")
    if not sep:
        raise UsageError(f"{label}={text!r}: expected LO:HI")
    low, high = finite_number(lo, label), finite_number(hi, label)
    if not low < high:
        raise UsageError(f"{label}={text}: lower bound {low!r} must be below upper {high!r}")
    decades = math.log10(high) - math.log10(low) if low > 0 else 0.0
    if decades > MAX_BOUND_DECADES:
        raise UsageError(
            f"{label}={text}: spans {decades:.0f} decades; a search box wider "
            f"than {MAX_BOUND_DECADES} decades leaves the simulation's range; narrow it"
        )
    return low, high


class PairOption(NamedTuple):
    """A repeatable ``--option NAME=VALUE`` that becomes the mapping ``keyword``."""

    option: str
    keyword: str
    metavar: str
    help: str
    parse: Callable[[str, str], Any]  # (value text, label for messages) -> value


PAIR_OPTIONS: tuple[PairOption, ...] = (
    PairOption("--bound", "bounds", "NAME=LO:HI",
               "search bounds of a parameter (repeatable), e.g. J_h=1e-3:1e-2", _interval),
    PairOption("--fix", "fixed", "NAME=VALUE", "hold a parameter at a value (repeatable)",
               finite_number),
    PairOption("--weight", "weights", "CHANNEL=W",
               "weight of an output channel (repeatable; default 1 each)", finite_number),
    PairOption("--noise", "noise", "CHANNEL=SIGMA",
               "noise standard deviation of a channel, in its unit (repeatable; default: "
               "estimated from the records)", _noise_level),
)


def add_effect_option(p: argparse.ArgumentParser) -> None:
    """``--effect NAME``: the model holds this effect (every command that builds a model)."""
    p.add_argument("--effect", action="append", default=[], metavar="NAME",
                   help="add a physical effect to the model (repeatable), e.g. payload")


def add_renamed_option(p: argparse.ArgumentParser, old: str, new: str) -> None:
    """A hidden ``old`` option that fails with one line naming the option that replaced it."""

    class Renamed(argparse.Action):
        def __call__(self, parser, namespace, values, option_string=None):
            parser.error(f"{old} is now {new}")

    p.add_argument(old, nargs="?", action=Renamed, help=argparse.SUPPRESS)


def add_fit_options(p: argparse.ArgumentParser) -> None:
    """``--effect`` and the :data:`PAIR_OPTIONS` on a command's parser."""
    add_effect_option(p)
    for o in PAIR_OPTIONS:
        p.add_argument(o.option, dest=f"pairs_{o.keyword}", action="append", default=[],
                       metavar=o.metavar, help=o.help)
    add_initial_state_options(p)


def add_initial_state_options(p: argparse.ArgumentParser, held_out: bool = False) -> None:
    """``--initial-state`` and ``--initial-modes``: where each record's simulation starts
    (:mod:`jaxflex.initial`)."""
    which = "held-out records (fitted ones start where the fit found them)" if held_out else (
        "records")
    p.add_argument("--initial-state", choices=INITIAL_STATES, default="rest",
                   help=f"where the {which} start: at rest, at a state estimated with the "
                        "parameters, or in the periodic steady state of a periodic input "
                        "(default: %(default)s)")
    p.add_argument("--initial-modes", type=_whole, default=INITIAL_MODES, metavar="K",
                   help="flexible modes whose coordinates an estimated or periodic start sets, "
                        "the lowest ones (default: %(default)s)")


def _whole(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a whole number") from None
    if value < 0:
        raise argparse.ArgumentTypeError(f"{text!r} must be >= 0")
    return value


def effects_from(names: list[str], option: str = "--effect") -> tuple:
    """The named effects (an unknown name names the option)."""
    from jaxflex.effects import get_effect

    added = []
    for name in names:
        try:
            added.append(get_effect(name))
        except (KeyError, ValueError) as exc:
            message = exc.args[0] if exc.args else exc
            raise UsageError(f"{option} {name}: {message}") from None
    return tuple(added)



def pair_values(args: argparse.Namespace) -> dict[str, dict[str, Any]]:
    """``{keyword: {name: value}}`` for every pair option given (empty ones left out)."""
    out: dict[str, dict[str, Any]] = {}
    for o in PAIR_OPTIONS:
        values: dict[str, Any] = {}
        for item in getattr(args, f"pairs_{o.keyword}"):
            name, sep, text = (s.strip() for s in item.partition("="))
            if not sep or not name or not text:
                raise UsageError(f"{o.option} {item!r}: expected {o.metavar}")
            if name in values:
                raise UsageError(f"{o.option}: {name!r} given twice")
            values[name] = o.parse(text, f"{o.option} {name}")
        if values:
            out[o.keyword] = values
    return out


def fit_keywords(args: argparse.Namespace, function: Callable) -> dict[str, Any]:
    """The keywords of ``function`` given by the fitting options; an option the function does
    not take is refused by name."""
    accepted = inspect.signature(function).parameters
    keywords = pair_values(args)
    for o in PAIR_OPTIONS:
        if o.keyword in keywords and o.keyword not in accepted:
            raise UsageError(f"{o.option} is not supported by this command yet")
    if getattr(args, "initial_state", "rest") != "rest":
        if "initial_state" not in accepted:
            raise UsageError("--initial-state is not supported by this command yet")
        keywords |= {"initial_state": args.initial_state, "initial_modes": args.initial_modes}
    return {k: v for k, v in keywords.items() if k in accepted}




def add_quiet_option(p: argparse.ArgumentParser) -> None:
    """``--quiet``: no progress output. Without it a long command shows its progress on stderr
    by the rule of :mod:`jaxflex._progress`: a bar on a terminal, a line per stage otherwise."""
    p.add_argument("--quiet", action="store_true",
                   help="no progress output (default: a bar on a terminal, else a line per "
                        "stage, on stderr)")


def add_record_options(p: argparse.ArgumentParser) -> None:
    """How records are read: ``--resample`` and ``--no-unit-check``."""
    p.add_argument("--resample", action="store_true",
                   help="resample records whose time column is not uniform")
    p.add_argument("--no-unit-check", dest="unit_check", action="store_false",
                   help="load records whose units look wrong (time in ms, angle in degrees, "
                        "torque scale) instead of stopping")


__all__ = [
    "PAIR_OPTIONS", "PairOption", "add_effect_option", "add_fit_options",
    "add_initial_state_options", "add_quiet_option", "add_record_options", "add_renamed_option",
    "effects_from", "finite_number", "fit_keywords", "pair_values",
]
