"""Method comparison over seeds: the paper's Table I and Figures 3-5.

A comparison file names a base config, the methods (each a label and ``key=value`` overrides
of the base, at least ``filter.method``), the number of seeds and optionally the paper's
figures to print beside ours::

    name: table1
    base: victoria_park_nano.yaml     # relative to this file; null: the embedded default
    seeds: 8
    first_seed: 0
    timing_chunk: 250                 # segments per timed chunk (Fig. 5 resolution)
    set: []                           # overrides applied to every method
    methods:
      - label: NANO-SLAM
        set: [filter.method=nano]
        paper_rmse: 2.538
        paper_ms: 17.692
      - label: the paper setting
        base: victoria_park_nano.yaml # this row's own base config (relative to this file)

A row's ``base`` replaces the comparison's base for that row (its ``set`` and the comparison's
``set`` still apply), so rows of different configs can be compared on the same seeds
(``configs/recommended.yaml``).

``seed_keys: [indoor.seed]`` makes each seed its own world: every row runs once per seed with
``seed`` and those keys set to it, all rows of a seed on the same simulated log, each run the run
of ``nanoslam run``; the feature map's table (the second paper's Table 1) and its Figures 5 and 6
are written too (:mod:`nanoslam_jax.app._compare_worlds`, ``configs/nasrukf_indoor_study.yaml``).

For each method the seeds run vmapped in one compiled program (:func:`filter.run_batch`); a
separate single run of the first seed, timed chunk by chunk, gives the computation time per
scan (the table's ms per scan and Fig. 5). EKF-SLAM, NASRUKF and dead reckoning are deterministic
and run once. With ``smoother.enabled`` (``filter.estimate: path``) each seed's final best particle's
path and map are smoothed after the batch (:mod:`nanoslam_jax.smoother._smoother`), and the smoothed path is
scored, with the path it started from beside it (``rmse_*_path``) and the filter's own estimate of the
same runs, the best particle's pose at each scan (``rmse_*_best``, a row of its own in ``table1.md``). Every run is scored by
:func:`nanoslam_jax.eval._scoring.score_run` and the seeds summarised by
:func:`nanoslam_jax.eval._scoring.summarize_runs`: a failed seed (non-finite estimate, exception) is
counted and named, and counts as an infinite error in the medians, quartiles and worst seed. A
method that fails as a whole (bad config, exception) is recorded with its reason; the others still
run.

Writes ``table1.md``, ``table1.csv`` (one row per method), ``runs.csv`` (one row per method and
seed), ``summary.json``, ``compare.yaml`` (the resolved comparison with the version), the resolved
config of each method under ``configs/``, and ``fig3_trajectories.png``, ``fig4_error.png``,
``fig5_time.png``.
"""

from __future__ import annotations

import json
import sys
import time
import traceback
from pathlib import Path
from typing import Any, Callable, NamedTuple, Optional

import jax
import numpy as np
import yaml

from nanoslam_jax.app._compare_spec import (
    CompareSpec,
    MethodSpec,
    deterministic,
    int_at_least,
    load_compare_spec,
    method_config,
    method_rows,
    read_comparison,
    resolve_base,
    seed_config,
    str_list,
)
from nanoslam_jax._version import __version__
from nanoslam_jax.eval._scoring import (
    MapEstimate,
    failure_reason,
    format_number,
    score_run,
)
from nanoslam_jax.app.config import Config, ConfigError, config_to_dict
from nanoslam_jax.methods import dead_reckoning, reported_map, run_batch, run_filter, stack_params
from nanoslam_jax.app.filters import settings_from_config
from nanoslam_jax.smoother._smoother import smooth_filter_run
from nanoslam_jax.app._scored import Tracks, score_estimate
from nanoslam_jax.app._compare_report import (
    FEATURE_KEYS as FEATURE_KEYS,
    MethodResult as MethodResult,
    RMSE_KEYS as RMSE_KEYS,
    SUMMARY_KEYS as SUMMARY_KEYS,
    _write_outputs as _write_outputs,
    log_key as log_key,
    markdown_table as markdown_table,
    summarise as summarise,
    write_resolved as write_resolved,
)
from nanoslam_jax.lib._precision import in_float64

__all__ = [
    "CompareSpec",
    "MethodResult",
    "MethodSpec",
    "deterministic",
    "filter_key",
    "int_at_least",
    "log_key",
    "load_compare_spec",
    "markdown_table",
    "method_config",
    "method_rows",
    "read_comparison",
    "resolve_base",
    "run_compare",
    "run_method",
    "seed_config",
    "str_list",
    "summarise",
    "write_resolved",
]


def _map_of(maps, i: int) -> MapEstimate:
    act = np.asarray(maps.active[i], bool)
    ids = None if getattr(maps, "ident", None) is None else np.asarray(maps.ident[i])[act]
    return MapEstimate(np.asarray(maps.mean[i])[act], np.asarray(maps.confirmed[i])[act], ids)


def filter_key(cfg: Config, seeds) -> str:
    """What a method's filter runs depend on: its config without the offline smoother (and the name)
    and the seeds. Rows of a comparison with the same key share their filter runs (``run_method``'s
    ``cache``), e.g. the smoother ablations of configs/recommended.yaml."""
    d = config_to_dict(cfg)
    for k in ("smoother", "name"):
        d.pop(k, None)
    return json.dumps([d, [int(s) for s in seeds]], sort_keys=True, default=str)


class _RunCache:
    """The filter runs of one :func:`filter_key`, by kind (``'timed'``, ``'single'``, ``'batch'``),
    kept in a caller's ``cache`` (None: each run is computed anew)."""

    def __init__(self, cache: Optional[dict], key: str):
        self.cache, self.key = cache, key

    def get(self, kind: str, compute: Callable[[], Any]) -> Any:
        """The run of ``kind``: the kept one, else ``compute()`` (kept)."""
        if self.cache is None:
            return compute()
        if (self.key, kind) not in self.cache:
            self.cache[(self.key, kind)] = compute()
        return self.cache[(self.key, kind)]


class _SeedRuns(NamedTuple):
    """The filter runs of a method's seeds, as they are smoothed and scored.

    Attributes:
        run: the run the smoother starts from (the single run, or the batch).
        batched: whether ``run`` is a batch (seed ``i`` its member ``i``).
        maps: the reported maps, one per seed (leading axis).
        overflow: the landmark overflow of each seed.
        estimates: the reported trajectory of each seed.
        best: the best particle's pose of each seed.
        mean: the mean pose of each seed.
        run_s: the run time (the single run's, or the batch's).
    """

    run: Any
    batched: bool
    maps: Any
    overflow: np.ndarray
    estimates: Any
    best: np.ndarray
    mean: np.ndarray
    run_s: float


def _run_dead_reckoning(
    res: MethodResult, cfg: Config, log, params, first_seed: int, keep_trajectories: bool
) -> MethodResult:
    """Dead reckoning (once, deterministic): timed after a first call that compiles, and scored."""
    seg = log.segments
    n = int(seg.time.shape[0])
    t0 = time.perf_counter()
    jax.block_until_ready(dead_reckoning(params, seg))
    t1 = time.perf_counter()
    est = np.asarray(dead_reckoning(params, seg))
    res.ms_per_scan = 1e3 * (time.perf_counter() - t1) / n
    res.compile_s = t1 - t0
    res.trajectory = est
    res.trajectories = [est] if keep_trajectories else None
    reason = failure_reason(np.asarray(seg.time), est)
    res.rows.append(
        {
            "seed": first_seed,
            "status": "failed" if reason else "ok",
            "reason": reason,
            **score_run(log, est, cfg.metrics),
            "n_landmarks": 0,
            "n_confirmed": 0,
        }
    )
    if reason:
        res.status, res.reason = "failed", reason
    return res


def _record_timing(res: MethodResult, single: Any, t: np.ndarray) -> None:
    """The compile time, the time per scan and each chunk's time per scan of the timed run."""
    n = len(t)
    res.compile_s = single.compile_s
    res.ms_per_scan = 1e3 * single.run_s / n
    sizes = np.minimum(single.chunk_size, n - single.chunk_size * np.arange(len(single.chunk_s)))
    res.chunk_ms = 1e3 * np.asarray(single.chunk_s) / sizes
    mids = np.minimum(single.chunk_size * np.arange(len(sizes)) + sizes // 2, n - 1)
    res.chunk_t = t[mids]


def _single_seed_runs(cfg: Config, settings: tuple, seg, first_seed: int, single: Any, runs: _RunCache) -> _SeedRuns:
    """The one seed's run (``single``, or a run chunked as ``nanoslam run`` chunks it when the
    smoother reads the map history)."""
    static, params = settings
    n = int(seg.time.shape[0])
    run = single
    if cfg.smoother.enabled and cfg.smoother.map_history and single.chunk_size != min(cfg.output.chunk, n):
        # The smoother's map history is the map at the end of each chunk of output.chunk
        # segments: the scored run is chunked as `nanoslam run` chunks it.
        single = run = runs.get("single", lambda: run_filter(static, params, seg, first_seed, chunk=cfg.output.chunk))
    maps = jax.tree.map(lambda a: np.asarray(a)[None], reported_map(single.state))
    overflow = np.asarray(single.state.overflow)[None]
    est_all = static.estimate.trajectory(single.outputs, single.state)[None]
    best_all, mean_all = (np.asarray(a)[None] for a in (single.outputs.best_pose, single.outputs.mean_pose))
    return _SeedRuns(run, False, maps, overflow, est_all, best_all, mean_all, single.run_s)


def _batch_runs(cfg: Config, settings: tuple, seg, seeds: list[int], progress, runs: _RunCache) -> _SeedRuns:
    """Every seed in one vmapped batch."""
    static, params = settings
    run = runs.get(
        "batch",
        lambda: run_batch(
            static,
            stack_params([params] * len(seeds)),
            seg,
            np.asarray(seeds),
            chunk=cfg.output.chunk,
            progress=progress,
        ),
    )
    maps = jax.tree.map(np.asarray, jax.vmap(reported_map)(run.state))
    overflow = np.asarray(run.state.overflow)
    est_all = static.estimate.trajectory(run.outputs, run.state)
    best_all, mean_all = np.asarray(run.outputs.best_pose), np.asarray(run.outputs.mean_pose)
    return _SeedRuns(run, True, maps, overflow, est_all, best_all, mean_all, run.run_s)


def _score_seeds(
    res: MethodResult, cfg: Config, log, settings: tuple, seeds: list[int], sr: _SeedRuns
) -> list[np.ndarray]:
    """Smooth (with ``smoother.enabled``) and score each seed's run into ``res.rows``; returns the
    scored trajectories."""
    static, params = settings
    seg = log.segments
    trajectories = []
    for i, s in enumerate(seeds):
        smooth = None
        if cfg.smoother.enabled:  # the path and its map refined offline, per seed
            member = i if sr.batched else None
            smooth = lambda est, m=member: smooth_filter_run(sr.run, est, seg, params, cfg.smoother, static.prior, m)  # noqa: E731
        tracks = Tracks(sr.estimates[i], sr.best[i], sr.mean[i])
        sc = score_estimate(log, tracks, static.estimate, cfg.metrics, _map_of(sr.maps, i), smooth, cfg.smoother)
        res.rows.append(
            {
                "seed": int(s),
                "status": "failed" if sc.reason else "ok",
                "reason": sc.reason,
                **sc.metrics,
                "landmark_overflow": int(sr.overflow[i]),
            }
        )
        trajectories.append(sc.trajectory)
    return trajectories


def run_method(
    spec: CompareSpec,
    m: MethodSpec,
    log,
    progress=None,
    timed: bool = True,
    keep_trajectories: bool = False,
    cache: Optional[dict] = None,
) -> MethodResult:
    """Run one method over the seeds (vmapped) and once more, timed, for the time per scan; with
    ``smoother.enabled`` each seed's run is smoothed after the batch; every seed is scored
    (:func:`~nanoslam_jax.eval._scoring.score_run`).

    Args:
        spec: the comparison.
        m: the row to run.
        log: the loaded log (:func:`~nanoslam_jax.app.experiment.load_log`).
        progress: progress callback of the batch run.
        timed: also run the first seed alone, chunk by chunk, for the time per scan (False: the
            time columns are NaN).
        keep_trajectories: keep every seed's scored trajectory in ``trajectories`` (else only the
            first seed's, in ``trajectory``).
        cache: filter runs by :func:`filter_key` (and kind), reused instead of run again: a row
            that differs from an earlier one only in its smoother settings smooths and scores the
            same runs. None: nothing is shared.
    """
    cfg = method_config(spec, m)
    method = cfg.filter.method
    seg = log.segments
    n = int(seg.time.shape[0])
    t = np.asarray(seg.time)
    static, params = settings_from_config(cfg, seg.k_max, n)
    res = MethodResult(m, method, rows=[])
    seeds = [spec.first_seed] if deterministic(method) else list(range(spec.first_seed, spec.first_seed + spec.seeds))
    if method == "dead_reckoning":
        return _run_dead_reckoning(res, cfg, log, params, spec.first_seed, keep_trajectories)

    runs = _RunCache(cache, filter_key(cfg, seeds))
    single = None
    if timed:  # one run of the first seed, chunk by chunk
        single = runs.get(
            "timed",
            lambda: run_filter(static, params, seg, spec.first_seed, chunk=min(spec.timing_chunk, n), timed=True),
        )
        _record_timing(res, single, t)
    elif len(seeds) == 1:
        single = runs.get("single", lambda: run_filter(static, params, seg, spec.first_seed, chunk=cfg.output.chunk))
    if len(seeds) == 1:
        sr = _single_seed_runs(cfg, (static, params), seg, spec.first_seed, single, runs)
    else:
        sr = _batch_runs(cfg, (static, params), seg, seeds, progress, runs)
    res.batch_run_s = sr.run_s
    trajectories = _score_seeds(res, cfg, log, (static, params), seeds, sr)
    res.trajectory = trajectories[0]
    if keep_trajectories:
        res.trajectories = trajectories
    maps = sr.maps
    res.landmarks = maps.mean[0][maps.active[0] & maps.confirmed[0]]
    bad = [r["seed"] for r in res.rows if r["status"] != "ok"]
    if bad:
        res.status, res.reason = "failed", f"non-finite estimate for seed(s) {bad}"
    return res


@in_float64
def run_compare(
    spec: CompareSpec, out_dir: str | Path, data_dir: Optional[str] = None, plots: bool = True, stream=sys.stderr
) -> list[dict]:
    """Run every method of ``spec`` and write the comparison directory.

    Args:
        spec: the comparison.
        out_dir: result directory (created).
        data_dir: log directory overriding ``data.path``.
        plots: draw Figures 3-5.
        stream: where progress lines go.

    Returns:
        The table rows (also in ``table1.csv``).
    """
    from nanoslam_jax.app.experiment import load_log

    if spec.seed_keys:  # each seed its own log: one run per seed and row
        from nanoslam_jax.app._compare_worlds import run_worlds

        if data_dir is not None:
            raise ConfigError(
                f"{spec.source}: key 'seed_keys' gives every seed its own simulated log, and --data names one log; "
                f"drop --data, or drop seed_keys to run the seeds on that log"
            )
        return run_worlds(spec, Path(out_dir), plots, stream)
    out = Path(out_dir)
    configs = {m.label: method_config(spec, m) for m in spec.methods}
    logs: dict[str, Any] = {}
    first = next(iter(configs.values()))
    key_of = log_key
    logs[key_of(first)] = load_log(first, data_dir)  # a bad log fails before anything is written
    if not len(logs[key_of(first)].raw.gps) and logs[key_of(first)].reference is None:
        raise ConfigError(
            f"{spec.source}: compare scores the trajectories against GPS or a reference path "
            f"(data.reference), and the log {logs[key_of(first)].source} has neither; score its map "
            f"with `nanoslam sweep` (metric: survey_rmse) or `nanoslam run`"
        )
    write_resolved(out, spec)

    def seeds_of(c: Config) -> list[int]:
        return (
            [spec.first_seed]
            if deterministic(c.filter.method)
            else list(range(spec.first_seed, spec.first_seed + spec.seeds))
        )

    # Rows that differ only in the smoother share their filter runs; each is kept while a later row needs it.
    keys = [filter_key(configs[m.label], seeds_of(configs[m.label])) for m in spec.methods]
    shared: dict = {}
    results: list[MethodResult] = []
    for i, m in enumerate(spec.methods):
        for kk in [kk for kk in shared if kk[0] not in keys[i:]]:
            del shared[kk]
        cfg = configs[m.label]
        safe = "".join(ch if ch.isalnum() or ch in "-_." else "_" for ch in m.label)
        (out / "configs" / f"{safe}.yaml").write_text(
            f"# nanoslam-jax {__version__}, seeds {spec.first_seed}..{spec.first_seed + spec.seeds - 1}\n"
            + yaml.safe_dump(config_to_dict(cfg), sort_keys=False)
        )
        stream.write(f"[{i + 1}/{len(spec.methods)}] {m.label} ({cfg.filter.method})\n")
        stream.flush()
        t0 = time.perf_counter()
        try:
            k = key_of(cfg)
            if k not in logs:
                logs[k] = load_log(cfg, data_dir)
            res = run_method(spec, m, logs[k], cache=shared)
        except Exception as e:  # recorded, the comparison goes on
            reason = f"{type(e).__name__}: {e}"
            seeds = seeds_of(cfg)
            res = MethodResult(
                m,
                cfg.filter.method,
                rows=[{"seed": s, "status": "failed", "reason": reason} for s in seeds],
                status="failed",
                reason=reason,
            )
            (out / f"error-{safe}.txt").write_text(traceback.format_exc())
        results.append(res)
        r = summarise(res)
        score = (
            f"path error against the reference {format_number(r['ref_rmse_median'])} m"
            if "ref_rmse_median" in r
            else f"rmse_fixed {format_number(r['rmse_fixed_median'])}, rmse_aligned {format_number(r['rmse_aligned_median'])}"
        )
        stream.write(
            f"    {res.status} in {time.perf_counter() - t0:.1f} s: {score}, {format_number(res.ms_per_scan, 2)} ms/scan\n"
        )
        stream.flush()
        # Written after every method: an interrupted comparison keeps what it finished.
        _write_outputs(out, spec, results)

    if plots:
        _figures(out, spec, results, logs, configs)
    return [summarise(r) for r in results]


def _figures(out: Path, spec: CompareSpec, results: list[MethodResult], logs: dict, configs: dict) -> None:
    from nanoslam_jax.eval.plotting import plot_series

    ok = [r for r in results if r.trajectory is not None and np.all(np.isfinite(r.trajectory))]
    if not ok:
        return
    cfg = configs[ok[0].spec.label]
    log = next(iter(logs.values()))
    if not len(log.raw.gps) and log.reference is not None:
        _reference_figures(out, spec, ok, log)
    else:
        _gps_figures(out, spec, ok, log, cfg)
    timed = [(r.spec.label, r.chunk_t, r.chunk_ms) for r in results if r.chunk_ms is not None]
    if timed:
        plot_series(
            out / "fig5_time.png",
            timed,
            "computation time per scan [ms]",
            f"{spec.name}: time per scan (mean over chunks of {spec.timing_chunk} scans)",
            logy=True,
            marker=".",
        )


def _reference_figures(out: Path, spec: CompareSpec, ok: list[MethodResult], log) -> None:
    """Figures 3 and 4 against a reference path: every path aligned onto it, and the aligned error
    at the reference poses."""
    from nanoslam_jax.eval import align_on_reference
    from nanoslam_jax.eval.plotting import plot_series, plot_trajectory_grid

    t = np.asarray(log.segments.time)
    ref = log.reference
    aligned = [(r.spec.label, *align_on_reference(ref, t, r.trajectory)) for r in ok]
    plot_trajectory_grid(
        out / "fig3_trajectories.png",
        ref.poses[:, :2],
        [(label, path, None) for label, path, _ in aligned],
        reference_label=f"reference ({ref.source})",
        title=f"{spec.name}: seed {spec.first_seed}, each path rigidly aligned onto the reference",
    )
    plot_series(
        out / "fig4_error.png",
        [(label, err[:, 0] - t[0], err[:, 1]) for label, _, err in aligned],
        "position error [m]",
        f"{spec.name}: error against the reference path after alignment (seed {spec.first_seed}; time from the log's start)",
    )


def _gps_figures(out: Path, spec: CompareSpec, ok: list[MethodResult], log, cfg: Config) -> None:
    """Figures 3 and 4 against GPS (or a simulated log's truth)."""
    from nanoslam_jax.eval.metrics import error_over_time, jump_mask, relative_gps
    from nanoslam_jax.eval.plotting import plot_series, plot_trajectory_grid

    gps = log.raw.gps
    t = np.asarray(log.segments.time)
    ref = relative_gps(gps[:, 1:3], cfg.metrics.gps_rotation_deg) if log.frame == "relative" else gps[:, 1:3]
    ref_label = "GPS (relative frame)" if log.frame == "relative" else "truth"
    plot_trajectory_grid(
        out / "fig3_trajectories.png",
        ref,
        [(r.spec.label, r.trajectory[:, :2], r.landmarks) for r in ok],
        true_landmarks=log.raw.truth_landmarks,
        reference_label=ref_label,
        title=f"{spec.name}: seed {spec.first_seed}",
    )
    series = []
    keep = jump_mask(gps[:, 0], gps[:, 1:3], cfg.metrics.jump_speed)  # GPS jumps would dwarf the errors
    for r in ok:
        te, err = error_over_time(
            t, r.trajectory[:, :2], gps[keep], rotation_deg=cfg.metrics.gps_rotation_deg, frame=log.frame
        )
        series.append((r.spec.label, te, err))
    plot_series(
        out / "fig4_error.png",
        series,
        "position error [m]",
        f"{spec.name}: error against {ref_label}, GPS jumps removed (seed {spec.first_seed})",
    )
