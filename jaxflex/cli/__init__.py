"""The ``jaxflex`` command: one sub-command per workflow stage, each in its own module.

Each module in :data:`COMMANDS` defines ``register(subparsers)``, which adds its parser and
sets ``func`` to the function that runs it. Every command checks its inputs and all of its
outputs before it computes anything (:mod:`jaxflex.cli._checks`); :func:`main` turns every
error a user can meet — bad files or values, permissions, full disks, sizes — into one line
``jaxflex <command>: error: …`` with exit status 2, never a traceback (``--debug`` shows one),
and every warning into one line ``jaxflex <command>: warning: …``.
Ctrl-C and SIGTERM stop with one line and exit status 130 and 143, leaving no partial or
temporary file.
"""

from __future__ import annotations

import argparse
import importlib
import signal
import sys
import warnings
from collections.abc import Sequence

COMMANDS: tuple[str, ...] = (
    "simulate",
    "identify",
    "study",
    "validate",
    "torque_map",
    "discover",
    "design",
    "demo",
    "datasets",
    "arms",
)
"""The sub-commands of ``jaxflex`` by module, in the order the help lists them (a command is
named as its module, ``-`` for ``_``: ``torque_map`` is ``jaxflex torque-map``)."""
EXIT_OK, EXIT_BUG, EXIT_USAGE, EXIT_INTERRUPTED, EXIT_TERMINATED = 0, 1, 2, 130, 143
"""Exit codes: success, an internal error, bad input or options, Ctrl-C (SIGINT), SIGTERM."""


class UsageError(ValueError):
    """A problem with the command line or its input files that the user can fix."""


def load_records(paths: Sequence[str], *, resample: bool, unit_check: bool = True,
                 channels: Sequence[str] = (), drive: str | None = None):
    """Records from files and directories, each file once (``channels``: a rig's sensor
    channels, ``drive`` its input column, :func:`jaxflex.data.load_record`); problems are
    UsageErrors."""
    from pathlib import Path

    from jaxflex._io import same_file
    from jaxflex.data import Dataset, RecordError, load_dataset, load_record

    records = []
    try:
        for name in paths:
            path = Path(name)
            if not path.exists():
                raise UsageError(f"{path}: record file not found")
            if path.is_dir():
                records += list(load_dataset(path, resample=resample, unit_check=unit_check,
                                             channels=channels, drive=drive))
            else:
                records.append(load_record(path, resample=resample, unit_check=unit_check,
                                           channels=channels, drive=drive))
        for i, r in enumerate(records):
            for earlier in records[:i]:
                if same_file(r.source, earlier.source):
                    raise UsageError(f"{r.source}: record file given twice")
                if r.name == earlier.name:
                    raise UsageError(
                        f"{earlier.source} and {r.source}: two records named {r.name!r}; "
                        "rename one of the files"
                    )
        return Dataset(records)
    except RecordError as exc:
        raise UsageError(str(exc)) from None


class _CommandParser(argparse.ArgumentParser):
    """A sub-command's parser: an argument it does not know is its error, answered under its
    own usage (argparse would leave it to the top-level parser and its usage)."""

    def parse_known_args(self, args=None, namespace=None):
        namespace, extras = super().parse_known_args(args, namespace)
        if extras:
            self.error(f"unrecognized arguments: {' '.join(extras)}")
        return namespace, extras


def build_parser() -> argparse.ArgumentParser:
    """The parser of every command; building it imports no JAX (each command imports what it
    computes with when it runs), so ``--help`` and ``--version`` answer at once."""
    from jaxflex import __version__

    parser = argparse.ArgumentParser(
        prog="jaxflex",
        description="Identify flexible-link manipulators by differentiable simulation.",
        epilog="--debug (anywhere on the line) shows the traceback of an error.",
    )
    parser.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    subparsers = parser.add_subparsers(dest="command", required=True, metavar="COMMAND",
                                       parser_class=_CommandParser)
    for name in COMMANDS:
        try:
            module = importlib.import_module(f"jaxflex.cli.{name}")
        except ModuleNotFoundError as exc:
            if exc.name == f"jaxflex.cli.{name}":
                continue  # command not available in this build
            raise
        module.register(subparsers)
    return parser




def main(argv: Sequence[str] | None = None) -> int:
    from jaxflex.cli._errors import describe, one_line_warning

    argv = list(sys.argv[1:] if argv is None else argv)
    debug = "--debug" in argv
    argv = [a for a in argv if a != "--debug"]
    try:
        args = build_parser().parse_args(argv)
    except SystemExit as exc:  # --help (0) or an option error, already printed (2)
        return int(exc.code or 0)
    except KeyboardInterrupt:
        print("jaxflex: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED
    args.argv = argv  # what a command that starts copies of itself passes on
    prefix = f"jaxflex {args.command}"
    restore = _on_signals(prefix)
    format_warning = warnings.formatwarning
    try:
        warnings.formatwarning = one_line_warning(prefix)
        with warnings.catch_warnings():  # registries anew: a second run warns as the first
            check_environment()
            use_persistent_cache()
            return int(args.func(args) or 0)
    except KeyboardInterrupt:
        print(f"{prefix}: interrupted; no partial output was left", file=sys.stderr)
        return EXIT_INTERRUPTED
    except Exception as exc:
        if debug:
            raise
        message, status = describe(exc)
        print(f"{prefix}: error: {message}", file=sys.stderr)
        return status
    finally:
        warnings.formatwarning = format_warning
        restore()


def use_persistent_cache() -> None:
    """Keep compiled programs between runs of the command in JAX's on-disk cache, so a second
    run on records of the same layout starts computing at once: in ``$JAXFLEX_CACHE_DIR`` if
    set (empty: no cache), else ``$XDG_CACHE_HOME/jaxflex`` or ``~/.cache/jaxflex``, every
    program however quickly it compiled (JAX's default keeps those over 1 s: a run compiles a
    couple of hundred small ones, several seconds together, that a second run would compile
    again). JAX's own ``JAX_COMPILATION_CACHE_DIR`` wins when set; nothing changes once JAX
    has compiled. A ``$JAXFLEX_CACHE_DIR`` that cannot be written is refused in one line (JAX
    would warn at every program); an unwritable default folder means no cache."""
    import os
    from pathlib import Path

    import jax

    if os.environ.get("JAX_COMPILATION_CACHE_DIR") or jax.config.jax_compilation_cache_dir:
        return
    folder = os.environ.get("JAXFLEX_CACHE_DIR")
    if folder is None:
        base = os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache"
        folder = str(Path(base) / "jaxflex")
        if _unwritable_folder(Path(folder)):
            return  # no cache rather than one warning from JAX per program it compiles
    elif folder and (problem := _unwritable_folder(Path(folder))):
        raise ValueError(
            f"JAXFLEX_CACHE_DIR={folder}: {problem}; set it to a folder this user may write, "
            "or to nothing (JAXFLEX_CACHE_DIR=) to keep no compiled programs"
        )
    if folder:
        jax.config.update("jax_compilation_cache_dir", folder)
        if "JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS" not in os.environ:
            jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)


def check_environment() -> None:
    """Refuse, before JAX starts, an environment variable of jaxflex's that it cannot use
    (``JAXFLEX_HOST_DEVICES``: :func:`jaxflex._host.default_host_devices`)."""
    from jaxflex._host import default_host_devices

    default_host_devices()


def _unwritable_folder(folder) -> str | None:
    """Why ``folder`` cannot be created or written, or None; creates nothing."""
    import os

    existing = folder
    while not existing.exists() and existing != existing.parent:
        existing = existing.parent
    if not existing.is_dir():
        return f"{existing} is not a directory" if existing != folder else "not a directory"
    if not os.access(existing, os.W_OK | os.X_OK):
        return "not writable" if existing == folder else f"{existing} is not writable"
    return None


def _on_signals(prefix: str):
    """On SIGINT or SIGTERM remove the temporary files, say so in one line and exit 130 or 143
    at once (main thread only): an exception could meet a bare ``except:`` in a library and be
    lost (JAX's tracing has several), and the command would go on to write its outputs.
    Python runs a handler only between two bytecodes of the main thread, never while one
    compiled call runs (a large rig's simulation can take minutes): a watcher thread, woken by
    the signal itself (:func:`signal.set_wakeup_fd`; XLA lets other threads run), ends the
    process when the main thread has not done so within :data:`SIGNAL_GRACE_S` (unless a
    handler of the command's own, such as the launcher's of ``--processes``, replaced this
    one). Returns the undo."""
    import os
    import threading

    from jaxflex._io import remove_temporaries

    if threading.current_thread() is not threading.main_thread():
        return lambda: None
    endings = {signal.SIGINT: ("interrupted", EXIT_INTERRUPTED),
               signal.SIGTERM: ("terminated", EXIT_TERMINATED)}
    ending = threading.Lock()  # one ending, by whichever thread gets there first

    def end(signum: int) -> None:
        ending.acquire()
        remove_temporaries()
        word, status = endings[signum]
        print(f"{prefix}: {word}; no partial output was left", file=sys.stderr, flush=True)
        os._exit(status)

    def handler(signum, frame):
        end(signum)

    previous = {signum: signal.signal(signum, handler) for signum in endings}
    woken, wake = os.pipe()
    os.set_blocking(wake, False)
    previous_wakeup = signal.set_wakeup_fd(wake, warn_on_full_buffer=False)

    def watch() -> None:
        import time

        while data := os.read(woken, 64):  # empty: the command ended, the pipe is closed
            for signum in data:
                if signum in endings:
                    time.sleep(SIGNAL_GRACE_S)  # the main thread's handler, when it can run
                    if signal.getsignal(signum) is handler:
                        end(signum)
        os.close(woken)

    threading.Thread(target=watch, name="jaxflex-signals", daemon=True).start()

    def restore() -> None:
        signal.set_wakeup_fd(previous_wakeup)
        os.close(wake)
        for signum, replaced in previous.items():
            signal.signal(signum, replaced)

    return restore


SIGNAL_GRACE_S = 0.25
"""Seconds a signal waits for the main thread's handler before the watcher thread ends the
command (the main thread may be inside one long compiled call)."""


if __name__ == "__main__":
    sys.exit(main())
