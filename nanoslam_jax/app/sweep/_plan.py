"""How a sweep's runs become compiled calls: runs grouped by static shape (one program each), each
group's batch size (memory budget, workers, devices), and the batches still to run.

The compiled program of a group depends only on ``(Static, vectorize, devices, batch size,
segment shapes)``: a group's last batch is padded with copies of its first run so every batch
reuses the program, and the batch size depends only on the whole group, so a resumed sweep makes
the same calls as an uninterrupted one.
"""

from __future__ import annotations

import dataclasses
from typing import Optional, Sequence

import jax
import numpy as np

from nanoslam_jax.methods import Static, row_buckets, shardable
from nanoslam_jax.app.filters import settings_from_config
from nanoslam_jax.app.sweep._batch import BatchTask, LogData, log_key
from nanoslam_jax.app.sweep._spec import Run, SweepSpec

__all__ = ["Group", "plan_groups", "make_tasks", "resolve_vectorize", "DEFAULT_MAX_BATCH", "AUTO_VECTORIZE"]

#: Default cap of runs per compiled call (progress and resume granularity; memory permitting).
DEFAULT_MAX_BATCH = 64

#: How a batch is computed on CPU by default: ``vmap`` gives the most runs per second, ``lax.map``
#: fewer (the filter step is compute-bound on CPU, so batching amortises little; the docs' sweeps
#: page, "Throughput", has the figures and ``experiments/sweep_benchmark.py`` measures them).
#: lax.map reproduces single runs bit for bit; vmap agrees with them to rounding at each step,
#: which the filter can amplify (a near-tie of weights picks another particle). On accelerators
#: ``auto`` is ``vmap``.
AUTO_VECTORIZE = "vmap"


@dataclasses.dataclass
class Group:
    """Runs sharing one compiled program.

    Attributes:
        label: ``g0``, ``g1``... in order of first appearance.
        static: their static settings.
        log_id: their log.
        runs: their runs, in sweep order.
        batch: runs per compiled call (every call of the group has this size).
        shape_values: the swept shape keys' values of the group.
    """

    label: str
    static: Static
    log_id: int
    runs: list
    batch: int = 1
    shape_values: dict = dataclasses.field(default_factory=dict)


def _bytes_per_run(static: Static, n_segments: int) -> int:
    """A generous estimate of one run's memory in a batch (state copies, window work, outputs)."""
    state = static.n_particles * static.capacity * (2 + 4 + 1 + 1 + 1) * 8
    window = static.n_particles * static.window_size * (2 + 4 + 3) * 8 * static.k_max
    outputs = n_segments * 16 * 8
    if static.estimate.records_path:  # every particle's pose and ancestor per segment, followed back in the program
        outputs += n_segments * static.n_particles * 4 * 8
    return 4 * state + 2 * window + 2 * outputs + (1 << 16)


def plan_groups(
    spec: SweepSpec, runs: Sequence[Run], logs: dict, *, batch: Optional[int] = None, split: int = 1, devices: int = 1
) -> list[Group]:
    """Group runs by (log, static settings) and choose each group's batch size.

    Args:
        spec: the sweep.
        runs: all its runs.
        logs: ``log_key -> (log_id, LogData)``.
        batch: runs per call (``None``: from ``spec.run``; automatic: at most
            :data:`DEFAULT_MAX_BATCH` and within ``run.memory_gb``).
        split: spread each group over at least this many batches when it is large enough
            (one per worker), so every worker gets work.
        devices: make the batch size a multiple of this (sharding).

    A group of ``n`` runs and a largest batch ``b`` gets ``ceil(n / b)`` batches of
    ``ceil(n / ceil(n / b))`` runs, so the padding of its last batch is as small as possible.

    The batch size depends only on the whole group (never on which runs are finished), so a
    resumed sweep makes the same calls as an uninterrupted one.
    """
    groups: dict[tuple, Group] = {}
    shape_keys = [k for k, _ in spec.shapes]
    for r in runs:
        lid, log = logs[log_key(r.point.config)]
        static, _ = settings_from_config(r.point.config, log.segments.k_max)
        g = groups.get((lid, static))
        if g is None:
            g = groups[(lid, static)] = Group(
                f"g{len(groups)}", static, lid, [], shape_values={k: r.point.values[k] for k in shape_keys}
            )
        g.runs.append(r)
    want = batch if batch is not None else spec.run.batch
    for g in groups.values():
        n = len(g.runs)
        if want is None:
            n_seg = logs_by_id(logs)[g.log_id].segments.time.shape[0]
            cap = max(1, int(spec.run.memory_gb * 2**30 // _bytes_per_run(g.static, n_seg)))
            b = min(DEFAULT_MAX_BATCH, cap, n)
        else:
            b = min(want, n)
        if split > 1:
            b = min(b, -(-n // split))
        b = -(-n // -(-n // b))  # as many batches as needed, of equal size: the least padding
        if devices > 1:
            b = -(-b // devices) * devices
        g.batch = max(1, b)
    return list(groups.values())


def logs_by_id(logs: dict) -> dict[int, LogData]:
    """``log_id -> LogData`` from ``log_key -> (log_id, LogData)``."""
    return {lid: log for lid, log in logs.values()}


def make_tasks(
    spec: SweepSpec, groups: Sequence[Group], logs: dict, done: set, devices: int = 1, vectorize: Optional[str] = None
) -> list[BatchTask]:
    """The batches still to run (finished run ids in ``done`` are skipped).

    Args:
        spec, groups, logs: the sweep, its groups and logs (see :func:`plan_groups`).
        done: finished run ids.
        devices: split each batch over this many JAX devices.
        vectorize: ``'vmap'`` or ``'map'`` (default: from ``spec.run.vectorize``).
    """
    vectorize = resolve_vectorize(vectorize or spec.run.vectorize)
    tasks = []
    by_id = logs_by_id(logs)
    for g in groups:
        pending = [r for r in g.runs if r.run_id not in done]
        k_max = by_id[g.log_id].segments.k_max
        # optimistix's least squares fails under shard_map (see `shardable`): such a group's
        # batches run whole on one device.
        split = devices if shardable(g.static.method, g.static.method_settings) else 1
        # The proposal's row buckets pay off by the particles one call carries (per device) and the
        # work the one compiled program does over the group's batches.
        per_call = g.static.n_particles * (max(1, g.batch // split) if vectorize == "vmap" else 1)
        calls = -(-len(pending) // g.batch) * (1 if vectorize == "vmap" else g.batch)
        n_seg = int(by_id[g.log_id].segments.time.shape[0])
        setting = g.runs[0].point.config.filter.row_buckets
        static = dataclasses.replace(
            g.static, row_buckets=row_buckets(setting, per_call, n_seg, calls), devices=1
        )  # the batch, not a run's particles, is split over devices
        # The smoother runs on the host after the batch, on each run's path and map; its map
        # history needs the run in chunks of output.chunk segments, as `nanoslam run` makes it.
        cfg0 = g.runs[0].point.config
        smoother = cfg0.smoother if cfg0.smoother.enabled else None
        history_chunk = cfg0.output.chunk if smoother is not None and smoother.map_history else 0
        for start in range(0, len(pending), g.batch):
            chunk = pending[start : start + g.batch]
            members = chunk + [chunk[0]] * (g.batch - len(chunk))
            plist = [settings_from_config(r.point.config, k_max)[1] for r in members]
            params = jax.tree.map(lambda *a: np.stack([np.asarray(x) for x in a]), *plist)
            tasks.append(
                BatchTask(
                    group=g.label,
                    static=static,
                    log_id=g.log_id,
                    params=params,
                    seeds=np.array([r.seed for r in members], dtype=np.int64),
                    n_real=len(chunk),
                    metrics_opts=tuple(r.point.config.metrics for r in chunk),
                    fail_on_overflow=spec.run.fail_on_overflow,
                    run_ids=tuple(r.run_id for r in chunk),
                    devices=split,
                    vectorize=vectorize,
                    smoother=smoother,
                    history_chunk=history_chunk,
                )
            )
    return tasks


def resolve_vectorize(vectorize: str) -> str:
    """``auto`` is :data:`AUTO_VECTORIZE` on CPU and ``vmap`` on accelerators."""
    if vectorize == "auto":
        return AUTO_VECTORIZE if jax.default_backend() == "cpu" else "vmap"
    return vectorize
