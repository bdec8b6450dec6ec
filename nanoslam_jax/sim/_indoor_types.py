"""The indoor scenario's data: its world, feature truth, path and log types and constants
(:mod:`nanoslam_jax.sim.indoor`)."""

from __future__ import annotations

import os
from pathlib import Path
from typing import NamedTuple

import numpy as np
from jaxtyping import Float, Int

from nanoslam_jax.data import LaserScans
from nanoslam_jax.data._types import RawLog
from nanoslam_jax.models._lines import line_through, slope_intercept_from_line


#: The truth files :func:`simulate_indoor_to_dir` writes and their columns.
TRUTH_FILES = {
    "truth_path.csv": ("time", "x", "y", "theta", "sensor_x", "sensor_y"),
    "truth_odometry.csv": ("time", "v", "omega", "sigma_v", "sigma_omega", "slip"),
    "truth_walls.csv": (
        "wall_id",
        "line_id",
        "x0",
        "y0",
        "x1",
        "y1",
        "length",
        "rho",
        "alpha",
        "vertical",
        "a",
        "b",
        "c",
    ),
    "truth_arcs.csv": ("arc_id", "xc", "yc", "radius"),
    "truth_corners.csv": ("corner_id", "x", "y", "wall_a", "wall_b", "line_a", "line_b", "angle_deg"),
    "truth_breakpoints.csv": ("point_id", "x", "y", "wall_id", "line_id", "kind"),
}


#: The world templates ``indoor.template`` names (``random`` picks one of them by the seed).
TEMPLATES = ("room", "l_room", "corridor")
#: Largest acceleration and deceleration of the vehicle (m/s^2).
ACCELERATION = 0.25
#: Clearances (m): a pillar's surface from the walls, from the path; the path from the walls (at least).
_PILLAR_WALL, _PILLAR_PATH, _PATH_WALL = 0.3, 0.5, 0.5
#: A door keeps this far (m) from a corner and from another door.
_DOOR_MARGIN = 0.5
#: Nearest range (m) of a spurious return.
_SPURIOUS_MIN = 0.1
#: Break point kinds (``IndoorWorld.breakpoint_kind``): a door jamb, the free end of a wall.
BREAK_DOOR, BREAK_FREE_END = 0, 1
_BREAK_NAMES = ("door", "free_end")


class IndoorWorld(NamedTuple):
    """The scene of an indoor log, in the SLAM frame.

    Attributes:
        template: the template it was built from (``room``, ``l_room`` or ``corridor``).
        walls: ``(W, 4)`` wall segments ``x0, y0, x1, y1`` (m).
        wall_line: ``(W,)`` the straight wall (line) each segment lies on: the pieces of one wall split by a
            door share it. The partitions are the last rows.
        pillars: ``(P, 3)`` round pillars ``xc, yc, R`` (m).
        corners: ``(C, 2)`` points where two walls meet at an angle.
        corner_walls: ``(C, 2)`` the two wall segments meeting there.
        corner_angle: ``(C,)`` the angle between them on the free side (deg): 90 in a room's corner, 270
            where a wall juts out (the L's inner corner, the corridor block's corners), 135 at a slanted
            wall.
        breakpoints: ``(K, 2)`` free ends of walls: door jambs (pairs, a door's two in a row), then the two
            ends of each partition.
        breakpoint_wall: ``(K,)`` the wall segment each ends.
        breakpoint_kind: ``(K,)`` :data:`BREAK_DOOR` or :data:`BREAK_FREE_END`.
        waypoints: ``(n, 2)`` corners of the closed polygon the path rounds off.
        turn_radius: ``(n,)`` the radius each waypoint's corner is rounded with (m).
    """

    template: str
    walls: Float[np.ndarray, "W 4"]
    wall_line: Int[np.ndarray, " W"]
    pillars: Float[np.ndarray, "P 3"]
    corners: Float[np.ndarray, "C 2"]
    corner_walls: Int[np.ndarray, "C 2"]
    corner_angle: Float[np.ndarray, " C"]
    breakpoints: Float[np.ndarray, "K 2"]
    breakpoint_wall: Int[np.ndarray, " K"]
    breakpoint_kind: Int[np.ndarray, " K"]
    waypoints: Float[np.ndarray, "n 2"]
    turn_radius: Float[np.ndarray, " n"]


class FeatureTruth(NamedTuple):
    """The true features of an indoor world in the form a line map is scored in (the second paper's
    Table 1, :func:`~nanoslam_jax.eval.metrics.feature_map_errors`).

    Attributes:
        lines: ``(L, 2)`` the distinct straight walls ``(rho, alpha)`` (the wall segments a door splits
            share one line), in the order of their line ids.
        line_ids: ``(L,)`` the line id of each row (``IndoorWorld.wall_line``).
        corners: ``(C, 2)`` the rows of ``lines`` meeting at each corner.
        arcs: ``(P, 3)`` the pillars ``(xc, yc, R)``.
        break_points: ``(K, 2)`` the break points (door jambs, free ends).
    """

    lines: Float[np.ndarray, "L 2"]
    line_ids: Int[np.ndarray, " L"]
    corners: Int[np.ndarray, "C 2"]
    arcs: Float[np.ndarray, "P 3"]
    break_points: Float[np.ndarray, "K 2"]


def _feature_truth(
    walls: np.ndarray, wall_line: np.ndarray, corner_lines: np.ndarray, arcs: np.ndarray, break_points: np.ndarray
) -> FeatureTruth:
    ids, first = np.unique(np.asarray(wall_line, dtype=np.int64), return_index=True)
    rho, alpha = hessian_lines(np.asarray(walls, dtype=np.float64).reshape(-1, 4)[first])
    row = np.searchsorted(ids, np.asarray(corner_lines, dtype=np.int64).reshape(-1, 2))
    return FeatureTruth(
        np.stack([rho, alpha], axis=1).reshape(-1, 2),
        ids,
        row,
        np.asarray(arcs, dtype=np.float64).reshape(-1, 3),
        np.asarray(break_points, dtype=np.float64).reshape(-1, 2),
    )


def feature_truth(world: IndoorWorld) -> FeatureTruth:
    """The true lines, corners, arcs and break points of a world (:class:`FeatureTruth`)."""
    return _feature_truth(
        world.walls, world.wall_line, world.wall_line[world.corner_walls], world.pillars, world.breakpoints
    )


def read_feature_truth(directory: str | os.PathLike) -> FeatureTruth | None:
    """The :class:`FeatureTruth` of an indoor log directory from its truth files (``truth_walls.csv``,
    ``truth_corners.csv``, ``truth_arcs.csv``, ``truth_breakpoints.csv``, as :func:`write_indoor_truth`
    writes them); None when the directory has no ``truth_walls.csv``.

    Raises:
        ValueError: a truth file lacks a column it needs (the message names the file and the column).
    """
    d = Path(directory)
    if not (d / "truth_walls.csv").is_file():
        return None

    def table(name: str, columns: tuple[str, ...]) -> dict[str, np.ndarray]:
        path = d / name
        if not path.is_file():
            return {c: np.zeros(0) for c in columns}
        data = np.genfromtxt(path, delimiter=",", names=True, dtype=None, encoding="utf-8", ndmin=1)
        missing = [c for c in columns if c not in (data.dtype.names or ())]
        if missing:
            raise ValueError(f"{path}: expected the column {missing[0]!r} (columns {', '.join(TRUTH_FILES[name])})")
        return {c: np.atleast_1d(data[c]) for c in columns}

    w = table("truth_walls.csv", ("line_id", "x0", "y0", "x1", "y1"))
    c = table("truth_corners.csv", ("line_a", "line_b"))
    a = table("truth_arcs.csv", ("xc", "yc", "radius"))
    b = table("truth_breakpoints.csv", ("x", "y"))
    return _feature_truth(
        np.stack([w["x0"], w["y0"], w["x1"], w["y1"]], axis=1),
        w["line_id"],
        np.stack([c["line_a"], c["line_b"]], axis=1),
        np.stack([a["xc"], a["yc"], a["radius"]], 1),
        np.stack([b["x"], b["y"]], axis=1),
    )


class IndoorPath(NamedTuple):
    """A closed loop of straight pieces and circular arcs, parameterised by arc length from its start.

    Attributes:
        s0: ``(n,)`` arc length at the start of each piece (m); ``s0[0] = 0``.
        length: ``(n,)`` length of each piece (m).
        start: ``(n, 2)`` start point of each piece.
        heading: ``(n,)`` heading at the start of each piece (rad, continuous along the loop).
        kappa: ``(n,)`` curvature (1/m, left positive; 0 on straight pieces).
        total: the loop's length (m).
        turn: the heading gained per lap (``+-2 pi``).
    """

    s0: Float[np.ndarray, " n"]
    length: Float[np.ndarray, " n"]
    start: Float[np.ndarray, "n 2"]
    heading: Float[np.ndarray, " n"]
    kappa: Float[np.ndarray, " n"]
    total: float
    turn: float

    def at(
        self, s: Float[np.ndarray, " m"]
    ) -> tuple[Float[np.ndarray, "m 2"], Float[np.ndarray, " m"], Float[np.ndarray, " m"]]:
        """Point, heading (continuous over laps) and curvature at arc lengths ``s`` (any number of laps)."""
        s = np.asarray(s, dtype=np.float64)
        lap = np.floor(s / self.total)
        sl = np.clip(s - lap * self.total, 0.0, self.total)
        i = np.clip(np.searchsorted(self.s0, sl, side="right") - 1, 0, self.s0.size - 1)
        u, k, h0 = sl - self.s0[i], self.kappa[i], self.heading[i]
        h = h0 + k * u
        straight = k == 0.0
        ks = np.where(straight, 1.0, k)
        dx = np.where(straight, u * np.cos(h0), (np.sin(h) - np.sin(h0)) / ks)
        dy = np.where(straight, u * np.sin(h0), (np.cos(h0) - np.cos(h)) / ks)
        return self.start[i] + np.stack([dx, dy], axis=1), h + lap * self.turn, k


class IndoorLog(NamedTuple):
    """A simulated indoor log.

    Attributes:
        raw: the log in the loader's form: ``dr`` the logged odometry ``time, v, omega``; ``detections``
            the pillars seen by 3 or more beams of a scan (``time, range, bearing, diameter`` of the centre);
            ``gps`` and ``truth_poses`` the true laser positions and poses (simulated truth, no GPS
            indoors); ``truth_landmarks`` / ``truth_diameters`` the pillars.
        scans: the raw scans.
        world: the scene.
        path: the desired path of the reference point.
        time: ``(N,)`` odometry sample times (s).
        pose: ``(N, 3)`` true reference-point poses ``x, y, theta`` at those times.
        sensor_pose: ``(N, 3)`` true laser poses.
        controls: ``(N, 2)`` true ``(v, omega)`` held over each sample's period.
        sigma: ``(N, 2)`` standard deviations of the noise added to ``v`` (m/s) and ``omega`` (rad/s).
        slip: ``(N,)`` whether the sample lies in a slip episode.
        scan_pose: ``(S, 3)`` true laser pose of each scan.
        kind: ``(S, B)`` what each beam's return came from (``KIND_WALL``, ``KIND_TREE`` for a pillar, -1
            none, a dropout or a spurious return).
        object_id: ``(S, B)`` the wall segment or pillar, -1 for none.
    """

    raw: RawLog
    scans: LaserScans
    world: IndoorWorld
    path: IndoorPath
    time: Float[np.ndarray, " N"]
    pose: Float[np.ndarray, "N 3"]
    sensor_pose: Float[np.ndarray, "N 3"]
    controls: Float[np.ndarray, "N 2"]
    sigma: Float[np.ndarray, "N 2"]
    slip: np.ndarray
    scan_pose: Float[np.ndarray, "S 3"]
    kind: Int[np.ndarray, "S B"]
    object_id: Int[np.ndarray, "S B"]


# --------------------------------------------------------------------------- line parameters


def hessian_lines(segments: Float[np.ndarray, "W 4"]) -> tuple[Float[np.ndarray, " W"], Float[np.ndarray, " W"]]:
    """Hessian normal form ``(rho, alpha)`` of the lines through segments
    (:func:`~nanoslam_jax.models.line_through`): the points ``p`` of the line satisfy ``p . (cos alpha,
    sin alpha) = rho`` with ``rho >= 0`` (the distance from the origin) and ``alpha`` in ``(-pi, pi]`` (the
    direction of the foot of the perpendicular)."""
    seg = np.asarray(segments, dtype=np.float64).reshape(-1, 4)
    line = np.asarray(line_through(seg[:, :2], seg[:, 2:]))
    return line[:, 0], line[:, 1] + 0.0  # + 0.0: no -0.0


def slope_intercept_lines(segments: Float[np.ndarray, "W 4"]) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The paper's line forms (eq. 14-15) of the lines through segments
    (:func:`~nanoslam_jax.models.slope_intercept_from_line`): ``y = a x + b``, or ``x = c`` for a vertical
    line.

    Returns:
        ``(vertical, a, b, c)``: ``(W,)`` booleans (the line's slope exceeds 1e12: the segment's ends share
        their x coordinate to 1e-12 of its length) and the parameters, NaN where the other form applies.
    """
    rho, alpha = hessian_lines(segments)
    form = slope_intercept_from_line(np.stack([rho, alpha], axis=1), max_slope=1e12)
    vertical = np.asarray(form.vertical)
    a, b, c = (
        np.where(vertical == v, np.asarray(x), np.nan) for v, x in ((False, form.a), (False, form.b), (True, form.c))
    )
    return vertical, a, b, c
