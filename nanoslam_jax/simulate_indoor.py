"""An indoor scenario (``nanoslam simulate --scenario indoor``): a low-speed differential-drive vehicle in
rooms or corridors of straight walls, corners, door gaps and round pillars, with raw laser scans and the
truth of every line, arc, corner and break point (the experiment of the NASRUKF paper, sections 4-5).

**The world** (section ``indoor``, :func:`build_world`) is exact geometry: wall segments and circles.
``indoor.template`` picks one of

* ``room``: a rectangular room 6-10 m by 5-8 m, one of its far corners cut by a slanted wall half the
  time (a line of general slope, two obtuse corners);
* ``l_room``: an L-shaped room 9-12 m by 8-11 m with arms 4.4-5.4 m wide (a reflex corner that juts
  into the room);
* ``corridor``: a ring corridor around a closed block (offices), 1.8-2.4 m wide, one side a hall
  3.6-4.6 m wide; the block's walls have doors too, so beams reach into its rooms;
* ``random``: one of the three, chosen by the seed.

Sizes are drawn from the seed; the world is mirrored (driven clockwise instead of counter-clockwise)
for half the seeds. ``indoor.doors`` door gaps ``indoor.door_width`` wide are cut into walls long enough
(0.5 m at least from a corner and from another door); their jambs are break points. ``indoor.pillars``
round pillars of radius ``indoor.pillar_radius_min`` to ``indoor.pillar_radius_max`` stand inside,
0.3 m at least from the walls and 0.5 m from the driven path (surface to path). ``indoor.partitions``
free-standing partition walls ``indoor.partition_length`` long, at random angles (lines of any slope),
keep 0.5 m from the walls, the path and the pillars; their ends are free-end break points.

**The path** is the room's outline inset by ``indoor.path_inset`` (the corridor's centre line; in the
hall, its middle), a closed loop of straight lines and circular arcs: each corner is rounded with radius
``indoor.turn_radius``, reduced where the arc would pass nearer than 0.5 m to a wall. The vehicle stands
still for ``indoor.static_time`` seconds (the paper's static state estimation), then laps the loop. Its
speed follows ``speed_min + (speed_max - speed_min) (1 + sin(2 pi t / P + phase)) / 2`` (P drawn in
20-40 s), capped so that the turn rate stays below ``indoor.max_turn_rate_deg`` on the arcs within
braking distance ahead, with accelerations of at most :data:`ACCELERATION`.

**The vehicle** is a differential-drive body whose reference point (the centre of the wheel axle, the
paper's ``(x, y, theta)``) follows the path; the laser sits ``indoor.sensor_ls`` behind it (the paper's
``Ls = 180 mm``; negative: ahead), so it is the :class:`~nanoslam_jax.models.Unicycle` model with
``sensor_x = -sensor_ls``. Odometry ``(v, omega)`` comes every ``indoor.odom_period`` seconds (the paper's
25 ms data period) and is held over the period. The truth is integrated with the model's own step (the
Euler step of :class:`~nanoslam_jax.models.Unicycle`, vectorised as cumulative sums), and the controls are
chosen so that the reference point lies exactly on the desired path at every sample: a filter fed the
true controls has no model error.

**Odometry noise with time-varying statistics (wheel slip).** The logged ``v`` and ``omega`` are the true
ones plus white Gaussian noise of standard deviations ``indoor.sigma_v`` and ``indoor.sigma_omega_deg``,
multiplied by ``indoor.slip_factor`` during slip episodes. Episodes and the stretches between them
alternate with exponentially distributed lengths, of means ``indoor.slip_duration`` and
``slip_duration (1 - slip_fraction) / slip_fraction``, so a fraction ``slip_fraction`` of the time slips
on average. Standing still, the wheels do not turn and the odometry reads exactly zero.
``truth_odometry.csv`` holds the standard deviations in effect at every sample.

**The laser**: every ``indoor.scan_period`` seconds (from t = 0) a fan of ``indoor.laser_beams`` beams over
``indoor.fov_deg`` is cast from the true sensor pose with :func:`nanoslam_jax.simulate_laser.ray_cast`
(walls as segments, pillars as circles; each scan instantaneous). A return carries Gaussian range noise
``indoor.range_noise``; a beam that hits a surface returns nothing with probability ``indoor.dropout``;
any beam reports a spurious range (uniform between 0.1 m and its true range, or ``max_range``) with
probability ``indoor.spurious``; surfaces at or beyond ``indoor.max_range`` give no return.

**Frames.** Everything is in the SLAM frame: the laser's pose at t = 0 is ``(0, 0, 0)``, the walls of the
starting side run along the x axis, so the other walls of rectangular rooms are exactly vertical
(the paper's ``x = c`` case).
"""

from __future__ import annotations

import dataclasses
import math
import os
from pathlib import Path
from typing import NamedTuple

import numpy as np
from jaxtyping import Float, Int
from matplotlib.path import Path as MplPath
from scipy.ndimage import maximum_filter1d

from .config import IndoorConfig
from .data import LaserScans, fan_angles, write_victoria_park
from .data._laser import NO_RETURN, write_laser
from .data._types import RawLog
from .models._angles import wrap_angle_np
from .models._lines import line_through, slope_intercept_from_line
from .simulate_laser import KIND_NONE, KIND_TREE, KIND_WALL, LaserWorld, ray_cast

__all__ = [
    "ACCELERATION",
    "BREAK_DOOR",
    "BREAK_FREE_END",
    "FeatureTruth",
    "TEMPLATES",
    "TRUTH_FILES",
    "IndoorLog",
    "IndoorPath",
    "IndoorWorld",
    "build_world",
    "feature_truth",
    "hessian_lines",
    "indoor_laser_world",
    "read_feature_truth",
    "reference_path",
    "simulate_indoor",
    "simulate_indoor_to_dir",
    "slope_intercept_lines",
    "write_indoor_truth",
]

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
    Table 1, :func:`~nanoslam_jax.metrics.feature_map_errors`).

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


# --------------------------------------------------------------------------- geometry helpers


def _point_segment_distance(p: np.ndarray, seg: np.ndarray) -> np.ndarray:
    """``(n, m)`` distances of points ``p (n, 2)`` to segments ``seg (m, 4)``."""
    a, d = seg[None, :, :2], seg[None, :, 2:] - seg[None, :, :2]
    w = p[:, None, :] - a
    t = np.clip(np.sum(w * d, axis=2) / np.maximum(np.sum(d * d, axis=2), 1e-300), 0.0, 1.0)
    return np.hypot(*np.moveaxis(w - t[..., None] * d, 2, 0))


def _inset(poly: np.ndarray, d) -> np.ndarray:
    """The polygon (counter-clockwise vertices) with each edge moved inward by ``d`` (scalar or per edge;
    edge ``i`` runs from vertex ``i`` to ``i + 1``): the intersections of consecutive moved edges."""
    n = poly.shape[0]
    d = np.broadcast_to(np.asarray(d, dtype=np.float64), (n,))
    e = np.roll(poly, -1, axis=0) - poly
    u = e / np.hypot(e[:, 0], e[:, 1])[:, None]
    nrm = np.stack([-u[:, 1], u[:, 0]], axis=1)  # inward (left) normal
    p = poly + d[:, None] * nrm
    out = np.empty_like(poly)
    for i in range(n):  # vertex i: edges i - 1 and i
        j = i - 1
        a1, u1, a2, u2 = p[j], u[j], p[i], u[i]
        den = u1[0] * u2[1] - u1[1] * u2[0]
        t = ((a2[0] - a1[0]) * u2[1] - (a2[1] - a1[1]) * u2[0]) / den
        out[i] = a1 + t * u1
    return out


def _signed_area(poly: np.ndarray) -> float:
    x, y = poly[:, 0], poly[:, 1]
    return 0.5 * float(np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y))


def reference_path(waypoints: np.ndarray, radius: np.ndarray) -> IndoorPath:
    """The closed loop through ``waypoints`` with corner ``i`` rounded by an arc of ``radius[i]``, starting
    at the middle of the straight piece from waypoint 0 to waypoint 1.

    Raises:
        ValueError: two neighbouring arcs overlap (an edge is shorter than its two tangent lengths).
    """
    w = np.asarray(waypoints, dtype=np.float64)
    n = w.shape[0]
    d_out = np.roll(w, -1, axis=0) - w
    length = np.hypot(d_out[:, 0], d_out[:, 1])
    h_out = np.arctan2(d_out[:, 1], d_out[:, 0])
    turn = wrap_angle_np(h_out - np.roll(h_out, 1))  # at vertex i: from edge i - 1 to edge i
    tan_len = radius * np.tan(0.5 * np.abs(turn))
    free = length - tan_len - np.roll(tan_len, -1)
    free = np.where(free > -1e-9 * length, np.maximum(free, 0.0), free)
    if np.any(free < 0.0):
        i = int(np.argmin(free))
        raise ValueError(
            f"indoor.turn_radius: the rounded corners at waypoints {i} and {(i + 1) % n} overlap "
            f"(edge {length[i]:.2f} m); lower indoor.turn_radius"
        )
    s0, ln, st, hd, kp = [], [], [], [], []
    s, h = 0.0, float(h_out[0])

    def add(piece_len, p0, heading, kappa):
        nonlocal s
        s0.append(s)
        ln.append(piece_len)
        st.append(p0)
        hd.append(heading)
        kp.append(kappa)
        s += piece_len

    half = 0.5 * free[0]
    u0 = d_out[0] / length[0]
    add(half, w[0] + (tan_len[0] + half) * u0, h, 0.0)
    for k in range(1, n + 1):
        i = k % n
        u_in = d_out[i - 1] / length[i - 1]
        a = w[i] - tan_len[i] * u_in
        if turn[i] != 0.0:
            add(radius[i] * abs(turn[i]), a, h, math.copysign(1.0 / radius[i], turn[i]))
            h += float(turn[i])
        u = d_out[i] / length[i]
        if i == 0:
            add(half, w[0] + tan_len[0] * u, h, 0.0)
        else:
            add(free[i], w[i] + tan_len[i] * u, h, 0.0)
    keep = np.asarray(ln) > 0.0
    return IndoorPath(
        s0=np.asarray(s0)[keep],
        length=np.asarray(ln)[keep],
        start=np.asarray(st)[keep],
        heading=np.asarray(hd)[keep],
        kappa=np.asarray(kp)[keep],
        total=float(s),
        turn=float(h - h_out[0]),
    )


# --------------------------------------------------------------------------- the world


class _Outline(NamedTuple):
    """A wall outline: closed polygon (counter-clockwise as built; mirroring reverses it) and whether the free
    space lies inside it."""

    vertices: np.ndarray
    free_inside: bool


def _template_geometry(template: str, cfg: IndoorConfig, rng: np.random.Generator):
    """Outlines and path waypoints (counter-clockwise, the first edge along +x) of a template."""
    u = rng.uniform
    if template == "room":
        w, h = u(6.0, 10.0), u(5.0, 8.0)
        v = [(0.0, 0.0), (w, 0.0), (w, h), (0.0, h)]
        if rng.random() < 0.5:  # cut a far corner with a slanted wall
            ca, cb = u(1.0, 2.0), u(1.0, 2.0)
            if rng.random() < 0.5:
                v = [(0.0, 0.0), (w, 0.0), (w, h - ca), (w - cb, h), (0.0, h)]
            else:
                v = [(0.0, 0.0), (w, 0.0), (w, h), (cb, h), (0.0, h - ca)]
        poly = np.array(v)
        return [_Outline(poly, True)], _inset(poly, cfg.path_inset)
    if template == "l_room":
        w, h, arm_a, arm_b = u(9.0, 12.0), u(8.0, 11.0), u(4.4, 5.4), u(4.4, 5.4)
        poly = np.array([(0.0, 0.0), (w, 0.0), (w, arm_a), (arm_b, arm_a), (arm_b, h), (0.0, h)])
        return [_Outline(poly, True)], _inset(poly, cfg.path_inset)
    if template == "corridor":
        w, h = u(11.0, 16.0), u(8.0, 11.0)
        gb, gr, gt, gl = u(1.8, 2.4), u(1.8, 2.4), u(1.8, 2.4), u(3.6, 4.6)
        outer = np.array([(0.0, 0.0), (w, 0.0), (w, h), (0.0, h)])
        block = np.array([(gl, gb), (w - gr, gb), (w - gr, h - gt), (gl, h - gt)])
        path = _inset(outer, np.array([gb, gr, gt, gl]) / 2)
        return [_Outline(outer, True), _Outline(block, False)], path
    raise ValueError(f"indoor.template: expected one of random, {', '.join(TEMPLATES)}; got {template!r}")


def _cut_doors(outlines: list[_Outline], cfg: IndoorConfig, rng: np.random.Generator):
    """Wall segments with ``cfg.doors`` door gaps; returns segments, their line ids, the edges' ids per
    outline vertex, and the door jambs."""
    edges = []  # (outline, vertex i, start, end)
    for o, ol in enumerate(outlines):
        v = ol.vertices
        for i in range(v.shape[0]):
            edges.append((o, i, v[i], v[(i + 1) % v.shape[0]]))
    lengths = np.array([np.hypot(*(b - a)) for _, _, a, b in edges])
    gaps: list[list[tuple[float, float]]] = [[] for _ in edges]
    need = cfg.door_width + 2 * _DOOR_MARGIN
    for _ in range(cfg.doors):
        placed = False
        for _try in range(200):
            ok = lengths >= need
            if not ok.any():
                break
            e = int(rng.choice(np.flatnonzero(ok), p=lengths[ok] / lengths[ok].sum()))
            c = rng.uniform(_DOOR_MARGIN + 0.5 * cfg.door_width, lengths[e] - _DOOR_MARGIN - 0.5 * cfg.door_width)
            lo, hi = c - 0.5 * cfg.door_width, c + 0.5 * cfg.door_width
            if all(hi + _DOOR_MARGIN <= g0 or lo - _DOOR_MARGIN >= g1 for g0, g1 in gaps[e]):
                gaps[e].append((lo, hi))
                placed = True
                break
        if not placed:
            raise ValueError(
                f"indoor.doors: cannot place {cfg.doors} doors {cfg.door_width} m wide "
                f"{_DOOR_MARGIN} m from corners and from each other; lower indoor.doors or "
                "indoor.door_width"
            )
    walls, line, jambs, jamb_wall = [], [], [], []
    first_piece, last_piece = {}, {}
    for e, (o, i, a, b) in enumerate(edges):
        uvec = (b - a) / lengths[e]
        cuts = sorted(gaps[e])
        bounds = [0.0] + [x for g in cuts for x in g] + [lengths[e]]
        for k in range(0, len(bounds), 2):
            p0, p1 = a + bounds[k] * uvec, a + bounds[k + 1] * uvec
            if k == 0:
                p0 = a
            if k + 2 == len(bounds):
                p1 = b
            wid = len(walls)
            walls.append(np.concatenate([p0, p1]))
            line.append(e)
            if k > 0:
                jambs.append(p0)
                jamb_wall.append(wid)
            if k + 2 < len(bounds):
                jambs.append(p1)
                jamb_wall.append(wid)
            first_piece.setdefault(e, wid)
            last_piece[e] = wid
    edge_of = {(o, i): e for e, (o, i, _, _) in enumerate(edges)}
    return (
        np.array(walls),
        np.array(line, dtype=np.int64),
        first_piece,
        last_piece,
        edge_of,
        np.array(jambs).reshape(-1, 2),
        np.array(jamb_wall, dtype=np.int64),
    )


def _corners(outlines, first_piece, last_piece, edge_of):
    pts, walls, ang = [], [], []
    for o, ol in enumerate(outlines):
        v = ol.vertices
        n = v.shape[0]
        for i in range(n):
            u_in, u_out = v[i] - v[i - 1], v[(i + 1) % n] - v[i]
            turn = math.atan2(u_in[0] * u_out[1] - u_in[1] * u_out[0], float(u_in @ u_out))
            interior = math.pi - turn  # counter-clockwise outline
            free = interior if ol.free_inside else 2 * math.pi - interior
            pts.append(v[i])
            walls.append((last_piece[edge_of[(o, (i - 1) % n)]], first_piece[edge_of[(o, i)]]))
            ang.append(math.degrees(free))
    return np.array(pts).reshape(-1, 2), np.array(walls, dtype=np.int64).reshape(-1, 2), np.array(ang)


def _round_corners(waypoints: np.ndarray, walls: np.ndarray, r0: float) -> np.ndarray:
    """Per-waypoint radius: ``r0`` or less so that an arc takes at most half of either edge beside it, then
    shrunk by 20 % steps while the arc passes nearer than 0.5 m to a wall."""
    n = waypoints.shape[0]
    d = np.roll(waypoints, -1, axis=0) - waypoints
    length, h = np.hypot(d[:, 0], d[:, 1]), np.arctan2(d[:, 1], d[:, 0])
    half_turn = np.tan(0.5 * np.abs(wrap_angle_np(h - np.roll(h, 1))))
    radius = np.minimum(r0, 0.5 * np.minimum(length, np.roll(length, 1)) / np.maximum(half_turn, 1e-12))
    for i in range(n):
        for _ in range(30):
            path = reference_path(waypoints, radius)
            arcs = np.flatnonzero(path.kappa != 0.0)
            # the arc of waypoint i is the one whose start is nearest the waypoint
            j = arcs[np.argmin(np.hypot(*(path.start[arcs] - waypoints[i]).T))] if arcs.size else None
            if j is None:
                break
            s = path.s0[j] + np.linspace(0.0, path.length[j], 33)
            p, _, _ = path.at(s)
            if _point_segment_distance(p, walls).min() >= _PATH_WALL or radius[i] < 0.05:
                break
            radius[i] *= 0.8
    return radius


def _place_pillars(cfg: IndoorConfig, rng, outlines, walls, path: IndoorPath) -> np.ndarray:
    outer = outlines[0].vertices
    lo, hi = outer.min(axis=0), outer.max(axis=0)
    inside = MplPath(outer)
    blocks = [MplPath(o.vertices) for o in outlines[1:]]
    track, _, _ = path.at(np.arange(0.0, path.total, 0.05))
    kept: list[np.ndarray] = []
    for _ in range(200):
        if len(kept) == cfg.pillars:
            break
        c = lo + (hi - lo) * rng.random((256, 2))
        r = rng.uniform(cfg.pillar_radius_min, cfg.pillar_radius_max, 256)
        ok = inside.contains_points(c)
        for b in blocks:
            ok &= ~b.contains_points(c)
        ok &= _point_segment_distance(c, walls).min(axis=1) >= r + _PILLAR_WALL
        d_path = np.hypot(c[:, None, 0] - track[None, :, 0], c[:, None, 1] - track[None, :, 1]).min(axis=1)
        ok &= d_path >= r + _PILLAR_PATH
        for k in np.flatnonzero(ok):
            if all(np.hypot(*(c[k] - q[:2])) >= r[k] + q[2] + 1.0 for q in kept):
                kept.append(np.array([c[k, 0], c[k, 1], r[k]]))
                if len(kept) == cfg.pillars:
                    break
    if len(kept) < cfg.pillars:
        raise ValueError(
            f"indoor.pillars: cannot place {cfg.pillars} pillars of radius up to "
            f"{cfg.pillar_radius_max} m {_PILLAR_WALL} m from the walls and {_PILLAR_PATH} m from the "
            f"path (placed {len(kept)}); lower indoor.pillars or indoor.pillar_radius_max"
        )
    return np.array(kept)


def _place_partitions(cfg: IndoorConfig, rng, outlines, walls, pillars, path: IndoorPath) -> np.ndarray:
    """Free-standing partition walls ``indoor.partition_length`` long at random angles, ``_PATH_WALL`` from the
    walls, the path, the pillars' surfaces and each other."""
    outer = outlines[0].vertices
    lo, hi = outer.min(axis=0), outer.max(axis=0)
    inside = MplPath(outer)
    blocks = [MplPath(o.vertices) for o in outlines[1:]]
    track, _, _ = path.at(np.arange(0.0, path.total, 0.05))
    along = np.linspace(0.0, 1.0, 13)
    kept: list[np.ndarray] = []
    for _ in range(200):
        if len(kept) == cfg.partitions:
            break
        c = lo + (hi - lo) * rng.random((128, 2))
        th = rng.uniform(0.0, np.pi, 128)
        half = 0.5 * cfg.partition_length * np.stack([np.cos(th), np.sin(th)], axis=1)
        seg = np.concatenate([c - half, c + half], axis=1)
        pts = seg[:, None, :2] + along[None, :, None] * (seg[:, None, 2:] - seg[:, None, :2])  # (128, 13, 2)
        flat = pts.reshape(-1, 2)
        ok = inside.contains_points(flat)
        for b in blocks:
            ok &= ~b.contains_points(flat)
        others = np.concatenate([walls, *kept]) if kept else walls
        ok &= _point_segment_distance(flat, others.reshape(-1, 4)).min(axis=1) >= _PATH_WALL
        d_path = np.hypot(flat[:, None, 0] - track[None, :, 0], flat[:, None, 1] - track[None, :, 1]).min(axis=1)
        ok &= d_path >= _PATH_WALL
        d_pil = np.hypot(flat[:, None, 0] - pillars[None, :, 0], flat[:, None, 1] - pillars[None, :, 1]) - pillars[:, 2]
        ok &= d_pil.min(axis=1) >= _PATH_WALL
        good = np.flatnonzero(ok.reshape(pts.shape[:2]).all(axis=1))
        if good.size:
            kept.append(seg[good[:1]])
    if len(kept) < cfg.partitions:
        raise ValueError(
            f"indoor.partitions: cannot place {cfg.partitions} partitions {cfg.partition_length} m long "
            f"{_PATH_WALL} m from the walls, the path, the pillars and each other (placed {len(kept)}); "
            "lower indoor.partitions or indoor.partition_length"
        )
    return np.concatenate(kept).reshape(-1, 4)


def build_world(cfg: IndoorConfig, rng: np.random.Generator) -> tuple[IndoorWorld, IndoorPath]:
    """The scene and the desired path of one indoor log (see the module docstring), in the SLAM frame.

    Args:
        cfg: the ``indoor`` section.
        rng: the stream the template, sizes, doors and pillars are drawn from.

    Returns:
        ``(world, path)``; the path starts at the reference point's start, heading +x, with the laser
        (``cfg.sensor_ls`` behind) at the origin.
    """
    template = cfg.template if cfg.template != "random" else TEMPLATES[int(rng.integers(len(TEMPLATES)))]
    outlines, waypoints = _template_geometry(template, cfg, rng)
    mirror = bool(rng.random() < 0.5)
    walls, wall_line, first, last, edge_of, jambs, jamb_wall = _cut_doors(outlines, cfg, rng)
    corners, corner_walls, corner_angle = _corners(outlines, first, last, edge_of)
    # SLAM frame: the laser starts at the origin heading +x (mirrored: y -> -y, the loop then runs clockwise)
    radius = _round_corners(waypoints, walls, cfg.turn_radius)
    origin = reference_path(waypoints, radius).start[0] - np.array([cfg.sensor_ls, 0.0])
    flip = np.array([1.0, -1.0 if mirror else 1.0])

    def tf(p):
        return (np.asarray(p, dtype=np.float64).reshape(-1, 2) - origin) * flip

    walls = tf(walls).reshape(-1, 4)
    waypoints, corners, jambs = tf(waypoints), tf(corners), tf(jambs)
    outlines = [_Outline(tf(o.vertices), o.free_inside) for o in outlines]
    path = reference_path(waypoints, radius)
    pillars = _place_pillars(cfg, rng, outlines, walls, path)
    parts = _place_partitions(cfg, rng, outlines, walls, pillars, path)
    n_walls = walls.shape[0]
    walls = np.concatenate([walls, parts])
    wall_line = np.concatenate([wall_line, wall_line.max() + 1 + np.arange(parts.shape[0])])
    jambs = np.concatenate([jambs, parts.reshape(-1, 2)])
    jamb_wall = np.concatenate([jamb_wall, np.repeat(n_walls + np.arange(parts.shape[0]), 2)])
    kinds = np.concatenate(
        [
            np.full(jamb_wall.size - 2 * parts.shape[0], BREAK_DOOR, dtype=np.int64),
            np.full(2 * parts.shape[0], BREAK_FREE_END, dtype=np.int64),
        ]
    )
    track, _, _ = path.at(np.arange(0.0, path.total, 0.02))
    gap = min(
        _point_segment_distance(track, walls).min(),
        (
            np.hypot(track[:, None, 0] - pillars[None, :, 0], track[:, None, 1] - pillars[None, :, 1])
            - pillars[None, :, 2]
        ).min(),
    )
    if gap < 0.3:
        raise ValueError(
            f"indoor.path_inset: the path passes {gap:.2f} m from a wall or pillar; raise "
            "indoor.path_inset or lower indoor.turn_radius"
        )
    world = IndoorWorld(
        template=template,
        walls=walls,
        wall_line=wall_line,
        pillars=pillars,
        corners=corners,
        corner_walls=corner_walls,
        corner_angle=corner_angle,
        breakpoints=jambs,
        breakpoint_wall=jamb_wall,
        breakpoint_kind=kinds,
        waypoints=waypoints,
        turn_radius=radius,
    )
    return world, path


def indoor_laser_world(world: IndoorWorld) -> LaserWorld:
    """The scene as :func:`~nanoslam_jax.simulate_laser.ray_cast` takes it: pillars as trees (circles),
    walls as wall segments (``segment_object`` the wall's row)."""
    n = world.walls.shape[0]
    return LaserWorld(
        trees=world.pillars[:, :2],
        tree_radius=world.pillars[:, 2],
        segments=world.walls,
        segment_kind=np.full(n, KIND_WALL, dtype=np.int64),
        segment_object=np.arange(n),
        bush_centres=np.zeros((0, 2)),
        bush_radius=np.zeros(0),
    )


# --------------------------------------------------------------------------- driving


def _arc_lengths(path: IndoorPath, cfg: IndoorConfig, rng: np.random.Generator, n: int) -> np.ndarray:
    """Arc length of the reference point at ``n`` samples ``k * odom_period``: standing still for
    ``static_time``, then the speed profile of the module docstring, capped on arcs, acceleration-limited."""
    dt = cfg.odom_period
    t = np.arange(n) * dt
    period, phase = rng.uniform(20.0, 40.0), rng.uniform(0.0, 2.0 * np.pi)
    profile = cfg.speed_min + (cfg.speed_max - cfg.speed_min) * 0.5 * (1.0 + np.sin(2.0 * np.pi * t / period + phase))
    ds = 0.01
    grid = np.arange(0.0, path.total, ds)
    _, _, kappa = path.at(grid)
    win = int(math.ceil((cfg.speed_max**2 / (2.0 * ACCELERATION) + 0.2) / ds)) + 1
    ahead = maximum_filter1d(np.abs(kappa), size=win, origin=-(win // 2), mode="wrap")  # max over [i, i + win)
    cap = math.radians(cfg.max_turn_rate_deg) / np.maximum(ahead, 1e-9)
    moving = (t >= cfg.static_time).tolist()
    profile = profile.tolist()
    cap_l, m, step = cap.tolist(), grid.size, ACCELERATION * dt
    s_out = np.empty(n)
    s = v = 0.0
    for k in range(n):
        s_out[k] = s
        target = min(profile[k], cap_l[int((s % path.total) / ds) % m]) if moving[k] else 0.0
        v = max(v + max(min(target - v, step), -step), 0.0)
        s += v * dt
    return s_out


def _controls(path: IndoorPath, s: np.ndarray, sensor: np.ndarray, dt: float):
    """True headings and controls that keep the reference point on the path under the model's Euler step.

    With the laser at ``sensor`` (robot frame) and its pose moved by ``p' = p + dt R(theta) (v e_x + omega J
    sensor)``, the reference point ``c = p - R(theta) sensor`` moves by ``R(theta_k) (dt v_k e_x + M(dtheta_k)
    sensor)`` with ``M(a) = I + a J - R(a)``; the heading ``theta_k`` that makes this the chord to the next
    path point is found by a fixed-point iteration (``M`` is O(dtheta^2)).

    Args:
        path: the desired path.
        s: ``(N + 2,)`` arc lengths at the samples.
        sensor: ``(2,)`` laser offset from the reference point.
        dt: the sample period.

    Returns:
        ``(centre, theta, v, omega)``: ``(N + 1, 2)`` desired points and ``(N + 1,)`` headings, ``(N,)``
        controls.
    """
    c, tangent, _ = path.at(s)
    d = np.diff(c, axis=0)
    dist = np.hypot(d[:, 0], d[:, 1])
    moving = dist > 1e-12
    psi = np.unwrap(np.where(moving, np.arctan2(d[:, 1], d[:, 0]), tangent[:-1]))
    theta = psi.copy()
    sx, sy = float(sensor[0]), float(sensor[1])
    safe = np.where(moving, dist, 1.0)
    for _ in range(6):
        a = np.diff(theta)
        m_y = (a - np.sin(a)) * sx + (1.0 - np.cos(a)) * sy
        theta[:-1] = np.where(moving[:-1], psi[:-1] - np.arcsin(np.clip(m_y / safe[:-1], -1.0, 1.0)), psi[:-1])
    a = np.diff(theta)
    m_x = (1.0 - np.cos(a)) * sx - (a - np.sin(a)) * sy
    v = np.where(moving[:-1], (dist[:-1] * np.cos(psi[:-1] - theta[:-1]) - m_x) / dt, 0.0)
    return c[:-1], theta, v, a / dt


def _integrate(p0: np.ndarray, theta0: float, controls: np.ndarray, sensor: np.ndarray, dt: float) -> np.ndarray:
    """Laser poses under the :class:`~nanoslam_jax.models.Unicycle` Euler step from ``(p0, theta0)``, as
    cumulative sums: ``(N + 1, 3)`` poses (heading not wrapped) for ``(N, 2)`` controls."""
    v, w = controls[:, 0], controls[:, 1]
    theta = theta0 + np.concatenate([[0.0], np.cumsum(dt * w)])
    c, s = np.cos(theta[:-1]), np.sin(theta[:-1])
    fx, fy = v - w * sensor[1], w * sensor[0]
    x = p0[0] + np.concatenate([[0.0], np.cumsum(dt * (c * fx - s * fy))])
    y = p0[1] + np.concatenate([[0.0], np.cumsum(dt * (s * fx + c * fy))])
    return np.stack([x, y, theta], axis=1)


def _slip_mask(t: np.ndarray, cfg: IndoorConfig, rng: np.random.Generator) -> np.ndarray:
    """Which sample times lie in a slip episode (alternating exponential stretches, module docstring)."""
    if cfg.slip_fraction <= 0.0 or cfg.slip_factor == 1.0:
        return np.zeros(t.shape, dtype=bool)
    on_mean = cfg.slip_duration
    off_mean = on_mean * (1.0 - cfg.slip_fraction) / cfg.slip_fraction
    offs, ons = np.zeros(0), np.zeros(0)
    while offs.sum() + ons.sum() <= t[-1]:
        k = int(t[-1] / (on_mean + off_mean)) + 8
        offs = np.concatenate([offs, rng.exponential(off_mean, k)])
        ons = np.concatenate([ons, rng.exponential(on_mean, k)])
    starts = np.cumsum(offs + ons) - ons
    i = np.searchsorted(starts, t, side="right") - 1
    return (i >= 0) & (t < (starts + ons)[np.maximum(i, 0)])


def _pose_at(
    times: np.ndarray, t: np.ndarray, poses: np.ndarray, controls: np.ndarray, sensor: np.ndarray
) -> np.ndarray:
    """Laser poses at ``times`` in the samples' span: the Euler step over the rest of the sample's period."""
    i = np.clip(np.searchsorted(t, times, side="right") - 1, 0, controls.shape[0] - 1)
    tau = times - t[i]
    p, v, w = poses[i], controls[i, 0], controls[i, 1]
    c, s = np.cos(p[:, 2]), np.sin(p[:, 2])
    fx, fy = v - w * sensor[1], w * sensor[0]
    return np.stack([p[:, 0] + tau * (c * fx - s * fy), p[:, 1] + tau * (s * fx + c * fy), p[:, 2] + tau * w], axis=1)


# --------------------------------------------------------------------------- the log


def simulate_indoor(cfg: IndoorConfig | None = None) -> IndoorLog:
    """Simulate an indoor log (see the module docstring).

    Args:
        cfg: the ``indoor`` section (:class:`~nanoslam_jax.config.IndoorConfig`); ``None``: defaults.

    Returns:
        The log, its scans, the world and every truth; deterministic for a given ``cfg.seed``.

    Raises:
        ValueError: the world cannot hold the doors or pillars asked for, or the path comes nearer than
            0.3 m to a wall or pillar (the message names the key to change).
    """
    cfg = IndoorConfig() if cfg is None else cfg
    rng_world, rng_drive, rng_odo, rng_laser, rng_det = (
        np.random.default_rng(s) for s in np.random.SeedSequence(cfg.seed).spawn(5)
    )
    world, path = build_world(cfg, rng_world)
    sensor = np.array([-cfg.sensor_ls, 0.0])
    dt = cfg.odom_period
    n = int(math.floor(cfg.duration / dt + 1e-9)) + 1  # samples at k dt, k = 0 .. n - 1
    s = _arc_lengths(path, cfg, rng_drive, n + 2)
    centre, theta, v, w = _controls(path, s, sensor, dt)
    controls = np.stack([v, w], axis=1)  # (n, 2): sample k's controls over [t_k, t_k + dt)
    t = np.arange(n) * dt
    c0, s0 = math.cos(theta[0]), math.sin(theta[0])
    p0 = centre[0] + np.array([c0 * sensor[0] - s0 * sensor[1], s0 * sensor[0] + c0 * sensor[1]])
    laser = _integrate(p0, float(theta[0]), controls, sensor, dt)  # (n + 1, 3)
    cth, sth = np.cos(laser[:, 2]), np.sin(laser[:, 2])
    ref = np.stack(
        [
            laser[:, 0] - (cth * sensor[0] - sth * sensor[1]),
            laser[:, 1] - (sth * sensor[0] + cth * sensor[1]),
            laser[:, 2],
        ],
        axis=1,
    )

    # odometry: white noise whose standard deviation grows slip_factor-fold in slip episodes
    slip = _slip_mask(t, cfg, rng_odo)
    turning = (np.abs(v) > 1e-9) | (np.abs(w) > 1e-9)
    factor = np.where(slip, cfg.slip_factor, 1.0) * turning
    sigma = np.stack([cfg.sigma_v * factor, math.radians(cfg.sigma_omega_deg) * factor], axis=1)
    logged = controls + rng_odo.normal(0.0, 1.0, controls.shape) * sigma

    # scans
    n_scan = int(math.floor(t[-1] / cfg.scan_period + 1e-9)) + 1
    scan_t = np.arange(n_scan) * cfg.scan_period
    scan_t = scan_t[scan_t <= t[-1]]
    scan_pose = _pose_at(scan_t, t, laser[:n], controls, sensor)
    angles = fan_angles(cfg.laser_beams, cfg.fov_deg)
    true_r, kind, obj, _ = ray_cast(scan_pose, angles, indoor_laser_world(world), cfg.max_range)
    shape = true_r.shape
    hit = np.isfinite(true_r)
    meas = np.where(hit, true_r, 0.0) + rng_laser.normal(0.0, cfg.range_noise, shape)
    dropped = hit & (rng_laser.random(shape) < cfg.dropout)
    spurious = rng_laser.random(shape) < cfg.spurious
    upper = np.where(hit, true_r, cfg.max_range)
    spur_r = _SPURIOUS_MIN + rng_laser.random(shape) * np.maximum(upper - _SPURIOUS_MIN, 0.0)
    meas = np.where(dropped | ~hit, NO_RETURN, meas)
    meas = np.where(spurious, np.minimum(spur_r, upper), meas)
    meas = np.where(meas >= cfg.max_range, NO_RETURN, np.maximum(meas, 0.0))
    lost = dropped | spurious
    kind = np.where(lost, KIND_NONE, kind)
    obj = np.where(lost, -1, obj)
    scans = LaserScans(time=scan_t, ranges=meas, angles=angles, max_range=cfg.max_range, source="simulated")

    # pillars seen by 3 or more beams of a scan: their centres as detections (measurements.dat)
    n_p = world.pillars.shape[0]
    pillar_beam = kind == KIND_TREE
    counts = np.bincount((np.nonzero(pillar_beam)[0] * n_p + obj[pillar_beam]), minlength=n_scan * n_p)
    si, pi = np.divmod(np.flatnonzero(counts.reshape(n_scan, n_p).ravel() >= 3), n_p)
    dxy = world.pillars[pi, :2] - scan_pose[si, :2]
    rng_true = np.hypot(dxy[:, 0], dxy[:, 1])
    det = np.stack(
        [
            scan_t[si],
            rng_true + rng_det.normal(0.0, cfg.range_noise, si.size),
            wrap_angle_np(
                np.arctan2(dxy[:, 1], dxy[:, 0])
                - scan_pose[si, 2]
                + rng_det.normal(0.0, 1.0, si.size) * cfg.range_noise / rng_true
            ),
            np.maximum(2 * world.pillars[pi, 2] + rng_det.normal(0.0, cfg.range_noise, si.size), 0.0),
        ],
        axis=1,
    ).reshape(-1, 4)

    truth_t = np.concatenate([t, scan_t])
    truth_p = np.concatenate([laser[:n], scan_pose], axis=0)
    truth_t, first = np.unique(truth_t, return_index=True)
    truth_poses = np.concatenate([truth_t[:, None], truth_p[first]], axis=1)
    truth_poses[:, 3] = wrap_angle_np(truth_poses[:, 3])
    raw = RawLog(
        dr=np.concatenate([t[:, None], logged], axis=1),
        detections=det,
        gps=np.concatenate([t[:, None], laser[:n, :2]], axis=1),
        truth_poses=truth_poses,
        truth_landmarks=world.pillars[:, :2].copy(),
        truth_diameters=2 * world.pillars[:, 2],
        source="simulated",
        detection_ids=pi.astype(np.int64),
        landmark_ids=np.arange(n_p),
    )
    ref_w = ref[:n].copy()
    ref_w[:, 2] = wrap_angle_np(ref_w[:, 2])
    laser_w = laser[:n].copy()
    laser_w[:, 2] = wrap_angle_np(laser_w[:, 2])
    scan_pose[:, 2] = wrap_angle_np(scan_pose[:, 2])
    return IndoorLog(
        raw=raw,
        scans=scans,
        world=world,
        path=path,
        time=t,
        pose=ref_w,
        sensor_pose=laser_w,
        controls=controls,
        sigma=sigma,
        slip=slip,
        scan_pose=scan_pose,
        kind=kind,
        object_id=obj,
    )


# --------------------------------------------------------------------------- files

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


def _write_csv(path: Path, columns: tuple[str, ...], rows: list[list]) -> None:
    with open(path, "w") as f:
        f.write(",".join(columns) + "\n")
        f.writelines(
            ",".join(
                v if isinstance(v, str) else (f"{v:d}" if isinstance(v, (int, np.integer)) else f"{v:.9f}") for v in row
            )
            + "\n"
            for row in rows
        )


def write_indoor_truth(directory: str | os.PathLike, log: IndoorLog) -> None:
    """Write the truth CSV files of :data:`TRUTH_FILES` (docs/simulate_indoor.md) into ``directory``."""
    d = Path(directory)
    w = log.world
    cols = TRUTH_FILES
    table = np.concatenate([log.time[:, None], log.pose, log.sensor_pose[:, :2]], axis=1)
    np.savetxt(
        d / "truth_path.csv", table, delimiter=",", fmt="%.9f", header=",".join(cols["truth_path.csv"]), comments=""
    )
    table = np.concatenate([log.time[:, None], log.controls, log.sigma, log.slip[:, None]], axis=1)
    np.savetxt(
        d / "truth_odometry.csv",
        table,
        delimiter=",",
        fmt=["%.9f"] * 5 + ["%d"],
        header=",".join(cols["truth_odometry.csv"]),
        comments="",
    )
    rho, alpha = hessian_lines(w.walls)
    vertical, a, b, c = slope_intercept_lines(w.walls)
    length = np.hypot(w.walls[:, 2] - w.walls[:, 0], w.walls[:, 3] - w.walls[:, 1])
    _write_csv(
        d / "truth_walls.csv",
        cols["truth_walls.csv"],
        [
            [i, int(w.wall_line[i]), *w.walls[i], length[i], rho[i], alpha[i], int(vertical[i]), a[i], b[i], c[i]]
            for i in range(w.walls.shape[0])
        ],
    )
    _write_csv(d / "truth_arcs.csv", cols["truth_arcs.csv"], [[i, *p] for i, p in enumerate(w.pillars)])
    _write_csv(
        d / "truth_corners.csv",
        cols["truth_corners.csv"],
        [
            [
                i,
                *w.corners[i],
                int(ab[0]),
                int(ab[1]),
                int(w.wall_line[ab[0]]),
                int(w.wall_line[ab[1]]),
                w.corner_angle[i],
            ]
            for i, ab in enumerate(w.corner_walls)
        ],
    )
    _write_csv(
        d / "truth_breakpoints.csv",
        cols["truth_breakpoints.csv"],
        [
            [
                i,
                *w.breakpoints[i],
                int(w.breakpoint_wall[i]),
                int(w.wall_line[w.breakpoint_wall[i]]),
                _BREAK_NAMES[int(w.breakpoint_kind[i])],
            ]
            for i in range(w.breakpoints.shape[0])
        ],
    )


def simulate_indoor_to_dir(directory: str | os.PathLike, cfg: IndoorConfig | None = None) -> IndoorLog:
    """Simulate an indoor log (:func:`simulate_indoor`) and write it as a log directory.

    Args:
        directory: output directory (created if needed). Receives ``inputs.dat`` (``time v omega``),
            ``measurements.dat`` (the pillars), ``gps.dat`` and ``truth_poses.dat`` (the true laser positions
            and poses: simulated truth, not a GPS), ``truth_landmarks.dat`` / ``truth_diameters.dat`` (the
            pillars), ``LASER.txt``, the truth CSV files of :data:`TRUTH_FILES`, ``beam_truth.npz`` (arrays
            ``kind`` and ``object_id`` of :class:`IndoorLog`: what each beam of each scan returned from) and
            ``scenario.yaml`` (the ``indoor`` section and the template drawn).
        cfg: the ``indoor`` section; ``None``: defaults.

    Returns:
        The simulated :class:`IndoorLog`.
    """
    import yaml

    log = simulate_indoor(cfg)
    cfg = IndoorConfig() if cfg is None else cfg
    d = Path(directory)
    d.mkdir(parents=True, exist_ok=True)
    write_victoria_park(d, log.raw)
    write_laser(d / "LASER.txt", log.scans)
    write_indoor_truth(d, log)
    np.savez_compressed(d / "beam_truth.npz", kind=log.kind.astype(np.int8), object_id=log.object_id.astype(np.int16))
    (d / "scenario.yaml").write_text(
        yaml.safe_dump({"indoor": dataclasses.asdict(cfg), "template": log.world.template}, sort_keys=False)
    )
    return log
