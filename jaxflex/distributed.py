"""Populations spread over several processes (and hosts) by JAX's multi-process runtime.

Nothing here schedules work. :func:`start` calls :func:`jax.distributed.initialize`; from then on
``jax.devices()`` lists the devices of every process, and :mod:`jaxflex.parallel` splits each
population across all of them with the same ``shard_map`` over a (now global) mesh: every process
runs the same program on its share and receives everyone's results. Every process therefore
computes the same search and the same fit; only the first writes files (:func:`is_main`). Per
candidate, the results are the bits of one process with as many devices (see
:func:`jaxflex.parallel.population_vmap`).

Three ways to start, as for any JAX program:

* ``--processes N`` alone: :func:`launch_local` starts ``N`` processes of the same command on this
  machine, the coordinator on a free localhost port, the cores shared between them;
* ``--processes N --process-id I --coordinator HOST:PORT`` on each of ``N`` hosts (or processes);
* ``JAX_COORDINATOR_ADDRESS`` in the environment: :func:`jax.distributed.initialize` finds the
  rest itself on the cluster environments it knows (SLURM, Open MPI, …), or from the options.

A library user calls :func:`jax.distributed.initialize` before the first JAX computation and then
uses jaxflex as on one process.

What can go wrong, and what then happens:

* a process of the group never starts: :func:`start` gives up after ``peer_timeout`` seconds
  (``--peer-timeout``, default :data:`PEER_TIMEOUT_S`) with :class:`PeerTimeout`, before JAX's
  runtime would abort the process; Ctrl-C and SIGTERM stop the wait at once;
* :func:`launch_local` starts no more processes than the usable cores. Its processes form one
  process group of their own, and each is killed when the launcher dies (``kill -9`` included:
  Linux's parent-death signal), so none outlives it. When one process fails the launcher stops
  the others and returns the group's status: that process's own (2 a usable error, 1 a bug, 130,
  143), or 1 with a line naming the rank when a signal killed it or it ended otherwise
  (``rank 1 killed by SIGKILL``);
* the collective library's greeting on standard output (``[Gloo] Rank 0 is connected …``) is
  dropped while the group starts, so standard output holds only the command's results.
"""

from __future__ import annotations

import contextlib
import ctypes
import os
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Iterator, Sequence

COORDINATOR_ENV = "JAX_COORDINATOR_ADDRESS"
POLL_S = 0.2
STOP_S = 10.0
"""How long a stopped process may take to end on SIGTERM before it is killed."""
PEER_TIMEOUT_S = 60.0
"""How long :func:`start` waits, by default, for every process of the group to join."""
LAUNCHER_ENV = "JAXFLEX_LAUNCHER_PID"
"""Set by :func:`launch_local` in its processes: the launcher speaks for the group."""
_PR_SET_PDEATHSIG = 1
_JAX_MISSING = ("Number of processes must be defined.",
                "The process id of the current process must be defined.")


class PeerTimeout(ValueError):
    """The group did not form within the time allowed: a process never started or joined."""


def start(processes: int | None, process_id: int | None, coordinator: str | None,
          peer_timeout: float = PEER_TIMEOUT_S) -> None:
    """Join the multi-process runtime (before any JAX computation); ValueError if the settings
    do not describe one process of a group, :class:`PeerTimeout` if the group has not formed
    within ``peer_timeout`` seconds."""
    if processes is not None and processes < 1:
        raise ValueError(f"--processes {processes}: expected an integer >= 1")
    if process_id is not None:
        if processes is None:
            raise ValueError("--process-id needs --processes (the size of the group)")
        if not 0 <= process_id < processes:
            raise ValueError(f"--process-id {process_id}: expected 0 ... {processes - 1}")
    if coordinator is None and process_id is not None and not os.environ.get(COORDINATOR_ENV):
        raise ValueError(f"--process-id needs --coordinator HOST:PORT (or {COORDINATOR_ENV})")
    if coordinator is not None and process_id is None:
        raise ValueError("--coordinator needs --process-id (this process's place in the group)")
    if not peer_timeout > 0:
        raise ValueError(f"--peer-timeout {peer_timeout}: expected a number of seconds > 0")
    own_handler = signal.getsignal(signal.SIGTERM)
    address = coordinator or os.environ.get(COORDINATOR_ENV)
    with _quiet_stdout():
        _initialize(processes, process_id, coordinator, peer_timeout, address)
        if threading.current_thread() is threading.main_thread():
            # JAX's preemption notifier took SIGTERM over and only records it: the process
            # would run on, and hold the group; put back what SIGTERM did before.
            signal.signal(signal.SIGTERM, own_handler)
        # Open the connections between the processes' devices now, while the group is in
        # step: opening them waits only 30 s for the slowest process, and the first program
        # of a search may finish compiling minutes apart on busy hosts; once open, a
        # collective waits as long as it takes.
        from jax.experimental import multihost_utils

        multihost_utils.sync_global_devices("jaxflex: group started")


def _initialize(processes: int | None, process_id: int | None, coordinator: str | None,
                peer_timeout: float, address: str | None) -> None:
    """:func:`jax.distributed.initialize` in a thread of its own, waited for here: JAX's runtime
    blocks signals' Python handlers while it waits and aborts the process (a C++ check
    failure) when its own timeout ends, so this wait ends first, and Ctrl-C and SIGTERM reach
    their handlers meanwhile."""
    failure: list[BaseException] = []

    import jax

    def join() -> None:
        try:
            jax.distributed.initialize(
                coordinator_address=coordinator, num_processes=processes,
                process_id=process_id, initialization_timeout=int(peer_timeout) + 60,
            )
        except BaseException as exc:  # re-raised in the waiting thread
            failure.append(exc)

    joiner = threading.Thread(target=join, name="jaxflex-join", daemon=True)
    joiner.start()
    joiner.join(peer_timeout)
    if joiner.is_alive():
        size = f" of {processes} processes" if processes else ""
        raise PeerTimeout(
            f"the group{size} did not form within {peer_timeout:g} s "
            f"(coordinator {address}): a process has not started or cannot reach the "
            "coordinator; start every process with the same --processes and --coordinator, "
            "or wait longer with --peer-timeout SECONDS"
        )
    if failure:
        exc = failure[0]
        if isinstance(exc, ValueError) and str(exc) in _JAX_MISSING and coordinator is None:
            raise ValueError(
                f"{COORDINATOR_ENV}={address} is set, but neither --processes and --process-id "
                "nor a cluster environment say which group this process belongs to; give "
                f"--processes N --process-id I, or unset {COORDINATOR_ENV} to run as one "
                "process"
            ) from None
        raise exc


@contextlib.contextmanager
def _quiet_stdout() -> Iterator[None]:
    """Standard output (file descriptor 1) goes nowhere inside the block: the collective
    library greets on it from C++ (``[Gloo] Rank 0 is connected to 1 peer ranks…``)."""
    sys.stdout.flush()
    try:
        saved = os.dup(1)
    except OSError:  # no standard output to guard
        yield
        return
    with open(os.devnull, "wb") as null:
        os.dup2(null.fileno(), 1)
    try:
        yield
    finally:
        os.dup2(saved, 1)
        os.close(saved)


def wanted(processes: int | None, process_id: int | None, coordinator: str | None) -> str:
    """What the settings ask for: ``"one"`` process, ``"launch"`` local ones, or ``"join"``."""
    if process_id is None and coordinator is None and not os.environ.get(COORDINATOR_ENV):
        return "one" if processes in (None, 1) else "launch"
    return "join"


def check_local_group(processes: int) -> None:
    """Refuse a group of more local processes than the usable cores (ValueError)."""
    from jaxflex.parallel import usable_cores

    cores = usable_cores()
    if processes > cores:
        raise ValueError(
            f"--processes {processes}: more processes than the {cores} usable cores of this "
            f"machine; give at most {cores}, or start the processes yourself with --process-id "
            "and --coordinator (one per host)"
        )


def is_main() -> bool:
    """Whether this is the process that prints and writes (process 0, or the only one)."""
    import jax

    return jax.process_index() == 0


def launched() -> bool:
    """Whether this process was started by :func:`launch_local` (which speaks for it)."""
    return os.environ.get(LAUNCHER_ENV) == str(os.getppid())


def free_port() -> int:
    """A TCP port free on localhost now (the coordinator binds it a moment later)."""
    with socket.socket() as s:
        s.bind(("localhost", 0))
        return s.getsockname()[1]


def launch_local(argv: Sequence[str], processes: int, prefix: str = "jaxflex") -> int:
    """Run ``jaxflex ARGV`` as ``processes`` processes of one group on this machine.

    Each process gets ``--process-id`` and the coordinator's address, and, unless
    ``JAXFLEX_HOST_DEVICES`` is set, its share of the cores as CPU devices. Process 0 prints to
    this terminal; the others' output is kept and shown only if one of them fails while process
    0 does not. The processes form a process group of their own and die with this one. If any
    process fails, the rest are stopped, as they are when this one is interrupted or
    terminated. Returns the group's exit status (see the module doc); a line starting with
    ``prefix`` names a rank that a signal killed.
    """
    check_local_group(processes)
    coordinator = f"localhost:{free_port()}"
    env = dict(os.environ)
    from jaxflex.parallel import default_host_devices

    env.setdefault("JAXFLEX_HOST_DEVICES", str(max(1, default_host_devices() // processes)))
    env[LAUNCHER_ENV] = str(os.getpid())
    logs = [tempfile.TemporaryFile() for _ in range(processes)]
    group: list[subprocess.Popen] = []
    previous = _forward_signals(group)
    try:
        for rank in range(processes):
            command = [sys.executable, "-m", "jaxflex", *argv, "--process-id", str(rank),
                       "--coordinator", coordinator]
            quiet = {} if rank == 0 else {"stdout": logs[rank], "stderr": subprocess.STDOUT}
            group.append(subprocess.Popen(
                command, env=env, process_group=group[0].pid if group else 0,
                preexec_fn=_die_with(os.getpid()), **quiet,
            ))
        failure = _wait(group)
    finally:
        _stop(group)
        for signum, handler in previous.items():
            signal.signal(signum, handler)
    status = 0 if failure is None else _report(*failure, logs, prefix)
    for log in logs:
        log.close()
    return status


def _report(rank: int, code: int, logs: list, prefix: str) -> int:
    """Say why the group failed (rank ``rank`` ended first, with ``code``); its status."""
    from jaxflex.cli import EXIT_BUG, EXIT_INTERRUPTED, EXIT_TERMINATED, EXIT_USAGE

    if code in (EXIT_BUG, EXIT_USAGE, EXIT_INTERRUPTED, EXIT_TERMINATED):
        if rank != 0:  # its own message, kept in its log (process 0 prints to the terminal)
            logs[rank].seek(0)
            text = logs[rank].read().decode(errors="replace")
            said = [line for line in text.splitlines(keepends=True) if line.startswith(prefix)]
            sys.stderr.write("".join(said) or text[-3000:])
        return code
    if code < 0:
        name = signal.Signals(-code).name if -code in signal.valid_signals() else str(-code)
        how = f"killed by {name}"
    else:
        how = f"ended with exit status {code}"
    print(f"{prefix}: error: rank {rank} {how}; the group was stopped and wrote nothing",
          file=sys.stderr, flush=True)
    return EXIT_BUG


def _die_with(parent: int):
    """What a child runs before ``exec``: ask Linux to kill it when ``parent`` dies (SIGKILL:
    a process stuck in a collective cannot run a SIGTERM handler), and end at once if it
    already has. ``prctl`` is looked up here, in the parent, not between fork and exec."""
    try:
        prctl = ctypes.CDLL(None, use_errno=True).prctl
    except (OSError, AttributeError):  # not Linux: the launcher's own stop must do
        prctl = None

    def preexec() -> None:
        if prctl is not None:
            prctl(_PR_SET_PDEATHSIG, int(signal.SIGKILL))
        if os.getppid() != parent:
            os._exit(1)

    return preexec


def _stop(group: list[subprocess.Popen]) -> None:
    """Terminate the processes still running (killed if they have not ended within
    :data:`STOP_S`)."""
    for process in group:
        if process.poll() is None:
            process.terminate()
    deadline = time.monotonic() + STOP_S
    for process in group:
        try:
            process.wait(timeout=max(0.0, deadline - time.monotonic()))
        except subprocess.TimeoutExpired:
            process.kill()
            process.wait()


def _forward_signals(group: list[subprocess.Popen]) -> dict:
    """On SIGINT or SIGTERM stop the group before this process's own handler runs (main thread
    only); returns the handlers it replaced, to put back."""
    if threading.current_thread() is not threading.main_thread():
        return {}

    def handler(signum, frame):
        _stop(group)
        if callable(previous[signum]):
            previous[signum](signum, frame)
        raise SystemExit(128 + signum)

    previous = {s: signal.signal(s, handler) for s in (signal.SIGINT, signal.SIGTERM)}
    return previous


def _wait(group: list[subprocess.Popen]) -> tuple[int, int] | None:
    """None once every process has ended well; (rank, status) of the first to fail, as soon
    as one fails."""
    while True:
        codes = [p.poll() for p in group]
        for rank, code in enumerate(codes):
            if code not in (None, 0):
                return rank, code
        if all(c == 0 for c in codes):
            return None
        time.sleep(POLL_S)


__all__ = [
    "COORDINATOR_ENV", "PEER_TIMEOUT_S", "PeerTimeout", "check_local_group", "free_port",
    "is_main", "launch_local", "launched", "start", "wanted",
]
