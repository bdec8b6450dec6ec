"""Returns of all scans as one flat point set, cut into clusters by the adaptive breakpoint detector
(Borges & Aldon 2004): neighbouring returns ``p``, ``p'`` at ranges ``r``, ``r'`` and angular step
``dphi`` belong to one cluster when ``|p - p'| <= min(r, r') sin(dphi) / sin(lambda - dphi) + 3 sigma_r``,
the largest gap a surface seen at incidence ``lambda`` or steeper leaves, plus the range noise.
Up to ``max_dropout_beams`` neighbouring no-return beams between two returns (dropouts) do not end a
cluster when the two returns pass that test (with ``dphi`` the angle between them); more do."""

from __future__ import annotations

import numpy as np
from jaxtyping import Bool, Float

from nanoslam_jax.frontend._settings import DetectorConfig
from nanoslam_jax.data import LaserScans
from nanoslam_jax.frontend._types import (
    EDGE_FARTHER,
    EDGE_FOV,
    EDGE_NEARER,
    EDGE_NO_RETURN,
    Clusters,
    Points,
)

__all__ = ["breakpoint_threshold", "find_clusters", "scan_points"]


def scan_points(scans: LaserScans, cfg: DetectorConfig) -> tuple[Points, Bool[np.ndarray, "S B"]]:
    """The returns of every scan (range below both the scanner's and the detector's maximum).

    Args:
        scans: the raw scans.
        cfg: the detector settings (``max_range``).

    Returns:
        ``(points, valid)``: the returns, scan by scan in beam order, and the ``(S, B)`` mask of
        beams that returned.
    """
    ranges = scans.ranges
    valid = (ranges < min(cfg.max_range, scans.max_range)) & (ranges > 0)
    flat = np.flatnonzero(valid)
    scan, beam = np.divmod(flat, scans.n_beams)
    r = ranges.ravel()[flat]
    a = scans.angles[beam]
    return Points(scan, beam, r, r * np.cos(a), r * np.sin(a)), valid


def breakpoint_threshold(
    r0: Float[np.ndarray, "..."], r1: Float[np.ndarray, "..."], dphi: Float[np.ndarray, "..."], cfg: DetectorConfig
) -> Float[np.ndarray, "..."]:
    """The adaptive breakpoint distance between returns at ranges ``r0``, ``r1`` an angle ``dphi`` apart (m)."""
    lam = np.deg2rad(cfg.breakpoint_lambda_deg)
    return np.asarray(
        np.minimum(r0, r1) * np.sin(dphi) / np.sin(np.maximum(lam - dphi, 1e-9)) + 3.0 * cfg.breakpoint_sigma_r
    )


def find_clusters(points: Points, valid: Bool[np.ndarray, "S B"], scans: LaserScans, cfg: DetectorConfig) -> Clusters:
    """Cut the returns into clusters at breakpoints, no-return beams and scan ends.

    Args:
        points: the returns (:func:`scan_points`).
        valid: which beams returned.
        scans: the scans (ranges and beam angles, for the edges' neighbours).
        cfg: the detector settings.
    """
    n = points.r.size
    step = points.beam[1:] - points.beam[:-1]
    same = (points.scan[1:] == points.scan[:-1]) & (step >= 1) & (step <= cfg.max_dropout_beams + 1)
    gap = np.hypot(np.diff(points.x), np.diff(points.y))
    dphi = np.abs(scans.angles[np.minimum(points.beam[1:], scans.n_beams - 1)] - scans.angles[points.beam[:-1]])
    joined = same & (gap <= breakpoint_threshold(points.r[:-1], points.r[1:], dphi, cfg))
    start = np.flatnonzero(np.concatenate([[True], ~joined])) if n else np.zeros(0, int)
    end = np.concatenate([start[1:] - 1, [n - 1]]) if n else np.zeros(0, int)
    scan, first, last = points.scan[start], points.beam[start], points.beam[end]
    return Clusters(
        scan,
        start,
        end,
        first,
        last,
        _edge(scans, valid, scan, first, first - 1, points.r[start]),
        _edge(scans, valid, scan, last, last + 1, points.r[end]),
    )


def _edge(
    scans: LaserScans, valid: np.ndarray, scan: np.ndarray, beam: np.ndarray, beyond: np.ndarray, r_edge: np.ndarray
) -> np.ndarray:
    """What the beam beyond a cluster's edge saw (``EDGE_*`` codes)."""
    inside = (beyond >= 0) & (beyond < scans.n_beams)
    b = np.clip(beyond, 0, scans.n_beams - 1)
    returned = inside & valid[scan, b]
    nearer = returned & (scans.ranges[scan, b] < r_edge)
    return np.where(~inside, EDGE_FOV, np.where(~returned, EDGE_NO_RETURN, np.where(nearer, EDGE_NEARER, EDGE_FARTHER)))
