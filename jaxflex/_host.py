"""The host's usable cores and the number of JAX CPU devices jaxflex asks for.

Kept apart from :mod:`jaxflex.parallel`, and free of JAX at import, because importing jaxflex
calls :func:`configure_host_devices` the moment JAX itself is first imported: also when that
import is :mod:`jaxflex.parallel`'s own, before its names exist.
"""

from __future__ import annotations

import os

MAX_HOST_DEVICES = 8
"""Upper bound on the CPU devices jaxflex asks for by default."""


def usable_cores() -> int:
    """The cores this process may run on (its CPU affinity on Linux, else the CPU count)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # not on Linux
        return os.cpu_count() or 1


def default_host_devices() -> int:
    """``JAXFLEX_HOST_DEVICES`` if set (an integer >= 1), else the usable cores (<= 8)."""
    value = os.environ.get("JAXFLEX_HOST_DEVICES")
    if value is not None:
        try:
            count = int(value)
        except ValueError:
            count = 0
        if count < 1:
            raise ValueError(f"JAXFLEX_HOST_DEVICES={value!r} must be an integer >= 1")
        return count
    return min(usable_cores(), MAX_HOST_DEVICES)


def configure_host_devices(count: int | None = None) -> None:
    """Ask JAX for ``count`` CPU devices (default :func:`default_host_devices`) before it starts.

    Does nothing when JAX is already running or the user chose a number themselves; starts
    nothing either (JAX's backends stay uninitialised until first used).
    """
    import jax

    user_flag = "xla_force_host_platform_device_count" in os.environ.get("XLA_FLAGS", "")
    if user_flag or jax.config.jax_num_cpu_devices != -1:
        return
    count = default_host_devices() if count is None else int(count)
    try:
        jax.config.update("jax_num_cpu_devices", count)
    except RuntimeError:  # backends already initialised: keep what the user has
        pass
