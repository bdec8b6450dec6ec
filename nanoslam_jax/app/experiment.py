"""One run from a :class:`Config`: log -> segments -> filter -> outputs -> metrics -> plots.

:func:`run_experiment` writes a result directory holding the resolved ``config.yaml``,
``metrics.json`` (with the version and seed), ``trajectory.csv``, ``map.csv`` (filters) and the
figures.
"""

from __future__ import annotations

import dataclasses
import datetime as _dt
import json
import math
import platform
import shutil
import sys
import time
from pathlib import Path
from typing import Any, NamedTuple, Optional

import jax
import numpy as np
import yaml

from nanoslam_jax.lib._cache import compile_stats
from nanoslam_jax._version import __version__
from nanoslam_jax.app.config import Config, ConfigError, config_to_dict
from nanoslam_jax.data import (
    Segments,
)
from nanoslam_jax.data._mrclam import sighting_map as _project_sightings
from nanoslam_jax.methods import (
    NasrukfStatic,
    Params,
    Static,
    adaptive_noise_summary,
    adaptive_process_summary,
    configured_noise,
    dead_reckoning,
    noise_estimates,
    reported_map,
    run_filter,
    text_progress,
)
from nanoslam_jax.app.filters import settings_from_config
from nanoslam_jax.methods._scan import is_gaussian, resample_count
from nanoslam_jax.eval.metrics import (
    evaluate,
    map_alignment_metrics,
    rmse_heading_deg,
)
from nanoslam_jax.eval._scoring import MapEstimate, score_run, with_arcs
from nanoslam_jax.smoother._smoother import smooth_filter_run
from nanoslam_jax.app._scored import Tracks, filter_statistics, score_estimate
from nanoslam_jax.lib._precision import in_float64
from nanoslam_jax.app._load import (
    LoadedLog as LoadedLog,
    Survey as Survey,
    circle_table as circle_table,
    feature_table as feature_table,
    load_log as load_log,
    odometry_controls as odometry_controls,
    with_laser_detections as with_laser_detections,
    with_scan_detections as with_scan_detections,
)
from nanoslam_jax.app._map_table import (
    MAP_COLUMNS as MAP_COLUMNS,
    MAP_ID_COLUMN as MAP_ID_COLUMN,
    _map_layout as _map_layout,
    map_columns as map_columns,
    map_table as map_table,
)
from nanoslam_jax.app._run_figures import write_run_figures


def sighting_map(poses: np.ndarray, segments: Segments) -> tuple[np.ndarray, np.ndarray]:
    """Every detection of known id projected from the pose of its segment and averaged per id:
    the map that a path alone gives (from the dead-reckoned path, the baseline a SLAM map is read
    against).

    Args:
        poses: ``(segments, 3)`` the pose ``(x, y, phi)`` of the sensor at each segment.
        segments: the log's segments (range-bearing detections with ``z_id``).

    Returns:
        ``(ids, xy)``: the ids seen, increasing, and ``(K, 2)`` the mean position of each.
    """
    z = np.asarray(segments.z, dtype=float)
    ids = np.asarray(segments.z_id)
    use = np.asarray(segments.z_mask) & (ids >= 0)
    p = np.broadcast_to(np.asarray(poses, dtype=float)[:, None, :], z.shape[:2] + (3,))[use]
    m = _project_sightings(p, z[use][:, 0], z[use][:, 1], ids[use])
    return m.ids, m.xy


def default_out_dir(cfg: Config, root: str | Path = "results") -> Path:
    """``results/<config-name>-<timestamp>``."""
    stamp = _dt.datetime.now().strftime("%Y%m%d-%H%M%S")
    out = Path(root) / f"{cfg.name}-{stamp}"
    k = 2
    while out.exists():  # never reuse a directory of an earlier run
        out = Path(root) / f"{cfg.name}-{stamp}-{k}"
        k += 1
    return out


def versions() -> dict:
    """Versions of the software a result was produced with."""
    import equinox
    import optimistix

    return {
        "nanoslam_jax": __version__,
        "jax": jax.__version__,
        "equinox": equinox.__version__,
        "optimistix": optimistix.__version__,
        "numpy": np.__version__,
        "python": platform.python_version(),
    }


def adaptive_noise_report(static: Static, params: Params, state) -> tuple[dict, list[str]]:
    """:func:`~nanoslam_jax.methods.adaptive_noise_summary` of a run's final state.

    Args:
        static: the run's static settings (``noise.adaptive`` on).
        params: its hyperparameters (the configured noise and ``noise_floor``).
        state: the filter's final state (a particle filter's or NASRUKF's).

    Returns:
        ``(metrics, warnings)`` as :func:`~nanoslam_jax.methods.adaptive_noise_summary` gives them.
    """
    return adaptive_noise_summary(
        np.asarray(noise_estimates(state)), np.asarray(configured_noise(static, params)), float(params.noise_floor)
    )


def _write_csv(path: Path, header: list[str], rows: np.ndarray, fmt: str = "%.6f") -> None:
    np.savetxt(path, rows, delimiter=",", header=",".join(header), comments="", fmt=fmt)


def _json_safe(d: dict) -> dict:
    out = {}
    for k, v in d.items():
        if isinstance(v, dict):
            out[k] = _json_safe(v)
        elif isinstance(v, (np.floating, float)):
            out[k] = None if not math.isfinite(float(v)) else float(v)
        elif isinstance(v, (np.integer,)):
            out[k] = int(v)
        elif isinstance(v, np.bool_):
            out[k] = bool(v)
        else:
            out[k] = v
    return out


@dataclasses.dataclass(frozen=True)
class RunResult:
    """Everything one run produced, in memory (what :func:`nanoslam_jax.run` returns and the
    ``run`` command writes with :meth:`write`).

    Attributes:
        config: the resolved configuration.
        log: the log the filter ran on (host log, segments, metrics frame, map truth).
        times: time of each segment (s), the rows of the trajectories.
        trajectory: ``(segments, 3)`` the reported pose ``(x, y, phi)`` at each segment (the
            smoothed path when the smoother ran).
        mean_trajectory: ``(segments, 3)`` the filter's weighted mean pose at each segment
            (dead reckoning: its poses).
        best_trajectory: ``(segments, 3)`` the best particle's pose at each segment (dead
            reckoning: its poses).
        path_before_smoother: ``(segments, 3)`` the path the smoother started from, or None.
        dead_reckoning: ``(segments, 3)`` the motion model alone from the origin.
        landmarks: the reported map, one row per landmark with the columns
            :data:`MAP_COLUMNS`, or None for dead reckoning.
        ess: the effective sample size per segment (particle methods), or None.
        outputs: the per-segment outputs of the filter (host arrays), or None.
        state: the filter's final state (JAX arrays), or None.
        metrics: errors, landmarks, timings and compile statistics (what ``metrics.json`` holds).
    """

    config: Config
    log: LoadedLog
    times: np.ndarray
    trajectory: np.ndarray
    mean_trajectory: np.ndarray
    best_trajectory: np.ndarray
    path_before_smoother: Optional[np.ndarray]
    dead_reckoning: np.ndarray
    landmarks: Optional[np.ndarray]
    ess: Optional[np.ndarray]
    outputs: Any
    state: Any
    metrics: dict

    @property
    def finite(self) -> bool:
        """Whether the reported trajectory is finite everywhere."""
        return bool(np.all(np.isfinite(self.trajectory)))

    def write(self, out_dir: str | Path, plots: Optional[bool] = None) -> Path:
        """Write the result directory: ``config.yaml`` (version and seed in its header),
        ``metrics.json``, ``trajectory.csv``, ``trajectory.tum`` (TUM format: ``time x y z qx qy
        qz qw``, read by evo and other trajectory tools), ``map.csv``, the figures and, last, the
        Rerun recording of ``output.rerun`` (a failure to write it is a warning in ``metrics.json``).

        Args:
            out_dir: the directory (created).
            plots: write the figures (default: ``output.plots``; never for a non-finite run).

        Returns:
            The directory.
        """
        cfg = self.config
        out = Path(out_dir)
        out.mkdir(parents=True, exist_ok=True)
        header = (
            f"# nanoslam-jax {__version__}, seed {cfg.seed}, "
            f"written {_dt.datetime.now().isoformat(timespec='seconds')}\n"
        )
        (out / "config.yaml").write_text(header + yaml.safe_dump(config_to_dict(cfg), sort_keys=False))
        t, est = self.times, self.trajectory
        cols, table = ["t", "x", "y", "phi", "mean_x", "mean_y", "mean_phi"], np.c_[t, est, self.mean_trajectory]
        if cfg.filter.estimate == "path":  # x, y, phi: the ancestral path; the filter's own estimate beside it
            cols, table = cols + ["best_x", "best_y", "best_phi"], np.c_[table, self.best_trajectory]
        if self.path_before_smoother is not None:  # x, y, phi: the smoothed path; the path it started from beside it
            cols, table = cols + ["path_x", "path_y", "path_phi"], np.c_[table, self.path_before_smoother]
        _write_csv(out / "trajectory.csv", cols, table)
        write_tum(out / "trajectory.tum", t, est)
        if self.landmarks is not None:
            dim, names = _map_layout(cfg)
            cols = map_columns(dim, names is not None)
            cols = cols + [MAP_ID_COLUMN] * (self.landmarks.shape[1] > len(cols))
            _write_csv(out / "map.csv", cols, self.landmarks, fmt="%.9g")
        (out / "metrics.json").write_text(json.dumps(_json_safe(self.metrics), indent=2) + "\n")
        if (cfg.output.plots if plots is None else plots) and self.finite:
            write_run_figures(out, self)
        if cfg.output.rerun:  # last: a recording that fails costs a warning, not the run's other results
            from nanoslam_jax.app._replay import record_run

            try:
                dim, names = _map_layout(cfg)
                record_run(self, out, map_columns(dim, names is not None), names)
            except Exception as e:  # any failure of the optional recording is reported, not raised
                warning = f"output.rerun: no Rerun recording written ({type(e).__name__}: {e})"
                print(f"warning: {warning}", file=sys.stderr)
                self.metrics.setdefault("warnings", []).append(warning)
                (out / "metrics.json").write_text(json.dumps(_json_safe(self.metrics), indent=2) + "\n")
        return out


def write_tum(path: str | Path, times: np.ndarray, poses: np.ndarray) -> None:
    """Write planar poses ``(x, y, phi)`` in the TUM trajectory format, ``time x y z qx qy qz qw``
    (z = 0, the heading as a rotation about the vertical axis), one pose per line."""
    half = 0.5 * np.asarray(poses[:, 2])
    zero = np.zeros_like(half)
    rows = np.c_[times, poses[:, 0], poses[:, 1], zero, zero, zero, np.sin(half), np.cos(half)]
    np.savetxt(path, rows, fmt="%.9f", delimiter=" ", header="time x y z qx qy qz qw")


class _Estimate(NamedTuple):
    """What a run estimated, before it is scored.

    Attributes:
        trajectory: the reported pose at each segment.
        mean: the filter's weighted mean pose at each segment (dead reckoning: its poses).
        best: the best particle's pose at each segment (dead reckoning: its poses).
        smooth: the smoother of this run (path -> ``Smoothed``), or None.
        ess: the effective sample size per segment (particle methods), or None.
        outputs: the per-segment outputs of the filter (host arrays), or None.
        state: the filter's final state, or None.
        landmarks: the reported map (:func:`map_table`), or None.
    """

    trajectory: np.ndarray
    mean: np.ndarray
    best: np.ndarray
    smooth: Any = None
    ess: Optional[np.ndarray] = None
    outputs: Any = None
    state: Any = None
    landmarks: Optional[np.ndarray] = None


def _add_warnings(metrics: dict, warnings: list[str]) -> None:
    """Append ``warnings`` to ``metrics["warnings"]`` (created on the first one)."""
    if warnings:
        metrics.setdefault("warnings", []).extend(warnings)


def _filter_metrics(run: Any, static: Static, n_segments: int) -> dict:
    """The filter's own counts (:func:`filter_statistics`), its compile and run time."""
    return dict(
        **filter_statistics(run.outputs, run.state.overflow, resample_count(run.state)),
        compile_s=run.compile_s,
        run_s=run.run_s,
        ms_per_scan=1e3 * run.run_s / max(n_segments, 1),
        n_particles=static.n_particles,
        capacity=static.capacity,
    )


def _add_adaptive_metrics(metrics: dict, static: Static, params: Params, state: Any) -> None:
    """Where the adaptive measurement noise and NASRUKF's adaptive process noise ended (when on)."""
    if static.adaptive_noise:
        noise_metrics, noise_warnings = adaptive_noise_report(static, params, state)
        metrics.update(noise_metrics)
        _add_warnings(metrics, noise_warnings)
    if isinstance(static.method_settings, NasrukfStatic) and static.method_settings.adaptive_process:
        process_metrics, process_warnings = adaptive_process_summary(
            np.asarray(state.process_scale), int(state.process_count), float(params.method.process_floor)
        )
        metrics.update(process_metrics)
        _add_warnings(metrics, process_warnings)


def _run_filter_of(
    cfg: Config, log: LoadedLog, settings: tuple[Static, Params], dr_poses: np.ndarray, show: bool, metrics: dict
) -> _Estimate:
    """Run the filter (and the smoother) on ``log``; adds to ``metrics`` dead reckoning's errors
    against GPS, the smoother's report and the filter's own statistics."""
    static, params = settings
    seg = log.segments
    t = np.asarray(seg.time)
    # The baseline every result is read against: the motion model alone on the same log.
    if np.all(np.isfinite(dr_poses)) and len(log.raw.gps):
        mk = dict(rotation_deg=cfg.metrics.gps_rotation_deg, jump_speed=cfg.metrics.jump_speed, frame=log.frame)
        dr = evaluate(t, dr_poses[:, :2], log.raw.gps, **mk)
        metrics.update({f"dr_{k}": dr[k] for k in ("rmse_fixed", "rmse_aligned", "final_error")})
    run = run_filter(
        static, params, seg, cfg.seed, chunk=cfg.output.chunk, progress=text_progress(cfg.name) if show else None
    )
    o = run.outputs
    best_pose, mean = np.asarray(o.best_pose), np.asarray(o.mean_pose)
    est = np.asarray(static.estimate.trajectory(o, run.state))
    smooth = None
    if cfg.smoother.enabled:  # the path and its map refined offline
        smooth = lambda path: smooth_filter_run(run, path, seg, params, cfg.smoother, static.prior)  # noqa: E731
    ess = None if is_gaussian(static.method) else np.asarray(o.ess)
    outputs, state = jax.tree.map(np.asarray, o), run.state
    landmarks = map_table(jax.tree.map(np.asarray, reported_map(run.state)))
    metrics.update(_filter_metrics(run, static, len(t)))
    _add_adaptive_metrics(metrics, static, params, run.state)
    return _Estimate(est, mean, best_pose, smooth, ess, outputs, state, landmarks)


def _map_estimate(cfg: Config, landmarks: Optional[np.ndarray], state: Any) -> Optional[MapEstimate]:
    """The reported map as the scorer reads it (positions, confirmed, ids, kinds, NASRUKF's arcs)."""
    if landmarks is None:
        return None
    dim, names = _map_layout(cfg)
    cols = map_columns(dim, names is not None)
    ids = landmarks[:, len(cols)] if landmarks.shape[1] > len(cols) else None
    kinds = None if names is None else np.asarray(names)[landmarks[:, dim].astype(int)]
    lm = MapEstimate(landmarks[:, :dim], landmarks[:, cols.index("confirmed")] > 0, ids, kinds)
    if (arc_table := getattr(state, "arc_table", None)) is not None:  # NASRUKF's per-beam arcs
        lm = with_arcs(lm, *(np.asarray(a) for a in arc_table()))
    return lm


def _add_dead_reckoning_baselines(cfg: Config, log: LoadedLog, dr_poses: np.ndarray, metrics: dict) -> None:
    """Dead reckoning scored beside the run: against the reference path, its error over the run's,
    its heading error, and the map its path gives against the survey."""
    seg = log.segments
    t = np.asarray(seg.time)
    dr_finite = np.all(np.isfinite(dr_poses))
    if log.reference is not None and dr_finite:  # dead reckoning against the reference path
        from nanoslam_jax.eval import score_reference

        metrics.update(score_reference(log.reference, t, None, dr_poses))
    if "dr_rmse_fixed" in metrics and "rmse_fixed" in metrics:
        metrics["dr_over_slam"] = metrics["dr_rmse_fixed"] / max(metrics["rmse_fixed"], 1e-12)
    if "rmse_heading_deg" in metrics and cfg.filter.method != "dead_reckoning" and dr_finite:
        metrics["dr_rmse_heading_deg"] = rmse_heading_deg(t, dr_poses[:, 2], log.raw.truth_poses)
    if log.survey is not None and dr_finite and (np.asarray(seg.z_id) >= 0).any():
        # The baseline: every sighting of known id projected from the dead-reckoned path.
        dr_ids, dr_xy = sighting_map(dr_poses, seg)
        dr_map = map_alignment_metrics(dr_xy, log.survey.xy, dr_ids, log.survey.ids, cfg.metrics.map_radius)
        metrics.update(dr_survey_rmse=dr_map["rmse"], dr_survey_found=dr_map["n_found"])
        if np.isfinite(metrics.get("survey_rmse", np.nan)):
            metrics["survey_dr_over_slam"] = dr_map["rmse"] / max(metrics["survey_rmse"], 1e-12)


@in_float64
def execute(
    cfg: Config, data_dir: Optional[str] = None, progress: Optional[bool] = None, log: Optional[LoadedLog] = None
) -> RunResult:
    """Run ``cfg`` in memory: load the log, run the filter (and the smoother), score it.

    Args:
        cfg: the run configuration.
        data_dir: log directory overriding ``data.path``.
        progress: show a progress indicator (default: ``output.progress``).
        log: the log of ``cfg`` already loaded (:func:`load_log`; None: load it).

    Returns:
        The :class:`RunResult`; its ``metrics["finite"]`` says whether the estimate stayed finite.
    """
    stats0 = compile_stats()
    log = load_log(cfg, data_dir) if log is None else log
    seg = log.segments
    static, params = settings_from_config(cfg, seg.k_max, int(seg.time.shape[0]))
    t = np.asarray(seg.time)
    metrics: dict = {
        "method": cfg.filter.method,
        "seed": cfg.seed,
        "version": __version__,
        "data": log.source,
        "frame": log.frame,
        "n_segments": int(t.shape[0]),
        "versions": versions(),
        "command": " ".join(sys.argv),
    }
    show = cfg.output.progress if progress is None else progress
    t0 = time.perf_counter()
    dr_poses = np.asarray(jax.block_until_ready(dead_reckoning(params, seg)))
    dr_s = time.perf_counter() - t0
    if cfg.filter.method == "dead_reckoning":
        metrics.update(run_s=dr_s)
        e = _Estimate(dr_poses, dr_poses, dr_poses)
    else:
        e = _run_filter_of(cfg, log, (static, params), dr_poses, bool(show), metrics)

    # JAX's own count of this run's tracing, lowering and compiling (or loading from the cache).
    metrics["compilation"] = {
        **compile_stats().since(stats0).as_dict(),
        "cache_dir": jax.config.jax_compilation_cache_dir or None,
    }
    lm = _map_estimate(cfg, e.landmarks, e.state)
    if cfg.filter.method == "dead_reckoning":
        trajectory, before = e.trajectory, None
        metrics.update(score_run(log, trajectory, cfg.metrics, lm))
    else:  # the one scorer of every command (smoothing the path first when the smoother is on)
        sc = score_estimate(
            log, Tracks(e.trajectory, e.best, e.mean), static.estimate, cfg.metrics, lm, e.smooth, cfg.smoother
        )
        metrics.update(sc.metrics)
        _add_warnings(metrics, sc.warnings)
        trajectory, before = sc.trajectory, sc.before_smoother
    _add_dead_reckoning_baselines(cfg, log, dr_poses, metrics)
    return RunResult(
        config=cfg,
        log=log,
        times=t,
        trajectory=trajectory,
        mean_trajectory=e.mean,
        best_trajectory=e.best,
        path_before_smoother=before,
        dead_reckoning=dr_poses,
        landmarks=e.landmarks,
        ess=e.ess,
        outputs=e.outputs,
        state=e.state,
        metrics=metrics,
    )


@in_float64
def run_experiment(
    cfg: Config,
    out_dir: str | Path,
    data_dir: Optional[str] = None,
    progress: Optional[bool] = None,
    clear: bool = False,
) -> dict:
    """Run ``cfg`` (:func:`execute`) and write its result directory (:meth:`RunResult.write`).

    Args:
        cfg: the run configuration.
        out_dir: result directory (created; a log that cannot be read leaves none behind).
        data_dir: log directory overriding ``data.path``.
        progress: show a progress indicator (default: ``output.progress``).
        clear: delete what ``out_dir`` holds once the run has finished, before writing (an earlier
            run's files; a run that fails leaves them in place).

    Returns:
        The metrics (also in ``metrics.json``).

    Raises:
        FloatingPointError: if the estimate became non-finite (the metrics are still written).
    """
    if cfg.output.rerun:  # refused before the run, not after it, when the optional package is missing
        from nanoslam_jax.eval._rerun import _require_rerun

        try:
            _require_rerun()
        except ImportError as e:
            raise ConfigError(str(e)) from None
    result = execute(cfg, data_dir, progress)
    if clear and Path(out_dir).is_dir():
        for entry in Path(out_dir).iterdir():
            if entry.is_dir() and not entry.is_symlink():
                shutil.rmtree(entry)
            else:
                entry.unlink()
    out = result.write(out_dir)
    if not result.finite:
        raise FloatingPointError(
            f"{cfg.name}: the estimate became non-finite; metrics written to {out / 'metrics.json'}"
        )
    return result.metrics
