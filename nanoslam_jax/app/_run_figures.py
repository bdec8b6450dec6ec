"""The figures of a run's result directory: the path against GPS, truth or a reference path, its
error along the log, the ESS, and for a laser log with a reference the scans drawn from the path.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Literal, cast

import numpy as np

from nanoslam_jax.eval.metrics import (
    error_over_time,
    relative_gps,
)
from nanoslam_jax.app._map_table import _map_layout, map_columns

if TYPE_CHECKING:
    from nanoslam_jax.app.experiment import RunResult


def write_run_figures(out: Path, result: RunResult) -> None:
    """The figures of ``result`` in ``out``: ``ess.png`` (particle methods), and ``trajectory.png``
    and ``error.png`` against the log's reference path (with ``scan_map.png``) or its GPS or truth."""
    from nanoslam_jax.eval.plotting import plot_series

    cfg, log = result.config, result.log
    if result.ess is not None:
        plot_series(
            out / "ess.png",
            [("ESS", result.times, result.ess)],
            "effective sample size",
            f"{cfg.name}: ESS",
            hline=cfg.filter.resample_threshold * cfg.filter.n_particles,
        )
    if log.reference is not None and not len(log.raw.gps):
        _reference_plots(out, result)
    else:
        _gps_plots(out, result)


def _gps_plots(out: Path, result: RunResult) -> None:
    """``trajectory.png`` against GPS (or the truth) and, with GPS, ``error.png`` beside dead reckoning's."""
    from nanoslam_jax.eval.plotting import plot_series, plot_trajectory

    cfg, log, t, est = result.config, result.log, result.times, result.trajectory
    landmarks, dr_poses = result.landmarks, result.dead_reckoning
    rotation_deg, frame = cfg.metrics.gps_rotation_deg, cast(Literal["relative", "slam"], log.frame)
    gps = log.raw.gps
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
        return
    te, err = error_over_time(t, est[:, :2], gps, rotation_deg=rotation_deg, frame=frame)
    series = [(cfg.filter.method, te, err)]
    if cfg.filter.method != "dead_reckoning" and np.all(np.isfinite(dr_poses)):
        # The baseline: the vehicle model alone on the same log.
        series.append(
            (
                "dead reckoning",
                *error_over_time(t, dr_poses[:, :2], gps, rotation_deg=rotation_deg, frame=frame),
            )
        )
    plot_series(
        out / "error.png", series, "position error [m]", f"{cfg.name}: error against {label}", logy=len(series) > 1
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


def _reference_plots(out: Path, result: RunResult) -> None:
    """A log scored against a reference path: the path and dead reckoning aligned onto it, their
    errors along it, and the map of every scan's points drawn from each path, with the landmark lines."""
    from nanoslam_jax.app._replay import scan_points
    from nanoslam_jax.eval import align_on_reference
    from nanoslam_jax.eval.plotting import plot_scan_maps, plot_series, plot_trajectory

    cfg, log, t, est = result.config, result.log, result.times, result.trajectory
    landmarks, dr_poses = result.landmarks, result.dead_reckoning

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
