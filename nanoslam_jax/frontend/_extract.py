"""The front end from raw scans to features and tree detections, vectorised over all scans."""

from __future__ import annotations

import numpy as np
from jaxtyping import Float

from nanoslam_jax.frontend._settings import DetectorConfig
from nanoslam_jax.data import LaserScans
from nanoslam_jax.frontend._circles import CircleFit, fit_circles
from nanoslam_jax.frontend._clusters import find_clusters, scan_points
from nanoslam_jax.frontend._segments import extract_lines
from nanoslam_jax.frontend._trees import find_trees, middle_range
from nanoslam_jax.frontend._types import Circles, Features

__all__ = ["detect_lines", "detect_trees", "extract_features"]


def extract_features(scans: LaserScans, cfg: DetectorConfig | None = None) -> Features:
    """Extract clusters, line segments, circles, corners, break points and trees from every scan.

    Args:
        scans: the raw scans (:func:`nanoslam_jax.data.load_laser`).
        cfg: the detector settings (the ``detector`` config section; default: its defaults).

    Returns:
        The features as flat tables whose ``scan`` column indexes ``scans``.
    """
    cfg = DetectorConfig() if cfg is None else cfg
    points, valid = scan_points(scans, cfg)
    clusters = find_clusters(points, valid, scans, cfg)
    lines, corners, breakpoints, has_line = extract_lines(points, clusters, cfg)
    n = clusters.n
    fitted = np.flatnonzero(n >= cfg.circle_min_points)
    part = fit_circles(points.x, points.y, clusters.start[fitted], n[fitted])
    fit = CircleFit(*(np.full(n.size, np.nan) for _ in range(4)))
    for full, f in zip(fit, part):
        full[fitted] = f
    trees = find_trees(points, clusters, fit, scans, cfg)
    arc = (
        np.isfinite(fit.radius)
        & ~has_line
        & (fit.rms <= cfg.circle_max_residual)
        & (fit.radius <= cfg.circle_max_radius)
        & (np.hypot(fit.cx, fit.cy) > middle_range(points, clusters))
    )
    k = np.flatnonzero(arc)
    circles = Circles(
        clusters.scan[k],
        clusters.first_beam[k],
        clusters.last_beam[k],
        fit.cx[k],
        fit.cy[k],
        fit.radius[k],
        fit.rms[k],
        n[k],
    )
    return Features(scans.time, points, clusters, lines, circles, corners, breakpoints, trees)


def detect_trees(scans: LaserScans, cfg: DetectorConfig | None = None) -> Float[np.ndarray, "M 4"]:
    """Tree detections of every scan, as the rows of a Victoria Park log's detections.

    Args:
        scans: the raw scans.
        cfg: the detector settings (default: the ``detector`` section's defaults).

    Returns:
        ``(M, 4)`` rows ``time, range, bearing, diameter``: range to the trunk's centre (m), bearing
        of the centre in the vehicle frame (rad, 0 ahead, left positive), diameter (m); ordered by
        time, then bearing (right to left).
    """
    return extract_features(scans, cfg).tree_table()


def detect_lines(scans: LaserScans, cfg: DetectorConfig | None = None) -> Float[np.ndarray, "L 4"]:
    """Line segment detections of every scan (the walls a ``line`` landmark map is built from), in the
    rows of a log's detections.

    Segments are split-and-merge fits at least ``detector.min_line_length`` long (the paper's L_min)
    with ``detector.min_line_points`` returns (:func:`extract_features`).

    Args:
        scans: the raw scans.
        cfg: the detector settings (default: the ``detector`` section's defaults).

    Returns:
        ``(L, 4)`` rows ``time, rho, alpha, length`` (:meth:`Features.line_table`): the segment's line in
        the sensor frame, ``p . (cos alpha, sin alpha) = rho`` with ``rho >= 0``, and its length (m).
    """
    return extract_features(scans, cfg).line_table()
