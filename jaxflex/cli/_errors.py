"""The one place that turns an exception or a warning into the one line a command-line user
reads.

Library messages speak Python (``overwrite=True``, ``t_end=``); :func:`describe` rewrites them
in the command line's words and adds the remedy for operating-system and size errors;
:func:`one_line_warning` writes every warning as ``jaxflex COMMAND: warning: …``, those of the
libraries jaxflex computes with said in what they mean for the run (:func:`in_our_words`).
"""

from __future__ import annotations

import errno
import re
import sys

_API_TO_CLI: tuple[tuple[str, str], ...] = (
    (r"pass overwrite=True \(CLI: --overwrite\)", "pass --overwrite"),
    (r"overwrite=True", "--overwrite"),
    (r"pass resample=True", "pass --resample"),
    (r"resample=True", "--resample"),
    (r"unit_check=False", "--no-unit-check"),
    (r"\bt_end=", "--t-end "),
    (r"\bf_max=", "--f-max "),
    (r"\bmax_torque=", "--max-torque "),
    (r"\brms_torque=", "--rms-torque "),
    (r"\bmax_angle=", "--max-angle "),
    (r"\bmax_speed=", "--max-speed "),
    (r"\bmax_frequency=", "--max-frequency "),
    (r"\bharmonics=", "--harmonics "),
    (r"\biterations=", "--iterations "),
    (r"\brefine_starts=", "--refine-starts "),
    (r"\bdisturbance=", "--disturbance "),
    (r"^weights given for", "--weight given for"),
    (r"^fixed value (\w+=)", r"--fix \1"),
    (r"^amplitude must", "--amplitude must"),
)

_REMEDY = {
    errno.EACCES: "check the permissions of the file and its directory",
    errno.EPERM: "check the permissions of the file and its directory",
    errno.ENOSPC: "free some disk space or write elsewhere",
    errno.EDQUOT: "free some disk space or write elsewhere",
    errno.EROFS: "the file system is read-only; write elsewhere",
    errno.ENOENT: "check the path",
    errno.EISDIR: "give a file name, not a directory",
    errno.ENOTDIR: "a part of the path is a file, not a directory",
    errno.ENAMETOOLONG: "use a shorter name",
}


def cli_words(message: str) -> str:
    """``message`` with the Python API's argument names replaced by the options' names."""
    for pattern, replacement in _API_TO_CLI:
        message = re.sub(pattern, replacement, message)
    return " ".join(message.split())  # one line


def describe(exc: BaseException) -> tuple[str, int]:
    """(one-line message, exit status) for an exception raised by a command."""
    from jaxflex.cli import EXIT_BUG, EXIT_USAGE

    if isinstance(exc, OSError) and not _is_jaxflex_message(exc):
        where = exc.filename if exc.filename is not None else "file"
        reason = exc.strerror or str(exc)
        remedy = _REMEDY.get(exc.errno or -1)
        return cli_words(f"{where}: {reason}" + (f"; {remedy}" if remedy else "")), EXIT_USAGE
    if isinstance(exc, MemoryError):
        return (
            "out of memory; use shorter records or a shorter --duration, a larger --dt, or "
            "fewer beam elements",
            EXIT_USAGE,
        )
    if isinstance(exc, (ValueError, KeyError, OSError, OverflowError)):
        text = exc.args[0] if isinstance(exc, KeyError) and exc.args else exc
        return cli_words(str(text)), EXIT_USAGE
    return (
        f"internal error ({type(exc).__name__}: {cli_words(str(exc))}); please report it, "
        "with the command line; --debug shows the traceback",
        EXIT_BUG,
    )


def _is_jaxflex_message(exc: OSError) -> bool:
    """Our own OSError subclasses (e.g. an existing output file) carry a complete message."""
    from jaxflex._io import OutputError

    return isinstance(exc, OutputError) or (exc.errno is None and exc.filename is None)


def one_line_warning(prefix: str):
    """A :func:`warnings.formatwarning` replacement: ``PREFIX: warning: message``, one line, no
    source line (the user did not write the library)."""

    def format_warning(message, category, filename, lineno, line=None) -> str:
        return f"{prefix}: warning: {cli_words(in_our_words(str(message)))}\n"

    return format_warning


def in_our_words(message: str) -> str:
    """``message`` with the words of a library jaxflex computes with replaced by what they mean
    for the run: optimistix's result messages (:func:`jaxflex.least_squares.in_fit_words`;
    only a run that loaded optimistix can meet them)."""
    if "optimistix" in sys.modules:
        from jaxflex.least_squares import in_fit_words

        message = in_fit_words(message)
    return message


__all__ = ["cli_words", "describe", "in_our_words", "one_line_warning"]
