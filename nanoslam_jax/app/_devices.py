"""The CPU cores this process may use, exposed to JAX as devices (:data:`DEVICES_PER_CORE` each for a
single run, :data:`SWEEP_DEVICES_PER_CORE` each for a sweep).

Several CPU devices let one process run work on every core side by side: a sweep splits each
batch of runs over them, a single run with many particles splits its particles
(``filter.split_devices``). JAX fixes its CPU device count at its first computation, so a
command sets it up first thing.
"""

from __future__ import annotations

import os

import jax


#: JAX CPU devices per core for a single run's split particles. XLA:CPU already runs one device's
#: program on more than one core, so more devices than cores only wait for each other at every
#: scan (the particles' outputs are gathered) and share the cores. Sweeps have their own count
#: (:data:`SWEEP_DEVICES_PER_CORE`).
DEVICES_PER_CORE = 1

#: JAX CPU devices per core for a sweep's batches (``run.parallel: devices``). A batch's devices
#: carry whole runs and never wait for each other inside a scan, so more devices only share the
#: cores more finely (throughput by mode: the docs' page on sweeps, "Several cores").
SWEEP_DEVICES_PER_CORE = 4


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


def setup_run_devices(cfg) -> int:
    """Set up :data:`DEVICES_PER_CORE` JAX CPU devices per core when a single run's particles
    will be split over them (``filter.split_devices``; see
    :func:`~nanoslam_jax.methods.particle_devices`). Call first thing, before JAX's first
    computation.

    Args:
        cfg: the run's :class:`~nanoslam_jax.app.config.Config`.

    Returns:
        The number of JAX devices available.
    """
    from nanoslam_jax.methods import particle_devices, shardable
    from nanoslam_jax.app.filters import method_static
    from nanoslam_jax.app.registry import get_method

    cores = available_cores()
    split_ok = shardable(get_method(cfg.filter.method), method_static(cfg))
    if (
        cores > 1
        and particle_devices(
            cfg.filter.split_devices, cfg.filter.n_particles, cores * DEVICES_PER_CORE, split_ok=split_ok
        )
        > 1
    ):
        return setup_devices(cores * DEVICES_PER_CORE)
    return len(jax.devices())
