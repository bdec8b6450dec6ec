"""Optional backend: the sweep's batches as Ray tasks (``pip install 'nanoslam-jax[ray]'``).

The driver keeps everything else: it plans the same batches, writes the rows each task returns
with the same atomic append, and resumes the same way. Each task runs :func:`execute_batch` in a
Ray worker process (one CPU each), which keeps its compiled programs between tasks; the log is
put into Ray's object store once.
"""

from __future__ import annotations

import math
from typing import Iterator, Optional, Sequence

from nanoslam_jax.app.config import ConfigError
from nanoslam_jax.lib._cache import enable_compile_cache
from nanoslam_jax.app.sweep._batch import BatchTask, LogData, _first_line, execute_batch

__all__ = ["ray_iter", "import_ray"]


def import_ray():
    """The ``ray`` module, or a :class:`ConfigError` saying how to install it."""
    try:
        import ray
    except ImportError:
        raise ConfigError(
            "backend 'ray' needs Ray, which is not installed; install it with "
            "pip install 'nanoslam-jax[ray]' (or pip install 'ray>=2.9'), or use backend: local"
        ) from None
    return ray


def _remote_execute(task: BatchTask, log: LogData, cache_dir: Optional[str]) -> list[dict]:
    """Body of a Ray task: run one batch in the worker (in float64, as :func:`execute_batch` is)."""
    if cache_dir:
        try:
            enable_compile_cache(cache_dir)
        except ValueError:  # the driver's directory is not visible on this node: just compile
            pass
    return execute_batch(task, log)


def ray_iter(
    tasks: Sequence[BatchTask],
    logs: dict[int, LogData],
    *,
    address: Optional[str] = None,
    num_cpus: Optional[int] = None,
    cache_dir: Optional[str] = None,
    max_in_flight: Optional[int] = None,
) -> Iterator[tuple[BatchTask, list[dict]]]:
    """Run batches as Ray tasks and yield ``(task, member results)`` as they finish.

    Args:
        tasks: the batches.
        logs: ``log_id -> LogData``.
        address: the cluster to connect to (``None``: start a local Ray instance, unless Ray is
            initialised already, which is then used as it is).
        num_cpus: CPUs of a local instance (``None``: Ray's default).
        cache_dir: JAX compilation cache for the workers (useful on one machine).
        max_in_flight: tasks submitted at a time (default: twice the cluster's CPUs).
    """
    ray = import_ray()
    started = False
    if not ray.is_initialized():
        kw = dict(include_dashboard=False, log_to_driver=False, configure_logging=False)
        if address is not None:
            ray.init(address=address, **kw)
        else:
            ray.init(num_cpus=num_cpus, **kw)
        started = True
    try:
        remote = ray.remote(num_cpus=1, max_retries=0)(_remote_execute)
        refs = {lid: ray.put(log) for lid, log in logs.items()}
        limit = max_in_flight or max(2, 2 * int(ray.cluster_resources().get("CPU", 1)))
        queue = list(tasks)
        running: dict = {}
        while queue or running:
            while queue and len(running) < limit:
                t = queue.pop(0)
                running[remote.remote(t, refs[t.log_id], cache_dir)] = t
            done, _ = ray.wait(list(running), num_returns=1)
            for ref in done:
                t = running.pop(ref)
                try:
                    res = ray.get(ref)
                except Exception as e:  # the task or its worker failed: fail the batch, go on
                    res = [
                        dict(
                            status="failed", reason=f"error: ray task: {_first_line(e)}", run_s=math.nan, compile_s=0.0
                        )
                        for _ in range(t.n_real)
                    ]
                yield t, res
    finally:
        for ref in list(locals().get("running", {})):
            try:
                ray.cancel(ref, force=True)
            except Exception:
                pass
        if started:
            ray.shutdown()
