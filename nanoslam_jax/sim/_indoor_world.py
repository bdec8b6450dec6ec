"""The indoor scenario's world: rooms, L-rooms and corridors with doors, pillars and partitions,
and the path driven through it (:mod:`nanoslam_jax.sim.indoor`)."""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from matplotlib.path import Path as MplPath

from nanoslam_jax.sim._settings import IndoorConfig
from nanoslam_jax.lib._angles import wrap_angle_np
from nanoslam_jax.sim.laser import KIND_WALL, LaserWorld
from nanoslam_jax.sim._indoor_types import (
    BREAK_DOOR,
    BREAK_FREE_END,
    IndoorPath,
    IndoorWorld,
    TEMPLATES,
    _DOOR_MARGIN,
    _PATH_WALL,
    _PILLAR_PATH,
    _PILLAR_WALL,
)


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
    walls: list = []
    line: list = []
    jambs: list = []
    jamb_wall: list = []
    first_piece: dict = {}
    last_piece: dict = {}
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
    """The scene as :func:`~nanoslam_jax.sim.laser.ray_cast` takes it: pillars as trees (circles),
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
