"""A run's log from a :class:`Config`: the files of ``data.kind`` / ``data.format`` (or a simulated
log), its detections (from a file, or the raw laser front end), its segments, and what it is
scored against (GPS, truth, a survey, a reference path).
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any, Literal, NamedTuple, Optional, cast

import numpy as np

from nanoslam_jax.app.config import Config, resolve_data_dir
from nanoslam_jax.data import (
    RawLog,
    Segments,
    load_mrclam,
    load_victoria_park,
    make_segments,
    odometry_rows_from_unicycle,
)
from nanoslam_jax.eval.metrics import (
    observable_landmarks,
)
from nanoslam_jax.app._models import measurement_model_from_config, motion_model_class
from nanoslam_jax.models import Odometry
from nanoslam_jax.models._settings import UnicycleConfig


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


class _Read(NamedTuple):
    """A log as read (or simulated), before it is cut into segments.

    Attributes:
        raw: the host log, with its detections.
        frame: metrics frame (:attr:`LoadedLog.frame`).
        source: where it came from.
        features: the true line segments and circles (``None``: none known).
        reference: the reference path (``None``: none).
        scans: the laser scans (``None``: none read).
    """

    raw: RawLog
    frame: str
    source: str
    features: Any = None
    reference: Any = None
    scans: Any = None


def _unicycle_at_odometry_sensor(cfg: Config) -> UnicycleConfig:
    """A differential-drive robot with its sensor at the odometry model's offset."""
    o = cfg.odometry
    return UnicycleConfig(sensor_x=o.sensor_x, sensor_y=o.sensor_y)


def _read_simulated_park(cfg: Config, odometry: bool) -> _Read:
    """``data.kind: simulated``: the simulated park."""
    from nanoslam_jax.sim.park import simulate, simulate_config

    if odometry:
        raw = simulate(cfg.sim, cfg.vehicle, _unicycle_at_odometry_sensor(cfg))
    else:
        raw = simulate_config(cfg)
    return _Read(raw, "slam", f"simulated (seed {cfg.sim.seed})")


def _read_simulated_city(cfg: Config, odometry: bool) -> _Read:
    """``data.kind: city``: the simulated city."""
    from nanoslam_jax.sim.city import simulate_city

    if odometry:
        unicycle: Optional[UnicycleConfig] = _unicycle_at_odometry_sensor(cfg)
    else:
        unicycle = cfg.unicycle if cfg.model.motion == "unicycle" else None
    raw = simulate_city(cfg.city, cfg.sim, cfg.vehicle, unicycle).raw
    source = (
        f"simulated city ({cfg.city.blocks}x{cfg.city.blocks} blocks, {cfg.city.distance_m:g} m, seed {cfg.city.seed})"
    )
    return _Read(raw, "slam", source)


def _read_simulated_indoor(cfg: Config) -> _Read:
    """``data.kind: indoor`` without a log directory: the simulated indoor world, its scans and
    (unless ``data.detections: file``) the front end's detections in them."""
    from nanoslam_jax.sim.indoor import feature_truth, simulate_indoor

    indoor = simulate_indoor(cfg.indoor)
    raw, features = indoor.raw, feature_truth(indoor.world)
    source = f"simulated indoor ({indoor.world.template}, seed {cfg.indoor.seed})"
    if cfg.data.detections != "file":
        raw = with_scan_detections(raw, indoor.scans, cfg.data.detections, cfg.detector, cfg.data.beam_step)
    return _Read(raw, "slam", source, features=features, scans=indoor.scans)


def _read_laser_odometry_log(cfg: Config, data_dir: Optional[str]) -> _Read:
    """``data.format: carmen`` or ``rosbag``: the odometry, the front end's detections in the scans
    and the reference path."""
    raw, scans, source, reference = _load_laser_odom(cfg, data_dir)
    raw = with_scan_detections(raw, scans, cfg.data.detections, cfg.detector, cfg.data.beam_step)
    return _Read(raw, "relative", source, reference=reference, scans=scans)


def _read_log_directory(cfg: Config, data_dir: Optional[str]) -> _Read:
    """A log directory (Victoria Park, MRCLAM or an indoor log): its files, the laser scans when
    the detections come from the front end, and the true features it holds."""
    from nanoslam_jax.data import load_laser
    from nanoslam_jax.sim.indoor import read_feature_truth

    directory = resolve_data_dir(cfg, data_dir)
    scans = None
    if cfg.data.format == "mrclam":
        raw = load_mrclam(directory, cfg.data.robot)
    else:
        fmt = cast(Literal["auto", "ascii", "mat"], cfg.data.format)  # carmen and rosbag are read elsewhere
        raw = load_victoria_park(directory, fmt, detections=cfg.data.detections == "file")
    if cfg.data.detections != "file":
        scans = load_laser(directory)
        raw = with_scan_detections(raw, scans, cfg.data.detections, cfg.detector, cfg.data.beam_step)
    frame = "slam" if raw.truth_poses is not None else "relative"
    source = raw.source or str(directory)
    return _Read(raw, frame, source, features=read_feature_truth(directory), scans=scans)


def _read_log(cfg: Config, data_dir: Optional[str], odometry: bool) -> _Read:
    """Read or simulate the log ``data.kind`` and ``data.format`` name."""
    if cfg.data.kind == "simulated":
        return _read_simulated_park(cfg, odometry)
    if cfg.data.kind == "city":
        return _read_simulated_city(cfg, odometry)
    if cfg.data.kind == "indoor" and data_dir is None and cfg.data.path is None:
        return _read_simulated_indoor(cfg)
    if cfg.data.format in ("carmen", "rosbag"):
        return _read_laser_odometry_log(cfg, data_dir)
    return _read_log_directory(cfg, data_dir)


def _cut_segments(cfg: Config, raw: RawLog, source: str) -> Segments:
    """Cut ``raw`` into the segments of ``data``; the errors name what to change.

    Raises:
        ValueError: no laser scan kept (naming detector.min_line_length for line segments), or a
            scan holds more features than ``nasrukf.max_groups``.
    """
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
    return segments


def _observable_map_truth(cfg: Config, raw: RawLog, segments: Segments) -> Optional[np.ndarray]:
    """The true landmarks observable from the true path (a simulated or surveyed point map)."""
    if raw.truth_landmarks is None or raw.truth_poses is None:
        return None
    d = cfg.data
    t = np.asarray(segments.time)[np.asarray(segments.z_mask).any(axis=1)]
    seen = observable_landmarks(raw.truth_landmarks, raw.truth_poses, t, d.max_range, cfg.map.fov_deg, d.min_range)
    return np.asarray(raw.truth_landmarks)[seen]


def _survey_of(raw: RawLog) -> Optional[Survey]:
    """The surveyed landmarks of a log without a true path (e.g. MRCLAM's)."""
    if raw.truth_landmarks is None or raw.truth_poses is not None:
        return None
    xy = np.asarray(raw.truth_landmarks, dtype=float)
    ids = np.arange(xy.shape[0]) if raw.landmark_ids is None else np.asarray(raw.landmark_ids, dtype=np.int64)
    return Survey(xy, ids)


def load_log(cfg: Config, data_dir: Optional[str] = None) -> LoadedLog:
    """Read (or simulate) the log of ``cfg`` and cut it into segments.

    Args:
        cfg: the run configuration (``data`` and ``sim`` or ``indoor`` sections).
        data_dir: a ``--data`` directory overriding ``data.path`` (with ``data.kind: indoor``, an
            indoor log directory read instead of simulating one).
    """
    odometry = odometry_controls(cfg)
    read = _read_log(cfg, data_dir, odometry)
    raw = read.raw
    if odometry and raw.dr.shape[1] == 3:  # a differential-drive robot's (v, omega) rows
        raw = dataclasses.replace(raw, dr=odometry_rows_from_unicycle(raw.dr))
    segments = _cut_segments(cfg, raw, read.source)
    # a map of lines: scored against the true walls, not points (NASRUKF's per-beam features are lines and arcs)
    measurement = cfg.model.measurement
    lines = measurement == "line" or cfg.data.detections == "laser_beams" or "+" in measurement
    features = read.features if lines or measurement in ("circle", "line+circle") else None
    map_truth = None if lines else _observable_map_truth(cfg, raw, segments)
    return LoadedLog(
        raw, segments, read.frame, read.source, map_truth, _survey_of(raw), features, read.reference, read.scans
    )


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
