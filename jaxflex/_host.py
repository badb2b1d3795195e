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
    """``JAXFLEX_HOST_DEVICES`` if set (an integer >= 1, at most :func:`host_device_ceiling`),
    else the usable cores (<= 8)."""
    value = os.environ.get("JAXFLEX_HOST_DEVICES")
    if value is None:
        return min(usable_cores(), MAX_HOST_DEVICES)
    return min(requested_host_devices(value), host_device_ceiling())


def requested_host_devices(value: str) -> int:
    """The count ``JAXFLEX_HOST_DEVICES=value`` asks for; ValueError unless an integer >= 1."""
    try:
        count = int(value)
    except ValueError:
        count = 0
    if count < 1:
        raise ValueError(
            f"JAXFLEX_HOST_DEVICES={value!r} must be an integer >= 1 (the CPU devices to split "
            "populations over; unset it for one per usable core)"
        )
    return count


def host_device_ceiling() -> int:
    """The most CPU devices jaxflex asks for: the usable cores, or :data:`MAX_HOST_DEVICES`
    where there are fewer (a few devices sharing a core still test a split; thousands would
    take minutes to start and wait on each other, beyond the reach of Ctrl-C)."""
    return max(usable_cores(), MAX_HOST_DEVICES)


def host_devices_notice() -> str | None:
    """The one line that says ``JAXFLEX_HOST_DEVICES`` was lowered, or None (it was not, or is
    unset or invalid)."""
    value = os.environ.get("JAXFLEX_HOST_DEVICES")
    try:
        count = requested_host_devices(value) if value is not None else 0
    except ValueError:
        return None
    if count <= host_device_ceiling():
        return None
    return (f"JAXFLEX_HOST_DEVICES={value} is more than this machine can use (its "
            f"{usable_cores()} usable cores, or {MAX_HOST_DEVICES} at least); using "
            f"{host_device_ceiling()} CPU devices")


def configure_host_devices(count: int | None = None) -> None:
    """Ask JAX for ``count`` CPU devices (default :func:`default_host_devices`, said when it
    lowered ``JAXFLEX_HOST_DEVICES``) before it starts.

    Does nothing when JAX is already running or the user chose a number themselves; starts
    nothing either (JAX's backends stay uninitialised until first used).
    """
    import jax

    user_flag = "xla_force_host_platform_device_count" in os.environ.get("XLA_FLAGS", "")
    if user_flag or jax.config.jax_num_cpu_devices != -1:
        return
    if count is not None:
        count = int(count)
    else:
        count = default_host_devices()
        notice = host_devices_notice()
        if notice:
            import warnings

            warnings.warn(notice, stacklevel=2)
    try:
        jax.config.update("jax_num_cpu_devices", count)
    except RuntimeError:  # backends already initialised: keep what the user has
        pass
