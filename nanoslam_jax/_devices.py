"""The CPU cores this process may use, exposed to JAX as devices (one per core).

Several CPU devices let one process run work on every core side by side: a sweep splits each
batch of runs over them, a single run with many particles splits its particles
(``filter.split_devices``). JAX fixes its CPU device count at its first computation, so a
command sets it up first thing.
"""

from __future__ import annotations

import os

import jax


def available_cores() -> int:
    """CPU cores this process may run on."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # pragma: no cover - not Linux
        return os.cpu_count() or 1


def setup_devices(n: int) -> int:
    """Ask JAX for ``n`` CPU devices (possible only before JAX's first computation).

    Returns:
        The number of devices available (less than ``n`` when JAX had started already).
    """
    if n > 1:
        try:
            jax.config.update("jax_num_cpu_devices", n)
        except RuntimeError:
            pass
    return len(jax.devices())


def setup_run_devices(split_devices: str, n_particles: int) -> int:
    """Set up one JAX CPU device per core when a single run's particles will be split over them
    (``filter.split_devices``; see :func:`~nanoslam_jax.filter.particle_devices`). Call first
    thing, before JAX's first computation.

    Returns:
        The number of JAX devices available.
    """
    from .filter import particle_devices

    cores = available_cores()
    if particle_devices(split_devices, n_particles, cores) > 1:
        return setup_devices(cores)
    return len(jax.devices())
