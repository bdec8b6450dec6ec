"""The front end's tables: one flat table per feature kind, each row carrying its scan index."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from jaxtyping import Float, Int

#: Codes of what lies beyond a cluster's edge beam (:attr:`Clusters.left` / :attr:`Clusters.right`,
#: :attr:`BreakPoints.beyond`).
EDGE_FARTHER, EDGE_NEARER, EDGE_NO_RETURN, EDGE_FOV = 0, 1, 2, 3
EDGE_NAMES = ("farther", "nearer", "no_return", "fov_edge")


class Points(NamedTuple):
    """The returns of all scans (beams below the detector's maximum range), scan by scan in beam order.

    Attributes:
        scan: scan index of each return.
        beam: beam index.
        r: range (m).
        x: forward coordinate in the vehicle frame (m).
        y: leftward coordinate (m).
    """

    scan: Int[np.ndarray, " N"]
    beam: Int[np.ndarray, " N"]
    r: Float[np.ndarray, " N"]
    x: Float[np.ndarray, " N"]
    y: Float[np.ndarray, " N"]


class Clusters(NamedTuple):
    """Runs of neighbouring returns not split by the adaptive breakpoint detector.

    Attributes:
        scan: scan index.
        start: index of the first return in :class:`Points`.
        end: index of the last return (inclusive).
        first_beam: beam index of the first return (rightmost).
        last_beam: beam index of the last return (leftmost).
        left: what lies beyond the first beam (``EDGE_*`` code) ...
        right: ... and beyond the last beam.
    """

    scan: Int[np.ndarray, " C"]
    start: Int[np.ndarray, " C"]
    end: Int[np.ndarray, " C"]
    first_beam: Int[np.ndarray, " C"]
    last_beam: Int[np.ndarray, " C"]
    left: Int[np.ndarray, " C"]
    right: Int[np.ndarray, " C"]

    @property
    def n(self) -> Int[np.ndarray, " C"]:
        """Returns per cluster."""
        return self.end - self.start + 1


class Lines(NamedTuple):
    """Line segments (split-and-merge, collinear neighbours merged), total least squares fits.

    Attributes:
        scan: scan index.
        first_beam, last_beam: beams of the segment's first and last return.
        x0, y0, x1, y1: its end points projected on the fitted line (m, vehicle frame).
        alpha: direction of the line's normal (rad) ...
        rho: ... and its distance from the sensor (m, >= 0): points p on it satisfy
            ``p . (cos alpha, sin alpha) = rho``.
        length: distance between the end points (m).
        rms: RMS distance of its points to the line (m).
        n: its returns.
    """

    scan: Int[np.ndarray, " L"]
    first_beam: Int[np.ndarray, " L"]
    last_beam: Int[np.ndarray, " L"]
    x0: Float[np.ndarray, " L"]
    y0: Float[np.ndarray, " L"]
    x1: Float[np.ndarray, " L"]
    y1: Float[np.ndarray, " L"]
    alpha: Float[np.ndarray, " L"]
    rho: Float[np.ndarray, " L"]
    length: Float[np.ndarray, " L"]
    rms: Float[np.ndarray, " L"]
    n: Int[np.ndarray, " L"]


class Circles(NamedTuple):
    """Clusters that are arcs: least-squares circles passing the residual test (trees, poles, arcs).

    Attributes:
        scan: scan index.
        first_beam, last_beam: the cluster's beams.
        cx, cy: centre (m, vehicle frame).
        radius: radius (m).
        rms: RMS geometric residual (m).
        n: returns fitted.
    """

    scan: Int[np.ndarray, " K"]
    first_beam: Int[np.ndarray, " K"]
    last_beam: Int[np.ndarray, " K"]
    cx: Float[np.ndarray, " K"]
    cy: Float[np.ndarray, " K"]
    radius: Float[np.ndarray, " K"]
    rms: Float[np.ndarray, " K"]
    n: Int[np.ndarray, " K"]


class Corners(NamedTuple):
    """Corner points: two line segments of one cluster meeting at an angle.

    Attributes:
        scan: scan index.
        beam: beam of the shared vertex.
        x, y: intersection of the two lines (m).
        angle: angle between the lines' directions (rad, in (0, pi/2]).
    """

    scan: Int[np.ndarray, " Q"]
    beam: Int[np.ndarray, " Q"]
    x: Float[np.ndarray, " Q"]
    y: Float[np.ndarray, " Q"]
    angle: Float[np.ndarray, " Q"]


class BreakPoints(NamedTuple):
    """Ends of line segments at a range discontinuity (a cluster's edge).

    Attributes:
        scan: scan index.
        beam: beam of the end return.
        x, y: the line's end point (m).
        beyond: what the neighbouring beam saw (``EDGE_*``): ``farther`` or ``no_return``: the
            object ends here; ``nearer``: hidden behind something (not its true end); ``fov_edge``:
            the scan ends.
    """

    scan: Int[np.ndarray, " P"]
    beam: Int[np.ndarray, " P"]
    x: Float[np.ndarray, " P"]
    y: Float[np.ndarray, " P"]
    beyond: Int[np.ndarray, " P"]


class Trees(NamedTuple):
    """Tree detections as the Victoria Park log reports them.

    Attributes:
        scan: scan index.
        time: scan time (s).
        range: range to the trunk's centre (m).
        bearing: bearing of the centre in the vehicle frame (rad, 0 ahead, left positive).
        diameter: trunk diameter (m).
        first_beam, last_beam: the cluster's beams.
        fitted: 1 when the cluster's least-squares circle passed its tests (``tree_fit_min_points``
            returns or more, convex, smooth, not flat), 0 when only the angular width vouched for it.
    """

    scan: Int[np.ndarray, " M"]
    time: Float[np.ndarray, " M"]
    range: Float[np.ndarray, " M"]
    bearing: Float[np.ndarray, " M"]
    diameter: Float[np.ndarray, " M"]
    first_beam: Int[np.ndarray, " M"]
    last_beam: Int[np.ndarray, " M"]
    fitted: Int[np.ndarray, " M"]


class Features(NamedTuple):
    """Everything the front end extracts from a log's scans (flat tables; ``scan`` indexes the scans).

    Attributes:
        time: ``(S,)`` scan times (s).
        points: the returns used.
        clusters: breakpoint clusters.
        lines: line segments.
        circles: arcs.
        corners: corner points.
        breakpoints: break points.
        trees: tree detections.
    """

    time: Float[np.ndarray, " S"]
    points: Points
    clusters: Clusters
    lines: Lines
    circles: Circles
    corners: Corners
    breakpoints: BreakPoints
    trees: Trees

    def line_table(self) -> Float[np.ndarray, "L 4"]:
        """The line segments as detections: ``(L, 4)`` rows ``time, rho, alpha, length`` (the line's
        distance from the sensor (m), the bearing of its normal in the vehicle frame (rad, 0 ahead,
        left positive), the segment's length (m)), in the layout of :meth:`tree_table`; ordered by
        time, then beam (right to left)."""
        ln = self.lines
        return np.stack([self.time[ln.scan], ln.rho, ln.alpha, ln.length], axis=1).reshape(-1, 4)

    def tree_table(self) -> Float[np.ndarray, "M 4"]:
        """The trees as ``(M, 4)`` rows ``time, range, bearing (vehicle frame), diameter``."""
        t = self.trees
        return np.stack([t.time, t.range, t.bearing, t.diameter], axis=1).reshape(-1, 4)
