"""One batch of a sweep: the log it runs on, the compiled program of a (static settings,
vectorisation, devices, batch size, segment shapes) key, and a batch's execution and scoring.

A group's programs are kept in :data:`_PROGRAMS` (and in the persistent compilation cache of
:mod:`nanoslam_jax.lib._cache`, so a resumed sweep, a second sweep of the same shapes and worker
processes load instead of compiling). :mod:`._runner` plans the batches and drives them.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import time
from typing import Any, NamedTuple, Optional

import jax
import jax.numpy as jnp
import numpy as np

from nanoslam_jax.lib._cache import program_cache, release_programs, watched_compile
from nanoslam_jax.app.config import Config
from nanoslam_jax.data import Segments
from nanoslam_jax.eval._scoring import MapEstimate
from nanoslam_jax.app._scored import Tracks, filter_statistics, score_estimate
from nanoslam_jax.methods import (
    MapHistory,
    Params,
    Static,
    adaptive_noise_summary,
    ancestral_path,
    configured_noise,
    filter_scan,
    initial_state,
    noise_estimates,
    reported_map,
    resample_count,
)
from nanoslam_jax.smoother._smoother import Smoothed, SmootherSettings, held_landmarks, smooth_run
from nanoslam_jax.lib._precision import in_float64


# --------------------------------------------------------------------------- the log


@dataclasses.dataclass(frozen=True)
class LogData:
    """A log as host arrays, ready to ship to a worker process or a Ray task.

    Attributes:
        segments: the (possibly truncated) segments, numpy arrays.
        gps: ``(G, 3)`` GPS fixes (or the truth of a simulated log).
        frame: metrics frame (``'relative'`` or ``'slam'``).
        map_truth: the true trees a map is judged against (the observable ones of a simulated log;
            ``None`` without ground truth).
        source: where the log came from.
        survey: a real log's surveyed landmarks (:class:`~nanoslam_jax.app.experiment.Survey`), or None.
        truth_poses: a simulated log's true path ``time, x, y, phi``, or None.
    """

    segments: Segments
    gps: np.ndarray
    frame: str
    map_truth: Optional[np.ndarray]
    source: str
    survey: Any = None
    truth_poses: Optional[np.ndarray] = None

    @property
    def time(self) -> np.ndarray:
        return np.asarray(self.segments.time)


def log_key(cfg: Config) -> tuple:
    """What determines the log of a configuration (its data section; and the simulator's inputs)."""
    laser = (cfg.detector,) if cfg.data.detections != "file" else ()  # the detections come from the detector
    if cfg.data.kind == "simulated":
        mounting = (cfg.odometry.sensor_x, cfg.odometry.sensor_y) if cfg.model.motion == "odometry" else ()
        return (cfg.data, cfg.sim, cfg.vehicle, cfg.model.motion, cfg.unicycle) + mounting + laser
    if cfg.data.kind == "city":
        mounting = (cfg.odometry.sensor_x, cfg.odometry.sensor_y) if cfg.model.motion == "odometry" else ()
        return (cfg.data, cfg.city, cfg.sim, cfg.vehicle, cfg.model.motion, cfg.unicycle) + mounting + laser
    if cfg.data.kind == "indoor":
        return (cfg.data, cfg.indoor, cfg.model.measurement) + laser
    return (cfg.data,) + laser


def load_log_data(cfg: Config, data_dir: Optional[str] = None, segments: Optional[int] = None) -> LogData:
    """Read (or simulate) the log of ``cfg`` and keep its first ``segments`` segments.

    Args:
        cfg: a configuration (its ``data``, ``sim`` and, for simulated logs, ``vehicle`` sections).
        data_dir: a ``--data`` directory overriding ``data.path``.
        segments: keep only this many leading segments (``None``: all).
    """
    from nanoslam_jax.app.experiment import load_log

    log = load_log(cfg, data_dir)
    seg = log.segments
    n = seg.time.shape[0] if segments is None else min(segments, seg.time.shape[0])
    seg = type(seg)(*(np.asarray(a)[:n] for a in seg))  # type: ignore[arg-type]  # numpy on the host
    return LogData(seg, np.asarray(log.raw.gps), log.frame, log.map_truth, log.source, log.survey, log.raw.truth_poses)


# --------------------------------------------------------------------------- the compiled program


class BatchOutput(NamedTuple):
    """What the sweep program returns per run (a leading batch axis when batched).

    Attributes:
        best_pose, mean_pose: ``(segments, 3)`` estimates.
        ess, iterations, n_associated: ``(segments,)`` per-segment records.
        n_capped, n_nonfinite, window_overflow: ``(segments,)`` counts.
        weight_reset: ``(segments,)`` all weights were reset.
        overflow: new landmarks dropped for lack of capacity.
        resample_count: resampling steps.
        map_mean, map_active, map_confirmed: the reported map (for the map metrics).
        map_ident: its landmarks' ids (known association), or None.
        path_pose: ``(segments, 3)`` the final best particle's ancestral path (``filter.estimate:
            path``; else None), followed back inside the program so that the particles' poses never
            leave it.
        noise: the final measurement-noise variances (``noise.adaptive``; else None), for
            :func:`~nanoslam_jax.methods.adaptive_noise_summary`.
        map_ident: the reported map's landmark ids (known association), or None.
        history_mean, history_held: ``(chunks, slots, 2)`` and ``(chunks, slots)``: the best
            particle's map at the end of every chunk of ``history_chunk`` segments (the
            :class:`~nanoslam_jax.methods.MapHistory` of a chunked run, for the smoother's
            ``smoother.map_history``), or None.
    """

    best_pose: Any
    mean_pose: Any
    ess: Any
    iterations: Any
    n_associated: Any
    n_capped: Any
    n_nonfinite: Any
    window_overflow: Any
    weight_reset: Any
    overflow: Any
    resample_count: Any
    map_mean: Any
    map_active: Any
    map_confirmed: Any
    path_pose: Any = None
    noise: Any = None
    map_ident: Any = None
    history_mean: Any = None
    history_held: Any = None


def _chunked_scan(static: Static, params: Params, key, segments: Segments, chunk: int):
    """The filter over ``segments`` in chunks of ``chunk`` segments, as ``run_filter`` drives it (the
    last chunk padded, its padding skipped), recording the best particle's confirmed landmarks at
    the end of every chunk. Returns the final state, the per-segment outputs and that history."""
    n = segments.time.shape[0]
    chunk = max(1, min(chunk, n))
    k = -(-n // chunk)
    pad = lambda a: jnp.concatenate([a, jnp.zeros((k * chunk - n,) + a.shape[1:], a.dtype)])  # noqa: E731
    pieces = jax.tree.map(lambda a: pad(jnp.asarray(a)).reshape((k, chunk) + a.shape[1:]), segments)
    valid = (jnp.arange(k * chunk) < n).reshape(k, chunk)

    def body(state, x):
        seg, ok = x
        state, out = filter_scan(static, params, seg, None, state, ok, skip_padding=True)
        lm = reported_map(state)
        return state, (out, lm.mean, lm.active & lm.confirmed)

    state, (outs, mean, held) = jax.lax.scan(body, initial_state(static, params, key), (pieces, valid))
    outs = jax.tree.map(lambda a: a.reshape((k * chunk,) + a.shape[2:])[:n], outs)
    return state, outs, (mean, held)


def _member(static: Static, params: Params, seed, segments: Segments, history_chunk: int = 0) -> BatchOutput:
    """One run: the filter from ``jax.random.key(seed)`` over all segments (as ``run_filter`` does);
    with ``history_chunk`` in chunks of that many segments, recording the map history."""
    if history_chunk:
        state, out, (h_mean, h_held) = _chunked_scan(static, params, jax.random.key(seed), segments, history_chunk)
    else:
        state, out = filter_scan(static, params, segments, jax.random.key(seed))
        h_mean = h_held = None
    lm = reported_map(state)
    n = segments.time.shape[0]

    def rec(name, dtype):
        v = getattr(out, name, None)
        return jnp.zeros(n, dtype) if v is None else v

    zero = jnp.zeros((), jnp.int32)
    return BatchOutput(
        best_pose=out.best_pose,
        mean_pose=out.mean_pose,
        ess=rec("ess", float),
        iterations=rec("iterations", float),
        n_associated=rec("n_associated", float),
        n_capped=rec("n_capped", jnp.int32),
        n_nonfinite=rec("n_nonfinite", jnp.int32),
        window_overflow=rec("window_overflow", jnp.int32),
        weight_reset=rec("weight_reset", bool),
        overflow=getattr(state, "overflow", zero),
        resample_count=resample_count(state),
        map_mean=lm.mean,
        map_active=lm.active,
        map_confirmed=lm.confirmed,
        path_pose=ancestral_path(out.poses, out.ancestors, state.best) if static.estimate.records_path else None,
        noise=noise_estimates(state) if static.adaptive_noise else None,
        map_ident=lm.ident,
        history_mean=h_mean,
        history_held=h_held,
    )


def _local_batch(
    static: Static, vectorize: str, params: Params, seeds, segments: Segments, history_chunk: int = 0
) -> BatchOutput:
    member = functools.partial(_member, static, history_chunk=history_chunk)
    if vectorize == "vmap":
        return jax.vmap(member, in_axes=(0, 0, None))(params, seeds, segments)
    return jax.lax.map(lambda ps: member(ps[0], ps[1], segments), (params, seeds))


@functools.partial(jax.jit, static_argnums=(0, 1, 2), static_argnames=("history_chunk",))
def batch_program(
    static: Static, vectorize: str, devices: int, params: Params, seeds, segments: Segments, history_chunk: int = 0
) -> BatchOutput:
    """A batch of runs in one compiled program.

    Args:
        static: the group's static settings.
        vectorize: ``'vmap'``: :func:`_member` vectorised over the batch (``jax.vmap``);
            ``'map'``: the members one after another in the program (``lax.map``), each computed
            exactly as a run alone (bit-identical to ``run_filter``).
        devices: split the batch over this many JAX devices (``shard_map``; 1: no split).
        params: hyperparameters with a leading batch axis on every leaf.
        seeds: ``(batch,)`` integer seeds.
        segments: the log's segments (shared by the batch).
        history_chunk: run each member in chunks of this many segments and record the best
            particle's map at the end of each (``BatchOutput.history_mean``, ``history_held``; the
            smoother's map history); 0: one scan, no history.
    """
    local = functools.partial(_local_batch, static, vectorize, history_chunk=history_chunk)
    if devices == 1:
        return local(params, seeds, segments)
    from jax.sharding import Mesh, PartitionSpec

    mesh = Mesh(np.array(jax.devices()[:devices]), ("batch",))
    split = PartitionSpec("batch")
    return jax.shard_map(local, mesh=mesh, in_specs=(split, split, PartitionSpec()), out_specs=split, check_vma=False)(
        params, seeds, segments
    )


@functools.partial(jax.jit, static_argnums=0)
def single_program(static: Static, params: Params, seed, segments: Segments) -> BatchOutput:
    """One run as its own program (the sequential baseline of the benchmark)."""
    return _member(static, params, seed, segments)


#: Compiled programs of this process: (Static, batch, segment shapes, devices) -> executable.
_PROGRAMS: dict[tuple, Any] = program_cache({})
#: Programs that failed to compile: key -> error message (later batches fail at once).
_FAILED: dict[tuple, str] = {}
#: One entry per compilation made by this process: dict(static, batch, devices, seconds).
_COMPILE_EVENTS: list[dict] = []


def compile_events() -> list[dict]:
    """The compilations this process made for sweeps (one per group shape, if all is well)."""
    return list(_COMPILE_EVENTS)


@dataclasses.dataclass(frozen=True)
class BatchTask:
    """One compiled call: up to ``batch`` runs of one group (padded to ``batch``).

    Attributes:
        group: the group label.
        static: the group's static settings.
        log_id: which log (index into the sweep's logs).
        params: stacked hyperparameters (numpy), ``batch`` long (padding repeats the first run).
        seeds: ``(batch,)`` seeds (padded likewise).
        n_real: how many leading members are real runs.
        metrics_opts: the ``metrics`` section (:class:`nanoslam_jax.app.config.MetricsConfig`) of each
            real run.
        fail_on_overflow: a landmark capacity overflow fails the run.
        run_ids: ids of the real runs.
        devices: split the batch over this many JAX devices (1: no split).
        vectorize: ``'vmap'`` or ``'map'`` (see :func:`batch_program`).
        smoother: the ``smoother`` section (:class:`nanoslam_jax.app.config.SmootherConfig`) when it is
            enabled: each run is smoothed on the host after the batch; else None.
        history_chunk: see :func:`batch_program` (``output.chunk`` with ``smoother.map_history``).
    """

    group: str
    static: Static
    log_id: int
    params: Params
    seeds: np.ndarray
    n_real: int
    metrics_opts: tuple
    fail_on_overflow: bool
    run_ids: tuple
    devices: int = 1
    vectorize: str = "vmap"
    smoother: Any = None
    history_chunk: int = 0

    @property
    def batch(self) -> int:
        return int(self.seeds.shape[0])


def _program_key(task: BatchTask, segments: Segments) -> tuple:
    return (
        task.static,
        task.vectorize,
        task.devices,
        task.batch,
        task.history_chunk,
        tuple((a.shape, str(a.dtype)) for a in segments if a is not None),
    )


def _place(task: BatchTask, segments: Segments):
    if task.devices > len(jax.devices()):
        raise RuntimeError(f"{task.devices} JAX devices requested, {len(jax.devices())} available")
    return jax.tree.map(jnp.asarray, task.params), jnp.asarray(task.seeds), jax.tree.map(jnp.asarray, segments)


def _first_line(e: BaseException, limit: int = 300) -> str:
    msg = str(e).strip().splitlines()
    text = f"{type(e).__name__}: {msg[0] if msg else ''}".strip()
    return text if len(text) <= limit else text[: limit - 3] + "..."


def batch_outputs(task: BatchTask, log: LogData) -> tuple[BatchOutput, float, float]:
    """Run one batch with the group's compiled program (compiled on first use).

    Returns:
        ``(outputs, compile_s, run_s)``: host outputs of all ``task.batch`` members (padding
        included), the time spent compiling (0 when the program was reused) and the execution time.

    Raises:
        Whatever compilation or execution raises.
    """
    key = _program_key(task, log.segments)
    if key in _FAILED:
        raise RuntimeError(_FAILED[key])
    args = _place(task, log.segments)
    compiled = _PROGRAMS.get(key)
    compile_s = 0.0
    if compiled is None:
        release_programs()
        t0 = time.perf_counter()
        try:
            with watched_compile(
                "sweep batch program", task.static, args, segments=int(log.segments.time.shape[0]), batch=task.batch
            ):
                compiled = batch_program.lower(
                    task.static, task.vectorize, task.devices, *args, history_chunk=task.history_chunk
                ).compile()
        except Exception as e:
            _FAILED[key] = f"compilation failed: {_first_line(e)}"
            raise RuntimeError(_FAILED[key]) from e
        compile_s = time.perf_counter() - t0
        _PROGRAMS[key] = compiled
        _COMPILE_EVENTS.append(dict(static=task.static, batch=task.batch, devices=task.devices, seconds=compile_s))
    t1 = time.perf_counter()
    out = jax.block_until_ready(compiled(*args))
    run_s = time.perf_counter() - t1
    return jax.tree.map(np.asarray, out), compile_s, run_s


@in_float64
def execute_batch(task: BatchTask, log: LogData) -> list[dict]:
    """Run one batch and score each real run.

    Never raises for a failing run: an exception (compilation or execution) fails every run of
    the batch with its reason; a non-finite estimate or (with ``fail_on_overflow``) a landmark
    capacity overflow fails that run.

    Returns:
        One dict per real run: ``status`` (``ok``/``failed``), ``reason``, the metrics, ``run_s``
        (the batch's execution time divided by its real runs) and ``compile_s`` (time spent
        compiling or loading the program for this batch, on the batch's first run; 0 otherwise).
    """
    try:
        host, compile_s, run_s = batch_outputs(task, log)
    except Exception as e:  # a failing group must not stop the sweep
        return [
            dict(status="failed", reason=f"error: {_first_line(e)}", run_s=math.nan, compile_s=0.0)
            for _ in range(task.n_real)
        ]
    run_s /= max(task.n_real, 1)
    rows = []
    for i in range(task.n_real):
        try:
            r = _score(i, host, log, task)
        except Exception as e:
            r = dict(status="failed", reason=f"metrics: {_first_line(e)}")
        r.update(run_s=run_s, compile_s=compile_s if i == 0 else 0.0)
        rows.append(r)
    return rows


def _smooth(i: int, out: BatchOutput, log: LogData, task: BatchTask, path: np.ndarray, *, lm: MapEstimate) -> Smoothed:
    """Member ``i``'s final best particle's path and map smoothed (as ``nanoslam run`` does after
    a run): its confirmed landmarks, and with ``smoother.map_history`` those it held at the end of
    an earlier chunk."""
    settings = SmootherSettings.from_config(task.smoother)
    final = np.asarray(lm.xy)[np.asarray(lm.confirmed, bool)]
    held = None
    if settings.map_history and out.history_mean is not None:
        held = held_landmarks(
            MapHistory(out.history_mean[i], out.history_held[i]), final, None, settings.map_history_radius
        )
    p_i = jax.tree.map(lambda a: np.asarray(a)[i], task.params)
    return smooth_run(path, final, log.segments, p_i, settings, task.static.prior, held)


def _score(i: int, out: BatchOutput, log: LogData, task: BatchTask) -> dict:
    """Metrics of member ``i`` (:func:`~nanoslam_jax.eval._scoring.score_run`, as every command scores
    a run; the smoothed path with ``smoother.enabled``) and its status."""
    static = task.static
    # The ancestral path is followed back in the program (path_pose); the others are recorded per segment.
    est = np.asarray(out.path_pose[i] if static.estimate.records_path else static.estimate.trajectory(out)[i])
    act = np.asarray(out.map_active[i], bool)
    lm = MapEstimate(
        np.asarray(out.map_mean[i])[act],
        np.asarray(out.map_confirmed[i])[act],
        None if out.map_ident is None else np.asarray(out.map_ident[i])[act],
    )
    sc = score_estimate(
        log,
        Tracks(est, out.best_pose[i], out.mean_pose[i]),
        static.estimate,
        task.metrics_opts[i],
        lm,
        None if task.smoother is None else functools.partial(_smooth, i, out, log, task, lm=lm),
        task.smoother,
    )
    m = sc.metrics
    if "smoother_converged" in m:
        m["smoother_converged"] = int(m["smoother_converged"])
    reasons = [sc.reason] if sc.reason else []
    m.update(filter_statistics(jax.tree.map(lambda a: a[i], out), out.overflow[i], out.resample_count[i]))
    overflow = m["landmark_overflow"]
    if out.noise is not None:
        p_i = jax.tree.map(lambda a: np.asarray(a)[i], task.params)
        m.update(adaptive_noise_summary(out.noise[i], configured_noise(static, p_i), float(p_i.noise_floor))[0])
    if overflow > 0 and task.fail_on_overflow:
        reasons.append(
            f"landmark capacity overflow: {overflow} new landmarks dropped (filter.capacity = {static.capacity})"
        )
    m["status"] = "failed" if reasons else "ok"
    m["reason"] = "; ".join(reasons)
    return m
