"""Split-and-merge line segments over all clusters at once, their total least squares lines, collinear
neighbours merged, corner points and break points.

Each cluster is a polyline of returns. Its first and last returns are vertices. Every round of
splitting takes, in each segment between consecutive vertices, the return farthest from the chord
joining them and makes it a vertex when it lies beyond ``split_distance``; rounds repeat until no
segment splits. Merging then removes a vertex when the returns between its two neighbouring
vertices all lie within ``split_distance`` of their chord and on average within
``merge_distance`` (alternate vertices per pass, so that no two merges overlap).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from jaxtyping import Bool, Float, Int

from nanoslam_jax.frontend._settings import DetectorConfig
from nanoslam_jax.frontend._types import BreakPoints, Clusters, Corners, Lines, Points

__all__ = ["Segments", "extract_lines", "fit_lines", "polyline_vertices", "segments_of", "split_and_merge"]


def _chord_distance(x, y, ax, ay, bx, by):
    """Distance of points to the chords from ``a`` to ``b`` (to ``a`` itself where they coincide)."""
    dx, dy = bx - ax, by - ay
    length = np.hypot(dx, dy)
    across = np.abs(dx * (y - ay) - dy * (x - ax)) / np.where(length > 0, length, 1.0)
    return np.where(length > 0, across, np.hypot(x - ax, y - ay))


def split_and_merge(
    x: Float[np.ndarray, " N"],
    y: Float[np.ndarray, " N"],
    cluster: Int[np.ndarray, " N"],
    starts: Int[np.ndarray, " C"],
    ends: Int[np.ndarray, " C"],
    split_distance: float,
    merge_distance: float,
    rounds: int = 24,
) -> Bool[np.ndarray, " N"]:
    """The vertices of every cluster's polyline after split-and-merge.

    Args:
        x, y: the points, clusters contiguous.
        cluster: each point's cluster index (non-decreasing).
        starts, ends: each cluster's first and last point index.
        split_distance: d_max (m).
        merge_distance: md_max (m).
        rounds: rounds of splitting, and of merging, at most.

    Returns:
        ``(N,)`` which points are vertices (every cluster's first and last point among them).
    """
    n = x.size
    vertex = np.zeros(n, dtype=bool)
    vertex[starts] = True
    vertex[ends] = True
    if n == 0:
        return vertex
    # splitting: only the points of segments that split in the previous round are examined again
    idx = np.arange(n)
    active = np.flatnonzero(~vertex & (cluster[np.maximum(idx - 1, 0)] == cluster[np.minimum(idx + 1, n - 1)]))
    for _ in range(rounds):
        if active.size == 0:
            break
        vi = np.flatnonzero(vertex)
        seg = (np.cumsum(vertex) - 1)[active]
        a, b = vi[seg], vi[seg + 1]
        dist = _chord_distance(x[active], y[active], x[a], y[a], x[b], y[b])
        first = np.flatnonzero(np.concatenate([[True], seg[1:] != seg[:-1]]))
        segmax = np.maximum.reduceat(dist, first)
        which = np.cumsum(np.concatenate([[False], seg[1:] != seg[:-1]]))
        cand = np.flatnonzero((dist > split_distance) & (dist == segmax[which]))
        if cand.size == 0:
            break
        cand = cand[np.concatenate([[True], seg[cand][1:] != seg[cand][:-1]])]
        vertex[active[cand]] = True
        split = np.zeros(first.size, dtype=bool)
        split[which[cand]] = True
        active = active[split[which] & ~vertex[active]]
    # merging: alternate interior vertices per pass, so that no two merges overlap
    for _ in range(rounds):
        changed = False
        for parity in (0, 1):
            vi = np.flatnonzero(vertex)
            m = vi.size
            cl = cluster[vi]
            interior = np.zeros(m, dtype=bool)
            interior[1:-1] = (cl[1:-1] == cl[:-2]) & (cl[1:-1] == cl[2:])
            cand = interior & (np.arange(m) % 2 == parity)
            if not cand.any():
                continue
            # the points between the candidate's neighbouring vertices (first one excluded: distance 0)
            c = np.flatnonzero(cand)
            lo, hi = vi[c - 1] + 1, vi[c + 1]
            cnt = hi - lo
            pts = np.repeat(lo - np.concatenate([[0], np.cumsum(cnt)[:-1]]), cnt) + np.arange(cnt.sum())
            o = np.repeat(c, cnt)
            a, b = vi[o - 1], vi[o + 1]
            dist = _chord_distance(x[pts], y[pts], x[a], y[a], x[b], y[b])
            offs = np.concatenate([[0], np.cumsum(cnt)[:-1]])
            dmax = np.maximum.reduceat(dist, offs)
            dsum = np.add.reduceat(dist, offs)
            ok = (dmax <= split_distance) & (dsum <= merge_distance * (cnt + 1))
            if ok.any():
                vertex[vi[c[ok]]] = False
                changed = True
        if not changed:
            break
    return vertex


def polyline_vertices(x, y, split_distance: float, merge_distance: float, rounds: int = 24) -> Int[np.ndarray, " V"]:
    """The vertex indices of one polyline (all points one cluster) after split-and-merge."""
    x, y = np.asarray(x, dtype=np.float64), np.asarray(y, dtype=np.float64)
    v = split_and_merge(
        x,
        y,
        np.zeros(x.size, dtype=np.int64),
        np.array([0]),
        np.array([x.size - 1]),
        split_distance,
        merge_distance,
        rounds,
    )
    return np.flatnonzero(v)


class Segments(NamedTuple):
    """Segments between consecutive vertices of one cluster (inclusive point ranges)."""

    start: Int[np.ndarray, " G"]
    end: Int[np.ndarray, " G"]
    cluster: Int[np.ndarray, " G"]


def segments_of(vertex: Bool[np.ndarray, " N"], cluster: Int[np.ndarray, " N"]) -> Segments:
    """The segments a vertex mask cuts the clusters into."""
    vi = np.flatnonzero(vertex)
    same = cluster[vi[1:]] == cluster[vi[:-1]]
    return Segments(vi[:-1][same], vi[1:][same], cluster[vi[:-1][same]])


class _LineFit(NamedTuple):
    n: np.ndarray
    sx: np.ndarray
    sy: np.ndarray
    sxx: np.ndarray
    sxy: np.ndarray
    syy: np.ndarray


def _sums(x, y, start, end) -> _LineFit:
    def cs(v):
        c = np.concatenate([[0.0], np.cumsum(v)])
        return c[end + 1] - c[start]

    return _LineFit((end - start + 1).astype(np.float64), cs(x), cs(y), cs(x * x), cs(x * y), cs(y * y))


def fit_lines(s: _LineFit) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Total least squares lines from point sums: ``(alpha, rho, rms)`` (normal direction, distance >= 0,
    RMS distance of the points)."""
    n = np.maximum(s.n, 1.0)
    mx, my = s.sx / n, s.sy / n
    cxx, cxy, cyy = s.sxx / n - mx * mx, s.sxy / n - mx * my, s.syy / n - my * my
    theta = 0.5 * np.arctan2(2 * cxy, cxx - cyy)  # direction of largest spread
    alpha = theta + np.pi / 2
    rho = mx * np.cos(alpha) + my * np.sin(alpha)
    alpha = np.where(rho < 0, alpha + np.pi, alpha)
    rho = np.abs(rho)
    alpha = np.arctan2(np.sin(alpha), np.cos(alpha))
    half = 0.5 * (cxx + cyy)
    small = half - np.sqrt(np.maximum(0.25 * (cxx - cyy) ** 2 + cxy * cxy, 0.0))
    return alpha, rho, np.sqrt(np.maximum(small, 0.0))


def _project(x, y, alpha, rho):
    c, s = np.cos(alpha), np.sin(alpha)
    d = x * c + y * s - rho
    return x - d * c, y - d * s


def extract_lines(
    points: Points, clusters: Clusters, cfg: DetectorConfig
) -> tuple[Lines, Corners, BreakPoints, Bool[np.ndarray, " C"]]:
    """Line segments, corners and break points of all clusters.

    Args:
        points: the returns.
        clusters: their clusters.
        cfg: the detector settings.

    Returns:
        ``(lines, corners, breakpoints, has_line)``; ``has_line`` marks the clusters holding a line.
    """
    x, y = points.x, points.y
    cluster = np.repeat(np.arange(clusters.start.size), clusters.n)
    vertex = split_and_merge(
        x, y, cluster, clusters.start, clusters.end, cfg.split_distance, cfg.merge_distance, cfg.split_rounds
    )
    seg = segments_of(vertex, cluster)
    sums = _sums(x, y, seg.start, seg.end)
    alpha, rho, rms = fit_lines(sums)
    x0, y0 = _project(x[seg.start], y[seg.start], alpha, rho)
    x1, y1 = _project(x[seg.end], y[seg.end], alpha, rho)
    length = np.hypot(x1 - x0, y1 - y0)
    is_line = (length >= cfg.min_line_length) & (sums.n >= cfg.min_line_points)
    has_line = np.zeros(clusters.start.size, dtype=bool)
    has_line[seg.cluster[is_line]] = True

    # corners: consecutive segments of one cluster, both lines, sharing a vertex
    both = is_line[:-1] & is_line[1:] & (seg.end[:-1] == seg.start[1:])
    i = np.flatnonzero(both)
    a1, a2 = alpha[i], alpha[i + 1]
    ang = np.abs(np.arctan2(np.sin(a1 - a2), np.cos(a1 - a2)))
    ang = np.minimum(ang, np.pi - ang)
    det = np.sin(a2 - a1)
    keep = ang >= np.deg2rad(cfg.corner_min_angle_deg)
    i, det, ang = i[keep], det[keep], ang[keep]
    r1, r2, a1, a2 = rho[i], rho[i + 1], alpha[i], alpha[i + 1]
    cx = (r1 * np.sin(a2) - r2 * np.sin(a1)) / det
    cy = (r2 * np.cos(a1) - r1 * np.cos(a2)) / det
    vtx = seg.end[i]
    corners = Corners(points.scan[vtx], points.beam[vtx], cx, cy, ang)

    # break points: line ends at a cluster edge
    li = np.flatnonzero(is_line)
    at_start = seg.start[li] == clusters.start[seg.cluster[li]]
    at_end = seg.end[li] == clusters.end[seg.cluster[li]]
    bp_idx = np.concatenate([seg.start[li][at_start], seg.end[li][at_end]])
    bp_x = np.concatenate([x0[li][at_start], x1[li][at_end]])
    bp_y = np.concatenate([y0[li][at_start], y1[li][at_end]])
    bp_beyond = np.concatenate([clusters.left[seg.cluster[li][at_start]], clusters.right[seg.cluster[li][at_end]]])
    order = np.argsort(bp_idx, kind="stable")
    breakpoints = BreakPoints(
        points.scan[bp_idx][order], points.beam[bp_idx][order], bp_x[order], bp_y[order], bp_beyond[order]
    )

    lines = _merge_collinear(points, seg, sums, is_line, _Ends(x0, y0, x1, y1), cfg)
    return lines, corners, breakpoints, has_line


class _Ends(NamedTuple):
    """The ends of every segment projected onto its fitted line: ``(x0, y0)`` at its first point,
    ``(x1, y1)`` at its last."""

    x0: np.ndarray
    y0: np.ndarray
    x1: np.ndarray
    y1: np.ndarray


def _merge_collinear(points: Points, seg: Segments, sums: _LineFit, is_line, ends: _Ends, cfg: DetectorConfig) -> Lines:
    """Lines of neighbouring clusters (next to each other in a scan) on one straight line joined into one."""
    li = np.flatnonzero(is_line)
    alpha, rho, _ = fit_lines(_LineFit(*(f[li] for f in sums)))
    scan = points.scan[seg.start[li]]
    ex0, ey0, ex1, ey1 = ends.x0[li], ends.y0[li], ends.x1[li], ends.y1[li]
    da = np.abs(np.arctan2(np.sin(alpha[1:] - alpha[:-1]), np.cos(alpha[1:] - alpha[:-1])))
    d_next = np.abs(ex0[1:] * np.cos(alpha[:-1]) + ey0[1:] * np.sin(alpha[:-1]) - rho[:-1])
    d_prev = np.abs(ex1[:-1] * np.cos(alpha[1:]) + ey1[:-1] * np.sin(alpha[1:]) - rho[1:])
    gap = np.hypot(ex0[1:] - ex1[:-1], ey0[1:] - ey1[:-1])
    join = (
        (scan[1:] == scan[:-1])
        & (seg.cluster[li][1:] != seg.cluster[li][:-1])
        & (da < np.deg2rad(cfg.collinear_angle_deg))
        & (d_next < cfg.collinear_distance)
        & (d_prev < cfg.collinear_distance)
        & (gap < cfg.collinear_gap)
    )
    group = np.cumsum(np.concatenate([[True], ~join])[: li.size]) - 1
    g = group.max() + 1 if group.size else 0
    merged = _LineFit(*(np.bincount(group, weights=f[li], minlength=g) for f in sums))
    alpha, rho, rms = fit_lines(merged)
    first = np.flatnonzero(np.concatenate([[True], ~join])[: li.size])
    last = np.concatenate([first[1:] - 1, [li.size - 1]]) if li.size else first
    s_idx, e_idx = seg.start[li][first], seg.end[li][last]
    gx0, gy0 = _project(points.x[s_idx], points.y[s_idx], alpha, rho)
    gx1, gy1 = _project(points.x[e_idx], points.y[e_idx], alpha, rho)
    return Lines(
        points.scan[s_idx],
        points.beam[s_idx],
        points.beam[e_idx],
        gx0,
        gy0,
        gx1,
        gy1,
        alpha,
        rho,
        np.hypot(gx1 - gx0, gy1 - gy0),
        rms,
        merged.n.astype(np.int64),
    )
