"""Executes a sweep: the batches :mod:`._plan` makes (one compiled program per group of runs
sharing a static shape, fixed-size batches over the traced hyperparameters and seeds, with
``jax.vmap``, or ``lax.map`` for runs bit-identical to single runs) run in this process, in worker
processes or on Ray; each batch's rows are appended to ``results.csv`` atomically; a sweep
resumes, records failed runs and reports progress. The programs are kept by :mod:`._batch` (which
also holds the log and a batch's execution and scoring).
"""

from __future__ import annotations

import dataclasses
import datetime as _dt
import json
import math
import os
import sys
import time
import traceback
from pathlib import Path
from typing import Any, Callable, Iterator, NamedTuple, Optional, Sequence

import yaml

from nanoslam_jax.lib._cache import enable_compile_cache
from nanoslam_jax._version import __version__
from nanoslam_jax.app.config import ConfigError
from nanoslam_jax.app._devices import SWEEP_DEVICES_PER_CORE, available_cores, setup_devices
from nanoslam_jax.methods import NOISE_ARC_SUMMARY_KEYS, NOISE_SUMMARY_KEYS, NasrukfStatic
from nanoslam_jax.app.registry import method_names
from nanoslam_jax.app._build import static_summary
from nanoslam_jax.app.sweep._batch import BatchTask, LogData, _first_line, execute_batch, load_log_data, log_key
from nanoslam_jax.app.sweep._results import (
    ResultsFile,
    read_results,
    select_best,
    summarize,
    write_best_yaml,
    write_summary,
)
from nanoslam_jax.app.sweep._expand import expand, spec_identity, spec_to_dict, stored_identity
from nanoslam_jax.app.sweep._plan import Group, logs_by_id, make_tasks, plan_groups, resolve_vectorize
from nanoslam_jax.app.sweep._spec import (
    MAP_METRIC_KEYS,
    METRIC_KEYS,
    SMOOTHER_METRIC_KEYS,
    SURVEY_METRIC_KEYS,
    ConfigPoint,
    Run,
    SweepSpec,
)
from nanoslam_jax.lib._precision import in_float64

__all__ = [
    "SweepOverrides",
    "SweepResult",
    "run_sweep",
    "resolve_parallel",
]

#: The default local mode on several cores, the fastest after compilation: one process, the batch
#: split over JAX CPU devices (``SWEEP_DEVICES_PER_CORE`` per core, see ``_devices.py``; the modes
#: compared: the docs' sweeps page, "Several cores", and ``experiments/sweep_benchmark.py``).
AUTO_PARALLEL = "devices"


# --------------------------------------------------------------------------- executors


def resolve_parallel(parallel: str, workers: Optional[int]) -> tuple[str, int]:
    """The local execution mode and worker count: ``auto`` is :data:`AUTO_PARALLEL` on several
    cores and ``single`` on one; ``workers`` defaults to the cores this process may use.

    (``devices`` needs JAX's CPU device count set before JAX's first computation; when that is
    too late, :func:`run_sweep` turns ``auto`` into ``processes``.)"""
    n = workers or available_cores()
    if parallel == "auto":
        parallel = AUTO_PARALLEL if n > 1 else "single"
    if parallel == "single":
        n = 1
    return parallel, max(1, n)


def _local_iter(tasks: Sequence[BatchTask], logs: dict[int, LogData]) -> Iterator[tuple[BatchTask, list[dict]]]:
    for t in tasks:
        yield t, execute_batch(t, logs[t.log_id])


def _worker_init(cores, cache_dir: Optional[str]) -> None:
    """Process-pool initializer: pin this worker to one core and share the compilation cache.

    The XLA flags stay those of the driver: JAX's persistent cache keys include them, so a
    worker loads the program the driver (or another worker) compiled instead of compiling it.
    """
    core = cores.get()
    if core is not None and hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, {core})
    if cache_dir:
        enable_compile_cache(cache_dir)


def _process_iter(
    tasks: Sequence[BatchTask], logs: dict[int, LogData], workers: int, cache_dir: Optional[str]
) -> Iterator[tuple[BatchTask, list[dict]]]:
    """Run batches in ``workers`` spawned processes, each pinned to its own core."""
    import concurrent.futures as cf
    import multiprocessing as mp

    ctx = mp.get_context("spawn")
    cores = ctx.Queue()
    avail = sorted(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else []
    for i in range(workers):
        cores.put(avail[i] if len(avail) >= workers else None)
    pool = cf.ProcessPoolExecutor(
        max_workers=workers, mp_context=ctx, initializer=_worker_init, initargs=(cores, cache_dir)
    )
    queue = list(tasks)
    running: dict = {}
    try:
        while queue or running:
            while queue and len(running) < 2 * workers:
                t = queue.pop(0)
                running[pool.submit(execute_batch, t, logs[t.log_id])] = t
            done, _ = cf.wait(list(running), return_when=cf.FIRST_COMPLETED)
            for f in done:
                t = running.pop(f)
                try:
                    res = f.result()
                except Exception as e:  # a worker died (e.g. out of memory): fail its batch, go on
                    res = [
                        dict(
                            status="failed",
                            reason=f"error: worker process: {_first_line(e)}",
                            run_s=math.nan,
                            compile_s=0.0,
                        )
                        for _ in range(t.n_real)
                    ]
                yield t, res
    finally:
        if queue or running:  # interrupted: do not wait for the batches in flight (they are not saved)
            for proc in list(getattr(pool, "_processes", {}).values()):
                proc.terminate()
        pool.shutdown(wait=not (queue or running), cancel_futures=True)


# --------------------------------------------------------------------------- progress


class Progress:
    """A progress bar ``sweep [###   ] done/total runs (pct), failed, elapsed, ETA`` on a stream (stderr).

    The estimate of the time left leaves compilation out (it is paid once per group).

    Args:
        total: runs in the sweep.
        done: runs finished before this session (resume).
        stream: where to write.
        enabled: write anything at all.
    """

    def __init__(self, total: int, done: int, stream=sys.stderr, enabled: bool = True):
        self.total, self.done, self.start_done = total, done, done
        self.failed = 0
        self.compile_s = 0.0
        self.stream, self.enabled = stream, enabled
        self.t0 = time.perf_counter()
        self.tty = bool(getattr(stream, "isatty", lambda: False)())

    def line(self) -> str:
        elapsed = time.perf_counter() - self.t0
        new = self.done - self.start_done
        left = self.total - self.done
        running = max(elapsed - self.compile_s, 1e-9)  # compilation is paid once per group, not per run
        eta = (
            f"~{_hms(running / new * left)} left"
            if new and left
            else ("done" if not left else "ETA after the first batch")
        )
        frac = self.done / max(self.total, 1)
        bar = "#" * int(round(24 * frac))
        return (
            f"sweep [{bar:<24}] {self.done}/{self.total} runs ({100 * frac:5.1f}%), {self.failed} failed, "
            f"{_hms(elapsed)} elapsed, {eta}"
        )

    def update(self, n_new: int, n_failed: int, compile_s: float = 0.0) -> None:
        self.done += n_new
        self.failed += n_failed
        self.compile_s += compile_s
        if self.enabled:
            end = "\n" if (self.done >= self.total or not self.tty) else "\r"
            self.stream.write(self.line() + end)
            self.stream.flush()

    def message(self, text: str) -> None:
        if self.enabled:
            self.stream.write(text + "\n")
            self.stream.flush()


def _hms(s: float) -> str:
    s = int(round(s))
    return f"{s // 3600}:{s % 3600 // 60:02d}:{s % 60:02d}" if s >= 3600 else f"{s // 60}:{s % 60:02d}"


# --------------------------------------------------------------------------- the driver


@dataclasses.dataclass(frozen=True)
class SweepResult:
    """What :func:`run_sweep` did.

    Attributes:
        out_dir: the sweep directory.
        n_runs: runs in the sweep.
        n_new: runs made in this call.
        n_skipped: runs found finished (``--resume``).
        n_failed: failed runs in ``results.csv``.
        best: the best configuration's summary (``None`` if none finished ok).
        groups: the shape groups.
    """

    out_dir: Path
    n_runs: int
    n_new: int
    n_skipped: int
    n_failed: int
    best: Optional[dict]
    groups: tuple


def _columns(spec: SweepSpec, metric_keys: Sequence[str]) -> list[str]:
    return [
        "run_id",
        "config_id",
        "group",
        *spec.swept_keys,
        "seed",
        "status",
        "reason",
        *metric_keys,
        "run_s",
        "compile_s",
    ]


def _write_atomic(path: Path, text: str) -> None:
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(text)
    os.replace(tmp, path)


def _first_difference(a: Any, b: Any, prefix: str = "") -> str:
    if isinstance(a, dict) and isinstance(b, dict):
        for k in list(dict.fromkeys([*a, *b])):
            if a.get(k) != b.get(k):
                return _first_difference(a.get(k), b.get(k), f"{prefix}{k}.")
    return prefix.rstrip(".") or "(top level)"


@dataclasses.dataclass(frozen=True)
class SweepOverrides:
    """Settings of one :func:`run_sweep` call that override the sweep file's ``run`` section.

    Each ``None`` keeps the file's setting.

    Attributes:
        backend: ``'local'`` or ``'ray'`` (``run.backend``).
        parallel: how the local backend uses several cores (``run.parallel``).
        workers: cores to use (``run.workers``).
        batch: runs per compiled call (``run.batch``).
        vectorize: how a batch is computed in its program (``run.vectorize``); a resumed sweep
            keeps the one it was started with.
    """

    backend: Optional[str] = None
    parallel: Optional[str] = None
    workers: Optional[int] = None
    batch: Optional[int] = None
    vectorize: Optional[str] = None


class _Execution(NamedTuple):
    """Where a sweep's batches run.

    Attributes:
        mode: ``'single'``, ``'devices'``, ``'processes'`` or ``'ray'``.
        workers: the cores of the local modes (the worker processes of ``'processes'``); 1 on Ray.
        devices: the JAX devices one batch is split over.
        split: how many batches run side by side (the batch size is chosen for that many at once).
    """

    mode: str
    workers: int
    devices: int
    split: int


@dataclasses.dataclass(frozen=True)
class _Plan:
    """What a sweep runs, before any batch runs.

    Attributes:
        points: the valid configurations.
        runs: every run (configuration x seed).
        skipped: the invalid configurations left out, as ``(values, reason)``.
        logs: ``log_key -> (log_id, LogData)``, each log the configurations read loaded once.
        groups: the shape groups.
        metric_keys: the metric columns of ``results.csv``.
        execution: where the batches run.
        vectorize: the resolved ``vectorize`` (``'vmap'`` or ``'map'``).
    """

    points: Sequence[ConfigPoint]
    runs: Sequence[Run]
    skipped: list
    logs: dict
    groups: list[Group]
    metric_keys: list[str]
    execution: _Execution
    vectorize: str


def _write_metadata(out: Path, spec: SweepSpec, plan: _Plan) -> None:
    """Write the resolved sweep, its base config, the versions, the groups and ``configs.csv``."""
    from nanoslam_jax.app.experiment import versions

    stamp = _dt.datetime.now().isoformat(timespec="seconds")
    d = spec_to_dict(spec)
    d["identity"] = spec_identity(spec)
    d["vectorize"] = plan.vectorize  # resolved; a resumed sweep keeps it (see run_sweep)
    d["skipped_invalid"] = [{"values": v, "reason": r} for v, r in plan.skipped]
    _write_atomic(
        out / "sweep.yaml",
        f"# resolved sweep, nanoslam-jax {__version__}, written {stamp}\n" + yaml.safe_dump(d, sort_keys=False),
    )
    _write_atomic(
        out / "base_config.yaml",
        f"# base configuration of sweep '{spec.name}'\n" + yaml.safe_dump(spec.base, sort_keys=False),
    )
    _write_atomic(
        out / "version.json",
        json.dumps({**versions(), "written": stamp, "command": " ".join(sys.argv)}, indent=2) + "\n",
    )
    by_id = logs_by_id(plan.logs)
    gd = {
        g.label: {
            "shapes": g.shape_values,
            "runs": len(g.runs),
            "batch": g.batch,
            "log": by_id[g.log_id].source,
            "segments": int(by_id[g.log_id].segments.time.shape[0]),
            "static": static_summary(g.static),
        }
        for g in plan.groups
    }
    _write_atomic(out / "groups.yaml", yaml.safe_dump(gd, sort_keys=False))
    lines = ["config_id,group," + ",".join(spec.swept_keys)]
    cfg_group = _config_groups(plan.groups)
    from nanoslam_jax.app.sweep._results import format_value

    for p in plan.points:
        lines.append(
            ",".join([p.config_id, cfg_group[p.config_id]] + [format_value(p.values[k]) for k in spec.swept_keys])
        )
    _write_atomic(out / "configs.csv", "\n".join(lines) + "\n")


def _config_groups(groups: Sequence[Group]) -> dict[str, str]:
    """``config_id -> group label``."""
    return {r.config_id: g.label for g in groups for r in g.runs}


def _check_out_dir(spec: SweepSpec, out: Path, resume: bool, vectorize: Optional[str]) -> Optional[str]:
    """Check that ``out`` may take this sweep: a fresh directory, or (``resume``) one the same sweep
    started; returns the ``vectorize`` to use (``vectorize``, else the resumed sweep's).

    Raises:
        ConfigError: ``out`` holds a sweep already (without ``resume``), none or a different one
            (with it), or one run with another ``vectorize``.
    """
    if not resume:
        if (out / "results.csv").exists():
            raise ConfigError(
                f"{out}: holds a sweep already (results.csv); pass --resume to continue it, or choose another --out"
            )
        return vectorize
    if not (out / "sweep.yaml").is_file():
        raise ConfigError(f"{out}: no sweep to resume here (sweep.yaml not found)")
    old = yaml.safe_load((out / "sweep.yaml").read_text()) or {}
    held, wanted = stored_identity(old.get("identity")), spec_identity(spec)
    if held != wanted:
        key = _first_difference(held, wanted)
        raise ConfigError(
            f"{out}: was made by a different sweep ('{key}' differs from {spec.source}); "
            f"resume it with the same sweep file, or choose another --out"
        )
    stored_vectorize = old.get("vectorize")
    opts = spec.run
    explicit = vectorize or (opts.vectorize if opts.vectorize != "auto" else None)
    if stored_vectorize and explicit and explicit != stored_vectorize:
        raise ConfigError(
            f"{out}: was run with vectorize '{stored_vectorize}'; resuming with '{explicit}' would "
            f"mix results that differ in rounding; resume with the same vectorize"
        )
    return vectorize or stored_vectorize


def _expand_registered(spec: SweepSpec) -> tuple[list[ConfigPoint], list[Run], list]:
    """The sweep's configurations, runs and skipped configurations (:func:`expand`).

    Raises:
        ConfigError: a configuration names a filter method that is not registered.
    """
    points, runs, skipped = expand(spec)
    for p in points:
        if p.config.filter.method not in method_names():
            raise ConfigError(
                f"{spec.source}: filter.method {p.config.filter.method!r} is not registered; "
                f"registered: {', '.join(method_names())}"
            )
    return points, runs, skipped


def _resolve_execution(spec: SweepSpec, overrides: SweepOverrides, prog: Progress) -> _Execution:
    """The execution mode, its cores and the devices of a batch. ``devices`` sets up JAX's CPU
    devices; when JAX started before the sweep, ``auto`` falls back to ``processes``."""
    opts = spec.run
    if (overrides.backend or opts.backend) == "ray":
        return _Execution("ray", 1, 1, spec.ray_num_cpus or 2)
    requested = overrides.parallel or opts.parallel
    mode, n_workers = resolve_parallel(requested, overrides.workers or opts.workers)
    devices = 1
    if mode == "devices":
        n_devices = n_workers * SWEEP_DEVICES_PER_CORE
        devices = min(setup_devices(n_devices), n_devices)
        if devices < n_workers and requested == "auto":  # JAX started before the sweep: next best
            mode, devices = "processes", 1
        elif devices < n_workers:
            prog.message(
                f"sweep: only {devices} JAX device(s) (JAX had started before the sweep); "
                f"set jax_num_cpu_devices first, or use parallel: processes"
            )
            if devices == 1:
                mode = "single"
    return _Execution(mode, n_workers, devices, n_workers if mode == "processes" else 1)


def _load_logs(points: Sequence[ConfigPoint], data_dir: Optional[str], segments: Any) -> dict:
    """``log_key -> (log_id, LogData)``: each log the configurations read, loaded once, in order."""
    logs: dict = {}
    for p in points:
        k = log_key(p.config)
        if k not in logs:
            logs[k] = (len(logs), load_log_data(p.config, data_dir, segments))
    return logs


def _metric_keys(logs: dict, groups: Sequence[Group]) -> list[str]:
    """The metric columns: the base metrics, and those of the map truth, the survey, the smoother
    and the adaptive noise estimates (where any run has them)."""
    metric_keys = list(METRIC_KEYS) + (
        list(MAP_METRIC_KEYS) if any(l.map_truth is not None for _, l in logs.values()) else []
    )
    metric_keys += list(SURVEY_METRIC_KEYS) if any(l.survey is not None for _, l in logs.values()) else []
    metric_keys += list(SMOOTHER_METRIC_KEYS) if any(g.runs[0].point.config.smoother.enabled for g in groups) else []
    if any(g.static.adaptive_noise for g in groups):  # where the adaptive noise estimates ended
        metric_keys += list(NOISE_SUMMARY_KEYS)
        if any(
            g.static.adaptive_noise
            and isinstance(g.static.method_settings, NasrukfStatic)
            and g.static.method_settings.feature == "arc"
            for g in groups
        ):
            metric_keys += list(NOISE_ARC_SUMMARY_KEYS)
    return metric_keys


def _plan_sweep(
    spec: SweepSpec,
    expanded: tuple[list[ConfigPoint], list[Run], list],
    vectorize: Optional[str],
    data_dir: Optional[str],
    overrides: SweepOverrides,
    prog: Progress,
) -> _Plan:
    """Choose where the sweep's runs (``expanded``: configurations, runs, skipped configurations)
    run, load their logs and group them into batches."""
    points, runs, skipped = expanded
    execution = _resolve_execution(spec, overrides, prog)
    resolved = resolve_vectorize(vectorize or spec.run.vectorize)
    logs = _load_logs(points, data_dir, spec.segments)
    groups = plan_groups(spec, runs, logs, batch=overrides.batch, split=execution.split, devices=execution.devices)
    return _Plan(points, runs, skipped, logs, groups, _metric_keys(logs, groups), execution, resolved)


def _open_results(rf: ResultsFile, out: Path, spec: SweepSpec, plan: _Plan, resume: bool) -> set:
    """Create ``out`` and its files (a fresh sweep), or check and repair ``results.csv`` (a resumed
    one); returns the run ids finished before."""
    out.mkdir(parents=True, exist_ok=True)
    if resume and rf.path.exists():
        try:
            rf.check_header()
        except ValueError as e:
            raise ConfigError(str(e)) from None
        rf.repair()
        return {r["run_id"] for r in read_results(rf.path)}
    _write_metadata(out, spec, plan)
    rf.create()
    return set()


def _announce(prog: Progress, spec: SweepSpec, plan: _Plan, tasks: Sequence[BatchTask], n_skipped: int) -> None:
    """Report the sweep's size, its batches and where they run, and the groups that cannot be split."""
    ex = plan.execution
    prog.message(
        f"sweep {spec.name}: {len(plan.points)} configurations x {len(spec.seeds)} seeds = {len(plan.runs)} runs in "
        f"{len(plan.groups)} shape group(s), {len(tasks)} batches ({ex.mode}, {plan.vectorize}"
        f"{f', {ex.workers} workers' if ex.mode == 'processes' else ''}"
        f"{f', {ex.devices} devices' if ex.devices > 1 else ''}); "
        f"{n_skipped} finished before"
        + (f", {len(plan.skipped)} invalid configurations skipped" if plan.skipped else "")
    )
    unsplit = sorted({t.group for t in tasks if t.devices < ex.devices})
    if unsplit:
        prog.message(
            f"sweep: {', '.join(unsplit)}: each batch on one device (optimistix's least squares "
            f"cannot run under shard_map)"
        )


def _batch_results(
    spec: SweepSpec, plan: _Plan, tasks: Sequence[BatchTask], cache_dir: Optional[str]
) -> Iterator[tuple[BatchTask, list[dict]]]:
    """The batches' results, as they finish, from the execution mode's executor."""
    by_id = logs_by_id(plan.logs)
    ex = plan.execution
    if ex.mode == "ray":
        from nanoslam_jax.app.sweep._ray import ray_iter

        return ray_iter(tasks, by_id, address=spec.ray_address, num_cpus=spec.ray_num_cpus, cache_dir=cache_dir)
    if ex.mode == "processes" and tasks:
        return _process_iter(tasks, by_id, ex.workers, cache_dir)
    return _local_iter(tasks, by_id)


def _run_batches(
    it: Iterator[tuple[BatchTask, list[dict]]],
    rf: ResultsFile,
    plan: _Plan,
    prog: Progress,
    on_batch: Optional[Callable[[list[dict]], None]],
) -> int:
    """Append each batch's rows to ``results.csv`` as it finishes and report progress; returns the
    runs made. The executor is closed however the loop ends."""
    run_meta = {r.run_id: r for r in plan.runs}
    groups_of = {r.run_id: g.label for g in plan.groups for r in g.runs}
    split = plan.execution.split
    n_new = 0
    try:
        for task, results in it:
            rows = []
            for rid, res in zip(task.run_ids, results):
                r = run_meta[rid]
                rows.append(
                    {
                        "run_id": rid,
                        "config_id": r.config_id,
                        "group": groups_of[rid],
                        **r.point.values,
                        "seed": r.seed,
                        **res,
                    }
                )
            rf.append(rows)
            n_new += len(rows)
            compile_s = sum(float(row.get("compile_s") or 0.0) for row in rows)
            # Workers compile side by side: their compile time overlaps.
            prog.update(len(rows), sum(row["status"] != "ok" for row in rows), compile_s / max(split, 1))
            if on_batch is not None:
                on_batch(rows)
    finally:
        close = getattr(it, "close", None)
        if close is not None:
            close()
    return n_new


def _finish(out: Path, spec: SweepSpec, plan: _Plan, prog: Progress, n_new: int) -> tuple[int, Optional[dict]]:
    """Write the summary, ``best.yaml`` and the plots from ``results.csv`` and report the best
    configuration; returns the failed runs recorded and the best configuration's summary."""
    rows = read_results(out / "results.csv")
    summary = summarize(rows, plan.points, _config_groups(plan.groups), plan.metric_keys, {spec.metric: spec.goal})
    best = select_best(summary, spec.metric, len(spec.seeds), spec.goal)
    complete = len({r["run_id"] for r in rows} & {r.run_id for r in plan.runs}) == len(plan.runs)
    write_summary(out, summary, spec, plan.metric_keys, best, complete)
    if best is not None:
        point = next(p for p in plan.points if p.config_id == best["config_id"])
        write_best_yaml(out / "best.yaml", spec, point, best)
    if spec.plots:
        from nanoslam_jax.app.sweep._plots import plot_sweep

        try:
            plot_sweep(out / "plots", spec, plan.points, rows, [spec.metric])
        except Exception as e:  # figures must never lose a sweep
            prog.message(f"sweep: plots failed: {_first_line(e)}\n{traceback.format_exc(limit=3)}")
    n_failed = sum(r["status"] != "ok" for r in rows)
    prog.message(
        f"sweep {spec.name}: {len(rows)} runs recorded ({n_failed} failed), {n_new} now; "
        + (
            f"best {best['config_id']} ({spec.metric} median {best[f'{spec.metric}_median']:.4g})"
            if best
            else "no configuration finished ok"
        )
    )
    return n_failed, best


@in_float64
def run_sweep(
    spec: SweepSpec,
    out_dir: str | os.PathLike,
    *,
    resume: bool = False,
    data_dir: Optional[str] = None,
    progress: bool = True,
    stream=sys.stderr,
    on_batch: Optional[Callable[[list[dict]], None]] = None,
    overrides: SweepOverrides = SweepOverrides(),
) -> SweepResult:
    """Run (or resume) a sweep and write its directory.

    Args:
        spec: the validated sweep.
        out_dir: the sweep directory (created). It keeps ``sweep.yaml`` (the resolved sweep),
            ``base_config.yaml``, ``version.json``, ``configs.csv``, ``groups.yaml``,
            ``results.csv``, and at the end ``summary.csv``, ``summary.md``, ``best.yaml`` and
            ``plots/``.
        resume: continue the sweep in ``out_dir``, skipping the runs ``results.csv`` holds.
        data_dir: log directory overriding ``data.path``.
        progress: report progress on ``stream``.
        stream: where progress goes (stderr).
        on_batch: called with each batch's rows after they are on disk (a hook for callers).
        overrides: settings overriding ``spec.run`` (backend, parallel, workers, batch, vectorize).

    Raises:
        ConfigError: ``out_dir`` holds a sweep already (without ``resume``), or a different one.
        KeyboardInterrupt: passed on after the finished batches are saved (resume later).
    """
    out = Path(out_dir)
    vectorize = _check_out_dir(spec, out, resume, overrides.vectorize)
    points, runs, skipped = _expand_registered(spec)
    prog = Progress(len(runs), 0, stream, progress)
    plan = _plan_sweep(spec, (points, runs, skipped), vectorize, data_dir, overrides, prog)
    rf = ResultsFile(out / "results.csv", _columns(spec, plan.metric_keys))
    done = _open_results(rf, out, spec, plan, resume)
    cache_dir = enable_compile_cache() if spec.run.compile_cache else None
    tasks = make_tasks(spec, plan.groups, plan.logs, done, devices=plan.execution.devices, vectorize=plan.vectorize)
    n_skipped = sum(1 for r in plan.runs if r.run_id in done)
    prog.done = prog.start_done = n_skipped
    _announce(prog, spec, plan, tasks, n_skipped)
    n_new = _run_batches(_batch_results(spec, plan, tasks, cache_dir), rf, plan, prog, on_batch)
    n_failed, best = _finish(out, spec, plan, prog, n_new)
    return SweepResult(out, len(plan.runs), n_new, n_skipped, n_failed, best, tuple(plan.groups))
