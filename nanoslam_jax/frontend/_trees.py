"""The tree detector: clusters that are trunks, measured as the Victoria Park log reports trees.

A cluster whose first and last beams are ``n - 1`` beam steps apart spans the angle ``w = n dphi``
(each beam covers ``dphi``; bridged dropouts count). A trunk of radius ``R`` whose nearest surface
lies at range ``r_s`` subtends ``2 asin(R / (r_s + R))``, so ``R = r_s sin(w / 2) / (1 - sin(w / 2))``;
the centre lies at range ``r_s + R`` on the bisector of the cluster's first and last beams; ``r_s`` is
the range at the cluster's middle. From ``tree_fit_min_points`` returns on, the least-squares circle
replaces that estimate when it is convex, passes the residual test and agrees with the angular width.
These estimates serve the plausibility tests; a cluster that passes them is measured by the trunk
profile fit (:mod:`._profile`: its edges placed between its edge beams and the beams beside them by
how well a trunk that wide explains its ranges), which resolves the diameter below the beam spacing.

A cluster is no tree when it has fewer than ``tree_min_returns`` returns; when its circle fit is flat
(a straight piece of a wall or fence), concave or rough; when its ranges do not follow the near side
of a trunk as wide as the cluster (``tree_max_profile_residual``: bush fragments, oblique wall pieces);
when it is too wide (walls, fences), thin, near or far; when its first and last returns
differ in range by more than a fraction of its diameter (an oblique surface); when another cluster
ends within ``tree_min_separation`` of its ends or any other return lies within
``tree_min_clearance`` of its surface (foliage, fences, people: a trunk stands alone); when it
reaches the edge of the field of view; or when a nearer return hides one of its edges (partly seen).
"""

from __future__ import annotations

import numpy as np

from nanoslam_jax.frontend._settings import DetectorConfig
from nanoslam_jax.data import LaserScans
from nanoslam_jax.frontend._circles import CircleFit
from nanoslam_jax.frontend._profile import fit_trunk_profiles
from nanoslam_jax.frontend._types import EDGE_FOV, EDGE_NEARER, EDGE_NO_RETURN, Clusters, Points, Trees

__all__ = ["find_trees", "middle_range", "width_radius"]


def middle_range(points: Points, clusters: Clusters) -> np.ndarray:
    """Range (m) at each cluster's middle: its middle return's, or the mean of its two middle returns'."""
    n = clusters.n
    return 0.5 * (points.r[clusters.start + (n - 1) // 2] + points.r[clusters.start + n // 2])


def width_radius(surface_range, n_beams, dphi):
    """Radius (m) of a trunk whose nearest surface is at ``surface_range`` and that ``n_beams`` beams
    ``dphi`` apart hit (it subtends ``n_beams * dphi``)."""
    s = np.sin(np.minimum(0.5 * n_beams * dphi, 0.5 * np.pi - 1e-6))
    return surface_range * s / (1.0 - s)


def find_trees(points: Points, clusters: Clusters, fit: CircleFit, scans: LaserScans, cfg: DetectorConfig) -> Trees:
    """The clusters that are trees, with their centre range, bearing and diameter.

    Args:
        points: the returns.
        clusters: their clusters.
        fit: each cluster's circle fit (NaN for clusters of fewer than ``circle_min_points``).
        scans: the scans (beam angles, times).
        cfg: the detector settings.
    """
    n = clusters.n
    dphi = float(np.abs(scans.angles[1] - scans.angles[0])) if scans.n_beams > 1 else 0.0
    a0, a1 = scans.angles[clusters.first_beam], scans.angles[clusters.last_beam]
    r_s = middle_range(points, clusters)
    span = clusters.last_beam - clusters.first_beam + 1
    r_w = width_radius(r_s, span, dphi)
    # angular-width estimate
    rng, brg, rad = r_s + r_w, 0.5 * (a0 + a1), r_w
    # circle fit where it is trustworthy
    c_range = np.hypot(fit.cx, fit.cy)
    has_fit = np.isfinite(fit.radius)
    convex = has_fit & (c_range > r_s)
    smooth = has_fit & (fit.rms <= cfg.tree_max_residual)
    ratio = cfg.tree_max_fit_ratio
    agrees = has_fit & (fit.radius <= ratio * r_w) & (fit.radius >= r_w / ratio)
    big = n >= cfg.tree_fit_min_points
    use_fit = big & convex & smooth & agrees
    rng = np.where(use_fit, c_range, rng)
    brg = np.where(use_fit, np.arctan2(fit.cy, fit.cx), brg)
    rad = np.where(use_fit, fit.radius, rad)
    diameter = 2 * rad
    # plausibility
    x0, y0 = points.x[clusters.start], points.y[clusters.start]
    x1, y1 = points.x[clusters.end], points.y[clusters.end]
    chord = np.hypot(x1 - x0, y1 - y0)
    asym = np.abs(points.r[clusters.end] - points.r[clusters.start])
    flat = big & has_fit & (~convex | (fit.radius > ratio * r_w) | (fit.rms > cfg.tree_max_residual))
    ok = (
        ~flat
        & (diameter >= cfg.tree_min_diameter)
        & (diameter <= cfg.tree_max_diameter)
        & (chord <= cfg.tree_max_diameter)
        & (r_s >= cfg.tree_min_range)
        & (rng <= cfg.tree_max_range)
        & (asym <= cfg.tree_max_asymmetry * diameter)
    )
    ok &= _separation(points, clusters) >= cfg.tree_min_separation
    margin = np.deg2rad(cfg.edge_margin_deg)
    ok &= (a0 - 0.5 * dphi >= scans.angles[0] + margin - 1e-9) & (a1 + 0.5 * dphi <= scans.angles[-1] - margin + 1e-9)
    ok &= (clusters.left != EDGE_FOV) & (clusters.right != EDGE_FOV)
    if cfg.reject_occluded:
        ok &= (clusters.left != EDGE_NEARER) & (clusters.right != EDGE_NEARER)
    if cfg.reject_no_return_edge:
        ok &= (clusters.left != EDGE_NO_RETURN) & (clusters.right != EDGE_NO_RETURN)
    ok &= n >= cfg.tree_min_returns
    k = np.flatnonzero(ok)
    if cfg.tree_min_clearance > 0:
        keep = _clearance(scans, clusters, k, rng, brg, rad, cfg.max_range) >= cfg.tree_min_clearance
        k = k[keep]
    # the trunk's measure: from the ranges of its beams and the beams beside it that missed it
    prof = fit_trunk_profiles(
        points.r, scans.angles[points.beam], clusters.start[k], n[k], a0[k], a1[k], dphi, cfg.tree_range_noise
    )
    rng[k], brg[k], rad[k] = prof.range, prof.bearing, prof.radius
    diameter = 2 * rad
    round_ = (n[k] < 3) | (prof.rms <= cfg.tree_max_profile_residual)
    k = k[round_ & (diameter[k] >= cfg.tree_min_diameter) & (diameter[k] <= cfg.tree_max_diameter)]
    return Trees(
        clusters.scan[k],
        scans.time[clusters.scan[k]],
        rng[k],
        brg[k],
        diameter[k],
        clusters.first_beam[k],
        clusters.last_beam[k],
        use_fit[k].astype(np.int64),
    )


def _separation(points: Points, clusters: Clusters) -> np.ndarray:
    """Distance (m) from each cluster's end returns to the nearest end return of the clusters beside
    it in its scan (infinite where there is none)."""
    c = clusters.scan.size
    gap = np.full(c, np.inf)
    if c < 2:
        return gap
    same = clusters.scan[1:] == clusters.scan[:-1]
    d = np.hypot(
        points.x[clusters.start[1:]] - points.x[clusters.end[:-1]],
        points.y[clusters.start[1:]] - points.y[clusters.end[:-1]],
    )
    d = np.where(same, d, np.inf)
    gap[1:] = np.minimum(gap[1:], d)
    gap[:-1] = np.minimum(gap[:-1], d)
    return gap


def _clearance(
    scans: LaserScans,
    clusters: Clusters,
    k: np.ndarray,
    rng: np.ndarray,
    brg: np.ndarray,
    rad: np.ndarray,
    max_range: float,
    block: int = 4096,
) -> np.ndarray:
    """For the clusters ``k``: the distance (m) from the trunk's surface (centre ``rng``, ``brg``,
    radius ``rad``) to the nearest return of its scan outside the cluster."""
    out = np.empty(k.size)
    beams = np.arange(scans.n_beams)
    cos_a, sin_a = np.cos(scans.angles), np.sin(scans.angles)
    for lo in range(0, k.size, block):
        kk = k[lo : lo + block]
        r = scans.ranges[clusters.scan[kk]]
        cx, cy = rng[kk] * np.cos(brg[kk]), rng[kk] * np.sin(brg[kk])
        d = np.hypot(r * cos_a - cx[:, None], r * sin_a - cy[:, None])
        own = (beams >= clusters.first_beam[kk, None]) & (beams <= clusters.last_beam[kk, None])
        d = np.where((r < min(max_range, scans.max_range)) & ~own, d, np.inf)
        out[lo : lo + block] = d.min(axis=1) - rad[kk]
    return out
