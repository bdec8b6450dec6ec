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
from typing import Any, Optional

import jax
import numpy as np
import yaml
from scipy.special import expit

from nanoslam_jax.lib._cache import compile_stats
from nanoslam_jax._version import __version__
from nanoslam_jax.app.config import Config, ConfigError, config_to_dict, resolve_data_dir
from nanoslam_jax.data import (
    RawLog,
    Segments,
    load_mrclam,
    load_victoria_park,
    make_segments,
    odometry_rows_from_unicycle,
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
    reported_trajectory,
    run_filter,
    text_progress,
)
from nanoslam_jax.app.filters import settings_from_config
from nanoslam_jax.methods._scan import is_gaussian, resample_count
from nanoslam_jax.eval.metrics import (
    error_over_time,
    evaluate,
    map_alignment_metrics,
    observable_landmarks,
    relative_gps,
    rmse_heading_deg,
)
from nanoslam_jax.eval._scoring import MapEstimate, companion_tracks, score_run, with_arcs
from nanoslam_jax.app._models import measurement_model_from_config, motion_model_class
from nanoslam_jax.models import Composite, Odometry
from nanoslam_jax.models._settings import UnicycleConfig
from nanoslam_jax.smoother._smoother import smooth_filter_run, smoother_metrics
from nanoslam_jax.lib._precision import in_float64


@dataclasses.dataclass(frozen=True)
class LoadedLog:
    """A log ready for the filter.

    Attributes:
        raw: the host log.
        segments: its fixed-shape segments.
        frame: metrics frame: ``'relative'`` (real GPS) or ``'slam'`` (simulated, GPS = truth).
        source: where it came from.
        map_truth: the true landmarks a map is judged against (those observable from the true
            path, :func:`~nanoslam_jax.eval.metrics.observable_landmarks`), or None without ground truth.
        survey: the surveyed landmarks of a real log without a true path (MRCLAM's), in a frame of
            their own, or None.
        feature_truth: the true walls (lines), corners, pillars and break points a line map is
            judged against (an indoor log's, :class:`~nanoslam_jax.sim.indoor.FeatureTruth`),
            or None (no such truth, or a map of points).
        reference: the reference path of ``data.reference`` (a ``ReferencePath``), or None.
        scans: the raw laser scans the detections were found in (a
            :class:`~nanoslam_jax.data.LaserScans`), or None (a log of detections only).
    """

    raw: RawLog
    segments: Segments
    frame: str
    source: str
    map_truth: Optional[np.ndarray] = None
    survey: Optional["Survey"] = None
    feature_truth: Any = None
    reference: Any = None  # a ReferencePath (data.reference) or None
    scans: Any = None  # the raw LaserScans, or None


@dataclasses.dataclass(frozen=True)
class Survey:
    """Surveyed landmark positions a map is scored against after a rigid alignment.

    Attributes:
        xy: ``(S, 2)`` the surveyed positions (m).
        ids: ``(S,)`` their landmark ids (those of the detections' ids).
    """

    xy: np.ndarray
    ids: np.ndarray


def with_laser_detections(raw: RawLog, directory, detector) -> RawLog:
    """``raw`` with its detections replaced by the trees the front end finds in the raw scans of
    ``directory`` (``LASER.txt`` or ``aa3_lsr2.mat``) with the ``detector`` settings."""
    from nanoslam_jax.data import load_laser

    return with_scan_detections(raw, load_laser(directory), "laser", detector)


def with_scan_detections(raw: RawLog, scans, kind: str, detector, beam_step: int = 1) -> RawLog:
    """``raw`` with its detections replaced by what the front end finds in the raw ``scans`` with the
    ``detector`` settings: ``kind`` ``'laser'``: the trees (``time, range, bearing, diameter``);
    ``'laser_lines'``: the line segments (``time, rho, alpha, length``,
    :func:`~nanoslam_jax.frontend.detect_lines`); ``'laser_circles'``: the arcs
    (:func:`circle_table`); ``'laser_features'``: both, with their types (:func:`feature_table`);
    ``'laser_beams'``: the returns on segments and arcs, one per beam
    (``time, range, beam angle, diameter``, every ``beam_step``-th beam,
    :func:`~nanoslam_jax.frontend._beams.beam_detections`)."""
    from nanoslam_jax.frontend import detect_lines, detect_trees, extract_features

    if kind == "laser_beams":  # one detection per beam on a segment or arc, the feature's index as its id
        from nanoslam_jax.frontend._beams import beam_detections

        rows, group = beam_detections(scans, detector, beam_step)
        return dataclasses.replace(raw, detections=rows, detection_ids=group)
    if kind == "laser_circles":
        return dataclasses.replace(raw, detections=circle_table(extract_features(scans, detector)), detection_ids=None)
    if kind == "laser_features":
        rows, kinds = feature_table(extract_features(scans, detector))
        return dataclasses.replace(raw, detections=rows, detection_ids=None, detection_kinds=kinds)
    detect = detect_lines if kind == "laser_lines" else detect_trees
    return dataclasses.replace(raw, detections=detect(scans, detector), detection_ids=None)


def circle_table(features) -> np.ndarray:
    """The front end's arcs (:attr:`~nanoslam_jax.frontend.Features.circles`) as detections of the
    ``circle`` measurement model: ``(K, 5)`` rows ``time, range, bearing, radius, diameter`` (the
    range and bearing of the circle's centre in the sensor frame, 0 ahead, left positive; its
    radius; twice the radius), ordered by time, then beam."""
    c = features.circles
    order = np.lexsort((c.first_beam, c.scan))
    rng, bearing = np.hypot(c.cx, c.cy)[order], np.arctan2(c.cy, c.cx)[order]
    radius = np.asarray(c.radius, float)[order]
    rows = np.stack([features.time[c.scan[order]], rng, bearing, radius, 2.0 * radius], axis=1)
    return rows.reshape(-1, 5)


def feature_table(features) -> tuple[np.ndarray, np.ndarray]:
    """The front end's line segments and arcs as detections of the composite ``line+circle``
    measurement model: ``(M, 5)`` rows ``time, z (3 values), length or diameter`` (a segment's
    ``rho, alpha, 0`` and length, :meth:`~nanoslam_jax.frontend.Features.line_table`; an arc's
    range and bearing of its centre, radius and diameter, :func:`circle_table`) ordered by time
    (segments before arcs within a scan), and each row's kind (0: line, 1: circle)."""
    lines = features.line_table()
    lines = np.c_[lines[:, :3], np.zeros(len(lines)), lines[:, 3]]
    rows = np.concatenate([lines, circle_table(features)])
    kinds = np.concatenate([np.zeros(len(lines), np.int64), np.ones(len(rows) - len(lines), np.int64)])
    order = np.argsort(rows[:, 0], kind="stable")
    return rows[order], kinds[order]


def odometry_controls(cfg: Config) -> bool:
    """Whether the run's motion model reads the odometry model's ``(vx, vy, omega)`` rows
    (:class:`~nanoslam_jax.models.Odometry` or a subclass): the log's controls are then written as
    pose increments (a CARMEN log's or a bag's odometry poses; a differential-drive robot's ``(v,
    omega)`` rows as ``(v, 0, omega)``) instead of the default rows."""
    return issubclass(motion_model_class(cfg.model.motion), Odometry)


def load_log(cfg: Config, data_dir: Optional[str] = None) -> LoadedLog:
    """Read (or simulate) the log of ``cfg`` and cut it into segments.

    Args:
        cfg: the run configuration (``data`` and ``sim`` or ``indoor`` sections).
        data_dir: a ``--data`` directory overriding ``data.path`` (with ``data.kind: indoor``, an
            indoor log directory read instead of simulating one).
    """
    features = reference = scans = None
    odometry = odometry_controls(cfg)
    if cfg.data.kind == "simulated":
        from nanoslam_jax.sim.park import simulate, simulate_config

        if odometry:  # a differential-drive robot with its sensor at the odometry model's offset
            o = cfg.odometry
            raw = simulate(cfg.sim, cfg.vehicle, UnicycleConfig(sensor_x=o.sensor_x, sensor_y=o.sensor_y))
        else:
            raw = simulate_config(cfg)
        frame, source = "slam", f"simulated (seed {cfg.sim.seed})"
    elif cfg.data.kind == "city":
        from nanoslam_jax.sim.city import simulate_city

        if odometry:  # a differential-drive robot with its sensor at the odometry model's offset
            o = cfg.odometry
            unicycle: Optional[UnicycleConfig] = UnicycleConfig(sensor_x=o.sensor_x, sensor_y=o.sensor_y)
        else:
            unicycle = cfg.unicycle if cfg.model.motion == "unicycle" else None
        raw = simulate_city(cfg.city, cfg.sim, cfg.vehicle, unicycle).raw
        frame = "slam"
        source = f"simulated city ({cfg.city.blocks}x{cfg.city.blocks} blocks, {cfg.city.distance_m:g} m, seed {cfg.city.seed})"
    elif cfg.data.kind == "indoor" and data_dir is None and cfg.data.path is None:
        from nanoslam_jax.sim.indoor import feature_truth, simulate_indoor

        indoor = simulate_indoor(cfg.indoor)
        raw, frame, features = indoor.raw, "slam", feature_truth(indoor.world)
        source = f"simulated indoor ({indoor.world.template}, seed {cfg.indoor.seed})"
        scans = indoor.scans
        if cfg.data.detections != "file":
            raw = with_scan_detections(raw, indoor.scans, cfg.data.detections, cfg.detector, cfg.data.beam_step)
    elif cfg.data.format in ("carmen", "rosbag"):
        raw, scans, source, reference = _load_laser_odom(cfg, data_dir)
        raw = with_scan_detections(raw, scans, cfg.data.detections, cfg.detector, cfg.data.beam_step)
        frame = "relative"
    else:
        from nanoslam_jax.data import load_laser
        from nanoslam_jax.sim.indoor import read_feature_truth

        directory = resolve_data_dir(cfg, data_dir)
        if cfg.data.format == "mrclam":
            raw = load_mrclam(directory, cfg.data.robot)
        else:
            raw = load_victoria_park(directory, cfg.data.format, detections=cfg.data.detections == "file")
        if cfg.data.detections != "file":
            scans = load_laser(directory)
            raw = with_scan_detections(raw, scans, cfg.data.detections, cfg.detector, cfg.data.beam_step)
        frame = "slam" if raw.truth_poses is not None else "relative"
        source = raw.source or str(directory)
        features = read_feature_truth(directory)
    if odometry and raw.dr.shape[1] == 3:  # a differential-drive robot's (v, omega) rows
        raw = dataclasses.replace(raw, dr=odometry_rows_from_unicycle(raw.dr))
    d = cfg.data
    try:
        segments = make_segments(
            raw,
            min_range=d.min_range,
            max_range=d.max_range,
            k_max=d.k_max,
            max_dr_per_segment=d.max_dr_per_segment,
            t_end=d.t_end,
            measurement_dim=measurement_model_from_config(cfg).measurement_dim,
        )
    except ValueError as e:
        if d.detections == "laser_lines" and "no laser scan" in str(e):
            raise ValueError(
                f"{e}: the front end found no line segment at least detector.min_line_length "
                f"({cfg.detector.min_line_length} m) long"
            ) from None
        raise
    if d.detections == "laser_beams":
        most = int(np.max(np.where(segments.z_mask, segments.z_id, -1), initial=-1)) + 1
        if most > cfg.nasrukf.max_groups:
            raise ValueError(
                f"key 'nasrukf.max_groups': a scan of {source} holds {most} line segments and arcs, more than "
                f"nasrukf.max_groups ({cfg.nasrukf.max_groups}); raise it to at least {most}"
            )
    # a map of lines: scored against the true walls, not points (NASRUKF's per-beam features are lines and arcs)
    lines = cfg.model.measurement == "line" or d.detections == "laser_beams" or "+" in cfg.model.measurement
    features = features if lines or cfg.model.measurement in ("circle", "line+circle") else None
    map_truth = None
    if raw.truth_landmarks is not None and raw.truth_poses is not None and not lines:
        t = np.asarray(segments.time)[np.asarray(segments.z_mask).any(axis=1)]
        seen = observable_landmarks(raw.truth_landmarks, raw.truth_poses, t, d.max_range, cfg.map.fov_deg, d.min_range)
        map_truth = np.asarray(raw.truth_landmarks)[seen]
    survey = None
    if raw.truth_landmarks is not None and raw.truth_poses is None:
        xy = np.asarray(raw.truth_landmarks, dtype=float)
        ids = np.arange(xy.shape[0]) if raw.landmark_ids is None else np.asarray(raw.landmark_ids, dtype=np.int64)
        survey = Survey(xy, ids)
    return LoadedLog(raw, segments, frame, source, map_truth, survey, features, reference, scans)


def _load_laser_odom(cfg: Config, data_dir: Optional[str]):
    """``data.format: carmen`` or ``rosbag``: the controls, the scans, the source and the reference path
    (or None)."""
    import os

    from nanoslam_jax.eval import ReferencePath
    from nanoslam_jax.data._carmen import load_carmen
    from nanoslam_jax.data._laser_log import laser_odom_raw
    from nanoslam_jax.data._reference import load_reference
    from nanoslam_jax.data._rosbag import load_rosbag

    d = cfg.data

    def find(p: str) -> Path:
        q = Path(p).expanduser()
        root = Path(__file__).resolve().parents[2] / q
        return q if q.exists() or q.is_absolute() or not root.exists() else root

    given = data_dir or d.path or os.environ.get("NANOSLAM_DATA") or "../shared/data/carmen/mit-csail"
    if d.format == "rosbag":
        bag = resolve_data_dir(cfg, data_dir)
        given = str(bag)
        log = load_rosbag(bag, scan_topic=d.scan_topic, odom_topic=d.odom_topic, laser_pose=d.laser_pose)
    else:
        log = load_carmen(
            find(given), laser_start_deg=d.laser_start_deg, laser_step_deg=d.laser_step_deg, no_return=d.no_return_m
        )
    mx, my = (float(v) for v in log.laser_pose[:2])
    odometry = odometry_controls(cfg)
    section = "odometry" if odometry else "unicycle"
    u = cfg.odometry if odometry else cfg.unicycle
    if cfg.model.motion in ("unicycle", "odometry") and max(abs(mx - u.sensor_x), abs(my - u.sensor_y)) > 1e-3:
        raise ValueError(
            f"{log.source}: the laser is mounted at ({mx:.4f}, {my:.4f}) m from the robot's centre; set "
            f"{section}.sensor_x and {section}.sensor_y to it (now {u.sensor_x}, {u.sensor_y})"
        )
    raw, scans = laser_odom_raw(log, controls="odometry" if odometry else "unicycle")
    reference = None
    if d.reference is not None:
        q, where = Path(d.reference).expanduser(), find(given)
        beside = (where if where.is_dir() else where.parent) / q
        index, poses = load_reference(beside if not q.is_absolute() and not q.exists() and beside.exists() else q, log)
        reference = ReferencePath(log.scans.time[index], poses, float(log.laser_pose[2]), str(d.reference))
    return raw, scans, log.source, reference


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


#: Columns of ``map.csv`` (and, with ``filter.association: known``, :data:`MAP_ID_COLUMN` last).
MAP_COLUMNS = [
    "x",
    "y",
    "cov_xx",
    "cov_xy",
    "cov_yy",
    "hits",
    "misses",
    "existence",
    "confirmed",
    "diameter",
    "diameter_sd",
]
#: The last column of ``map.csv`` when landmarks carry the id of the detection that started them.
MAP_ID_COLUMN = "id"


def map_columns(dim: int = 2, kinds: bool = False) -> list[str]:
    """The columns of ``map.csv`` for landmarks of ``dim`` values (the measurement model's
    ``landmark_dim``): :data:`MAP_COLUMNS` with the values past the first two after ``y``, as
    ``m2``, ``m3``, ... (a circle's radius: ``m2``), then with ``kinds`` (a composite model's map)
    each landmark's type ``kind`` (the index of its model); the covariance columns are those of the
    first two values."""
    return MAP_COLUMNS[:2] + [f"m{i}" for i in range(2, dim)] + ["kind"] * kinds + MAP_COLUMNS[2:]


def _map_layout(cfg: Config) -> tuple[int, tuple[str, ...] | None]:
    """The landmark dimension of ``cfg``'s measurement model and, for a composite, its types' names."""
    model = measurement_model_from_config(cfg)
    return model.landmark_dim, (model.names if isinstance(model, Composite) else None)


def map_table(lm) -> np.ndarray:
    """The rows of ``map.csv`` (:func:`map_columns`) of a reported map's active landmarks (host arrays):
    ``existence`` is the existence probability, ``confirmed`` 1 or 0 (0: tentative); a map whose
    landmarks carry ids (known association) has their id as a last column."""
    act = np.asarray(lm.active)
    cov = np.asarray(lm.cov)[act]
    existence = expit(np.asarray(lm.log_odds, float)[act])
    kind = getattr(lm, "kind", None)
    table = np.c_[
        np.asarray(lm.mean)[act],
        np.asarray(kind)[act] if kind is not None else np.zeros((int(act.sum()), 0)),
        cov[:, 0, 0],
        cov[:, 0, 1],
        cov[:, 1, 1],
        np.asarray(lm.hits)[act],
        np.asarray(lm.misses)[act],
        existence,
        np.asarray(lm.confirmed)[act],
        np.asarray(lm.diam)[act],
        np.sqrt(np.asarray(lm.diam_var)[act]),
    ]
    if getattr(lm, "ident", None) is not None:
        table = np.c_[table, np.asarray(lm.ident)[act]]
    return table


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
            mk = dict(
                rotation_deg=cfg.metrics.gps_rotation_deg, jump_speed=cfg.metrics.jump_speed, frame=self.log.frame
            )
            _plots(
                out, cfg, self.log, t, est, self.landmarks, self.ess, cfg.filter.n_particles, mk, self.dead_reckoning
            )
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

    landmarks = None
    other = unsmoothed = outputs = state = None
    mean = best_pose = None
    mk = dict(rotation_deg=cfg.metrics.gps_rotation_deg, jump_speed=cfg.metrics.jump_speed, frame=log.frame)
    t0 = time.perf_counter()
    dr_poses = np.asarray(jax.block_until_ready(dead_reckoning(params, seg)))
    dr_s = time.perf_counter() - t0
    if cfg.filter.method == "dead_reckoning":
        metrics.update(run_s=dr_s)
        est = mean = best_pose = dr_poses
        ess = None
    else:
        # The baseline every result is read against: the motion model alone on the same log.
        if np.all(np.isfinite(dr_poses)) and len(log.raw.gps):
            dr = evaluate(t, dr_poses[:, :2], log.raw.gps, **mk)
            metrics.update({f"dr_{k}": dr[k] for k in ("rmse_fixed", "rmse_aligned", "final_error")})
        run = run_filter(
            static, params, seg, cfg.seed, chunk=cfg.output.chunk, progress=text_progress(cfg.name) if show else None
        )
        o = run.outputs
        best_pose, mean = np.asarray(o.best_pose), np.asarray(o.mean_pose)
        est = np.asarray(reported_trajectory(static.estimate, o, run.state))
        other = mean if static.estimate == "best" else best_pose
        if cfg.smoother.enabled and np.all(np.isfinite(est)):  # the path and its map refined offline
            unsmoothed = est
            sm = smooth_filter_run(run, est, seg, params, cfg.smoother, cfg.filter.prior)
            est = sm.poses
            smoother_report, smoother_warnings = smoother_metrics(sm, cfg.smoother)
            metrics.update(smoother_report)
            if smoother_warnings:
                metrics.setdefault("warnings", []).extend(smoother_warnings)
        ess = None if is_gaussian(static.method) else np.asarray(o.ess)
        outputs, state = jax.tree.map(np.asarray, o), run.state
        landmarks = map_table(jax.tree.map(np.asarray, reported_map(run.state)))
        has = np.asarray(o.n_associated) > 0
        metrics.update(
            landmark_overflow=int(run.state.overflow),
            window_overflow_max=int(np.max(o.window_overflow)),
            resample_count=int(resample_count(run.state)),
            ess_mean=float(np.mean(o.ess)),
            ess_min=float(np.min(o.ess)),
            nano_iterations_mean=float(np.mean(np.asarray(o.iterations)[has])) if has.any() else 0.0,
            proposal_capped=int(np.sum(o.n_capped)),
            proposal_nonfinite=int(np.sum(o.n_nonfinite)),
            weight_resets=int(np.sum(o.weight_reset)),
            associations_per_scan=float(np.mean(o.n_associated)),
            compile_s=run.compile_s,
            run_s=run.run_s,
            ms_per_scan=1e3 * run.run_s / max(len(t), 1),
            n_particles=static.n_particles,
            capacity=static.capacity,
        )
        if static.adaptive_noise:
            noise_metrics, noise_warnings = adaptive_noise_report(static, params, run.state)
            metrics.update(noise_metrics)
            if noise_warnings:
                metrics.setdefault("warnings", []).extend(noise_warnings)
        if isinstance(static.method_settings, NasrukfStatic) and static.method_settings.adaptive_process:
            process_metrics, process_warnings = adaptive_process_summary(
                np.asarray(run.state.process_scale), int(run.state.process_count), float(params.method.process_floor)
            )
            metrics.update(process_metrics)
            if process_warnings:
                metrics.setdefault("warnings", []).extend(process_warnings)

    # JAX's own count of this run's tracing, lowering and compiling (or loading from the cache).
    metrics["compilation"] = {
        **compile_stats().since(stats0).as_dict(),
        "cache_dir": jax.config.jax_compilation_cache_dir or None,
    }
    lm = None
    if landmarks is not None:
        dim, names = _map_layout(cfg)
        cols = map_columns(dim, names is not None)
        ids = landmarks[:, len(cols)] if landmarks.shape[1] > len(cols) else None
        kinds = None if names is None else np.asarray(names)[landmarks[:, dim].astype(int)]
        lm = MapEstimate(landmarks[:, :dim], landmarks[:, cols.index("confirmed")] > 0, ids, kinds)
        if (arc_table := getattr(state, "arc_table", None)) is not None:  # NASRUKF's per-beam arcs
            lm = with_arcs(lm, *(np.asarray(a) for a in arc_table()))
    # The one scorer of every command: the estimate against GPS, the map, and (for path: the
    # filter's own estimate; after the smoother: the path it started from) the other trajectories.
    others = None if other is None else companion_tracks(static.estimate, best_pose, mean, unsmoothed)
    metrics.update(score_run(log, est, cfg.metrics, lm, others))
    if log.reference is not None and np.all(np.isfinite(dr_poses)):  # dead reckoning against the reference path
        from nanoslam_jax.eval import score_reference

        metrics.update(score_reference(log.reference, t, None, dr_poses))
    if "dr_rmse_fixed" in metrics and "rmse_fixed" in metrics:
        metrics["dr_over_slam"] = metrics["dr_rmse_fixed"] / max(metrics["rmse_fixed"], 1e-12)
    if "rmse_heading_deg" in metrics and cfg.filter.method != "dead_reckoning" and np.all(np.isfinite(dr_poses)):
        metrics["dr_rmse_heading_deg"] = rmse_heading_deg(t, dr_poses[:, 2], log.raw.truth_poses)
    if log.survey is not None and np.all(np.isfinite(dr_poses)) and (np.asarray(seg.z_id) >= 0).any():
        # The baseline: every sighting of known id projected from the dead-reckoned path.
        dr_ids, dr_xy = sighting_map(dr_poses, seg)
        dr_map = map_alignment_metrics(dr_xy, log.survey.xy, dr_ids, log.survey.ids, cfg.metrics.map_radius)
        metrics.update(dr_survey_rmse=dr_map["rmse"], dr_survey_found=dr_map["n_found"])
        if np.isfinite(metrics.get("survey_rmse", np.nan)):
            metrics["survey_dr_over_slam"] = dr_map["rmse"] / max(metrics["survey_rmse"], 1e-12)
    return RunResult(
        config=cfg,
        log=log,
        times=t,
        trajectory=est,
        mean_trajectory=mean,
        best_trajectory=best_pose,
        path_before_smoother=unsmoothed,
        dead_reckoning=dr_poses,
        landmarks=landmarks,
        ess=ess,
        outputs=outputs,
        state=state,
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


def _plots(out, cfg, log, t, est, landmarks, ess, n_particles, mk, dr_poses):
    from nanoslam_jax.eval.plotting import plot_series, plot_trajectory

    gps = log.raw.gps
    if log.reference is not None and not len(gps):
        _reference_plots(out, cfg, log, t, est, landmarks, dr_poses)
        if ess is not None:
            plot_series(
                out / "ess.png",
                [("ESS", t, ess)],
                "effective sample size",
                f"{cfg.name}: ESS",
                hline=cfg.filter.resample_threshold * n_particles,
            )
        return
    ref = (
        relative_gps(gps[:, 1:3], cfg.metrics.gps_rotation_deg) if log.frame == "relative" and len(gps) else gps[:, 1:3]
    )
    label = "GPS (relative frame)" if log.frame == "relative" else "truth"
    lines = cfg.model.measurement == "line" or "+" in cfg.model.measurement or cfg.data.detections == "laser_beams"
    if lines:  # lines (rho, alpha): no points to draw
        landmarks = None
    dim, names = _map_layout(cfg)
    confirmed = None if landmarks is None else landmarks[:, map_columns(dim, names is not None).index("confirmed")] > 0
    # True landmarks in another frame than the path (a surveyed map, e.g. MRCLAM's) are not drawn.
    true_landmarks = log.raw.truth_landmarks if log.frame == "slam" and landmarks is not None else None
    plot_trajectory(
        out / "trajectory.png",
        ref,
        [(cfg.filter.method, est[:, :2])],
        None if landmarks is None else landmarks[:, :2],
        true_landmarks,
        title=f"{cfg.name}: {cfg.filter.method}",
        reference_label=label,
        confirmed=confirmed,
    )
    if not len(gps):  # no GPS (e.g. MRCLAM): no error over time
        if ess is not None:
            plot_series(
                out / "ess.png",
                [("ESS", t, ess)],
                "effective sample size",
                f"{cfg.name}: ESS",
                hline=cfg.filter.resample_threshold * n_particles,
            )
        return
    te, err = error_over_time(t, est[:, :2], gps, rotation_deg=mk["rotation_deg"], frame=mk["frame"])
    series = [(cfg.filter.method, te, err)]
    if cfg.filter.method != "dead_reckoning" and np.all(np.isfinite(dr_poses)):
        # The baseline: the vehicle model alone on the same log.
        series.append(
            (
                "dead reckoning",
                *error_over_time(t, dr_poses[:, :2], gps, rotation_deg=mk["rotation_deg"], frame=mk["frame"]),
            )
        )
    plot_series(
        out / "error.png", series, "position error [m]", f"{cfg.name}: error against {label}", logy=len(series) > 1
    )
    if ess is not None:
        plot_series(
            out / "ess.png",
            [("ESS", t, ess)],
            "effective sample size",
            f"{cfg.name}: ESS",
            hline=cfg.filter.resample_threshold * n_particles,
        )


def _world_points(points: list[np.ndarray], poses: np.ndarray, offset: tuple[float, float], every: int) -> np.ndarray:
    """Every ``every``-th segment's scan points (sensor frame) drawn from its pose, the sensor at
    ``offset`` (m, vehicle frame) from it."""
    out = []
    for i in range(0, len(points), every):
        p = points[i]
        if not len(p) or not np.all(np.isfinite(poses[i])):
            continue
        c, s = np.cos(poses[i, 2]), np.sin(poses[i, 2])
        local = p + np.asarray(offset)
        out.append(poses[i, :2] + local @ np.array([[c, s], [-s, c]]))
    return np.concatenate(out) if out else np.zeros((0, 2))


def _line_extents(lines: np.ndarray, points: np.ndarray, near: float = 0.1, gap: float = 0.5) -> np.ndarray:
    """``(L, 2, 2)`` each line ``(rho, alpha)`` drawn over the longest stretch of ``points`` within
    ``near`` of it with no gap over ``gap`` (m) along it; a line with fewer than 10 such points is left out."""
    segs = []
    for rho, alpha in np.asarray(lines, float).reshape(-1, 2):
        n, d = np.array([np.cos(alpha), np.sin(alpha)]), np.array([-np.sin(alpha), np.cos(alpha)])
        on = points[np.abs(points @ n - rho) <= near]
        if len(on) < 10:
            continue
        along = np.sort(on @ d)
        runs = np.split(along, np.flatnonzero(np.diff(along) > gap) + 1)
        run = max(runs, key=len)  # the wall itself: the longest stretch without a gap
        if len(run) < 10:
            continue
        segs.append([rho * n + run[0] * d, rho * n + run[-1] * d])
    return np.asarray(segs, float).reshape(-1, 2, 2)


def _reference_plots(out, cfg, log, t, est, landmarks, dr_poses) -> None:
    """A log scored against a reference path: the path and dead reckoning aligned onto it, their
    errors along it, and the map of every scan's points drawn from each path, with the landmark lines."""
    from nanoslam_jax.app._replay import scan_points
    from nanoslam_jax.eval import align_on_reference
    from nanoslam_jax.eval.plotting import plot_scan_maps, plot_series, plot_trajectory

    ref = log.reference
    paths = [(cfg.filter.method, est)]
    if cfg.filter.method != "dead_reckoning" and np.all(np.isfinite(dr_poses)):
        paths.append(("dead reckoning", dr_poses))
    aligned = [(label, *align_on_reference(ref, t, p)) for label, p in paths if np.all(np.isfinite(p))]
    plot_trajectory(
        out / "trajectory.png",
        ref.poses[:, :2],
        [(label, xy) for label, xy, _ in aligned],
        title=f"{cfg.name}: {cfg.filter.method}, rigidly aligned onto the reference path",
        reference_label="reference path",
    )
    plot_series(
        out / "error.png",
        [(label, err[:, 0] - t[0], err[:, 1]) for label, _, err in aligned],
        "position error [m]",
        f"{cfg.name}: error against the reference path after alignment (time from the log's start)",
        logy=len(aligned) > 1,
    )
    if log.scans is None:
        return
    points = scan_points(log.segments, log.scans)
    offset = (cfg.unicycle.sensor_x, cfg.unicycle.sensor_y) if cfg.model.motion == "unicycle" else (0.0, 0.0)
    every = max(1, len(points) // 1000)
    lines = None
    if landmarks is not None and cfg.model.measurement == "line":
        dim, names = _map_layout(cfg)
        conf = landmarks[:, map_columns(dim, names is not None).index("confirmed")] > 0
        lines = landmarks[conf, :2]
    panels = []
    for label, p in paths:
        if not np.all(np.isfinite(p)):
            continue
        world = _world_points(points, p, offset, every)
        segs = _line_extents(lines, world) if lines is not None and label == cfg.filter.method else None
        panels.append((label, world, p[:, :2], segs))
    plot_scan_maps(out / "scan_map.png", panels, f"{cfg.name}: every scan drawn from the path")
