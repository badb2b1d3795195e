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
"""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Sequence

import jax
from jax.experimental import multihost_utils

from jaxflex.parallel import default_host_devices

COORDINATOR_ENV = "JAX_COORDINATOR_ADDRESS"
POLL_S = 0.2
STOP_S = 10.0


def start(processes: int | None, process_id: int | None, coordinator: str | None) -> None:
    """Join the multi-process runtime (before any JAX computation); ValueError if the settings
    do not describe one process of a group."""
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
    own_handler = signal.getsignal(signal.SIGTERM)
    jax.distributed.initialize(
        coordinator_address=coordinator, num_processes=processes, process_id=process_id
    )
    if threading.current_thread() is threading.main_thread():
        # JAX's preemption notifier took SIGTERM over and only records it: the process would
        # run on, and hold the group; put back what SIGTERM did before.
        signal.signal(signal.SIGTERM, own_handler)
    # Open the connections between the processes' devices now, while the group is in step:
    # opening them waits only 30 s for the slowest process, and the first program of a search
    # may finish compiling minutes apart on busy hosts; once open, a collective waits as long
    # as it takes (measured: 45 s of skew, jax 0.10.2, CPU collectives over Gloo).
    multihost_utils.sync_global_devices("jaxflex: group started")


def wanted(processes: int | None, process_id: int | None, coordinator: str | None) -> str:
    """What the settings ask for: ``"one"`` process, ``"launch"`` local ones, or ``"join"``."""
    if process_id is None and coordinator is None and not os.environ.get(COORDINATOR_ENV):
        return "one" if processes in (None, 1) else "launch"
    return "join"


def is_main() -> bool:
    """Whether this is the process that prints and writes (process 0, or the only one)."""
    return jax.process_index() == 0


def free_port() -> int:
    """A TCP port free on localhost now (the coordinator binds it a moment later)."""
    with socket.socket() as s:
        s.bind(("localhost", 0))
        return s.getsockname()[1]


def launch_local(argv: Sequence[str], processes: int) -> int:
    """Run ``jaxflex ARGV`` as ``processes`` processes of one group on this machine.

    Each process gets ``--process-id`` and the coordinator's address, and, unless
    ``JAXFLEX_HOST_DEVICES`` is set, its share of the cores as CPU devices. Process 0 prints to
    this terminal; the others' output is kept and shown only if one of them fails while process
    0 does not. If any process fails, the rest are stopped, as they are when this one is
    interrupted or terminated. Returns the group's exit status.
    """
    coordinator = f"localhost:{free_port()}"
    env = dict(os.environ)
    env.setdefault("JAXFLEX_HOST_DEVICES", str(max(1, default_host_devices() // processes)))
    logs = [tempfile.TemporaryFile() for _ in range(processes)]
    group: list[subprocess.Popen] = []
    previous = _forward_sigterm(group)
    for rank in range(processes):
        command = [sys.executable, "-m", "jaxflex", *argv, "--process-id", str(rank),
                   "--coordinator", coordinator]
        quiet = {} if rank == 0 else {"stdout": logs[rank], "stderr": subprocess.STDOUT}
        group.append(subprocess.Popen(command, env=env, **quiet))
    try:
        status = _wait(group)
    finally:
        _stop(group)
        if previous is not None:
            signal.signal(signal.SIGTERM, previous)
    if status != 0 and group[0].returncode == 0:
        failed = next(i for i, p in enumerate(group) if p.returncode != 0)
        logs[failed].seek(0)
        sys.stderr.write(logs[failed].read().decode(errors="replace")[-3000:])
    for log in logs:
        log.close()
    return status


def _stop(group: list[subprocess.Popen]) -> None:
    """Terminate the processes still running (killed if they have not ended within
    :data:`STOP_S`)."""
    for process in group:
        if process.poll() is None:
            process.terminate()
    for process in group:
        try:
            process.wait(timeout=STOP_S)
        except subprocess.TimeoutExpired:
            process.kill()
            process.wait()


def _forward_sigterm(group: list[subprocess.Popen]):
    """Stop the group before this process's own SIGTERM handler runs (main thread only);
    returns the handler it replaced, to put back, or None."""
    if threading.current_thread() is not threading.main_thread():
        return None
    previous = signal.getsignal(signal.SIGTERM)

    def handler(signum, frame):
        _stop(group)
        if callable(previous):
            previous(signum, frame)
        raise SystemExit(128 + signum)

    signal.signal(signal.SIGTERM, handler)
    return previous


def _wait(group: list[subprocess.Popen]) -> int:
    """0 once every process has ended well; the first failure's status as soon as one fails."""
    while True:
        codes = [p.poll() for p in group]
        failed = [c for c in codes if c not in (None, 0)]
        if failed:
            return failed[0]
        if all(c == 0 for c in codes):
            return 0
        time.sleep(POLL_S)


__all__ = ["COORDINATOR_ENV", "free_port", "is_main", "launch_local", "start", "wanted"]
