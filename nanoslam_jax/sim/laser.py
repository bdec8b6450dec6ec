"""Raw laser scans of a simulated log (``nanoslam simulate --laser``): a ray-caster over the simulator's world.

The vehicle drives exactly as in :func:`nanoslam_jax.sim.park.simulate` (the same trees, path, truth and
scan times for a given ``sim.seed``); at every scan time a fan of ``sim.laser_beams`` beams over
``sim.laser_fov_deg`` is cast from the true laser pose into a world of

* **trees**: circles at the simulator's tree positions with its tree diameters;
* **walls**: ``sim.laser_walls`` solid straight segments, 8 to 40 m long;
* **fences**: ``sim.laser_fences`` straight segments that a crossing beam returns from with probability
  ``sim.laser_fence_return`` (else it passes through, as through wire mesh);
* **bushes**: ``sim.laser_bushes`` irregular star-shaped polygons of 20 vertices (mean radius 0.5 to 2 m,
  each vertex's radius varied by up to ``sim.laser_bush_roughness``).

Walls, fences and bushes keep ``sim.laser_clearance`` from every trunk's surface and 3 m from the driven
laser path. A beam returns the range of the nearest surface it crosses (occlusion), plus
``N(0, sim.laser_range_noise)``; surfaces at or beyond ``sim.laser_max_range`` give no return. A beam that
hits a surface returns nothing with probability ``sim.laser_dropout``; any beam reports a spurious range
(uniform between 0.5 m and its true range, or ``laser_max_range`` without a surface) with probability
``sim.laser_spurious``. No return is written as :data:`NO_RETURN` (81.91 m), as in the real log.

The truth of each scan lists every tree the fan reaches (its centre within range and at least one beam
crossing it): how many beams cross it (``beams_span``) and how many of the scan's returns come from it
(``beams_hit``: not occluded, not dropped, not replaced by a spurious range), with its range, bearing and
diameter. Beam angles follow :class:`nanoslam_jax.data.LaserScans` (vehicle frame, 0 ahead, left positive);
``LASER.txt`` holds file bearings ``0 .. fov`` (90 deg ahead), one scan per line.
"""

from __future__ import annotations

import os
from typing import NamedTuple

import numpy as np
from jaxtyping import Bool, Float, Int
from scipy.spatial import cKDTree

from nanoslam_jax.sim._settings import SimConfig
from nanoslam_jax.models._settings import UnicycleConfig, VehicleConfig
from nanoslam_jax.data import LaserScans, fan_angles, write_victoria_park
from nanoslam_jax.data._laser import NO_RETURN, write_laser
from nanoslam_jax.data._types import RawLog
from nanoslam_jax.lib._angles import wrap_angle_np
from nanoslam_jax.sim.park import PATH_CLEARANCE, simulate

__all__ = [
    "KIND_BUSH",
    "KIND_FENCE",
    "KIND_TREE",
    "KIND_WALL",
    "NO_RETURN",
    "TRUTH_COLUMNS",
    "LaserLog",
    "LaserWorld",
    "build_world",
    "ray_cast",
    "simulate_laser",
    "simulate_laser_to_dir",
    "write_laser",
]

#: Columns of ``laser_truth.csv`` (and of :attr:`LaserLog.truth`).
TRUTH_COLUMNS = ("time", "tree_id", "beams_hit", "beams_span", "range_to_centre", "bearing", "diameter")
#: Object kinds of the world (``LaserWorld.segment_kind`` and :func:`ray_cast`'s ``kind``).
KIND_NONE, KIND_TREE, KIND_WALL, KIND_FENCE, KIND_BUSH = -1, 0, 1, 2, 3
_KIND_NAMES = {KIND_WALL: "wall", KIND_FENCE: "fence", KIND_BUSH: "bush"}
#: Vertices of a bush outline; length range of walls and fences (m); mean bush radius range (m).
BUSH_VERTICES = 20
_LINE_LENGTH = (8.0, 40.0)
_BUSH_RADIUS = (0.5, 2.0)
#: Nearest range a spurious return reports (m).
_SPURIOUS_MIN = 0.5
#: Scans ray-cast together (bounds the (scans, beams, objects) work arrays).
_CHUNK = 32


class LaserWorld(NamedTuple):
    """What the scanner sees: trunks as circles, walls, fences and bush outlines as segments.

    Attributes:
        trees: ``(T, 2)`` trunk centres (m).
        tree_radius: ``(T,)`` trunk radii (m).
        segments: ``(N, 4)`` segments ``x0, y0, x1, y1`` (m).
        segment_kind: ``(N,)`` :data:`KIND_WALL`, :data:`KIND_FENCE` or :data:`KIND_BUSH`.
        segment_object: ``(N,)`` which wall, fence or bush (numbered per kind) the segment belongs to.
        bush_centres: ``(K, 2)`` bush centres; bush ``k``'s segments are rows ``segment_kind == KIND_BUSH``
            with ``segment_object == k``.
        bush_radius: ``(K,)`` radius of a circle about the centre that holds the whole bush (m).
    """

    trees: Float[np.ndarray, "T 2"]
    tree_radius: Float[np.ndarray, " T"]
    segments: Float[np.ndarray, "N 4"]
    segment_kind: Int[np.ndarray, " N"]
    segment_object: Int[np.ndarray, " N"]
    bush_centres: Float[np.ndarray, "K 2"]
    bush_radius: Float[np.ndarray, " K"]


class LaserLog(NamedTuple):
    """A simulated log with raw scans.

    Attributes:
        raw: the simulated log of :func:`nanoslam_jax.sim.park.simulate` (its detections are the
            simulator's direct ones, not extracted from the scans).
        scans: the ray-cast scans, one per scan time of ``raw`` (with or without detections).
        truth: ``(R, 7)`` rows of :data:`TRUTH_COLUMNS`: every tree the fan of a scan reaches; bearing
            in the vehicle frame (rad), ranges and diameter in m.
        world: the world the scans were cast in.
        kind: ``(S, B)`` what each beam's return came from (:data:`KIND_TREE` ..., -1: nothing, a
            dropout or a spurious return).
        object_id: ``(S, B)`` the tree (row of ``world.trees``) or wall/fence/bush number, -1 for none.
    """

    raw: RawLog
    scans: LaserScans
    truth: Float[np.ndarray, "R 7"]
    world: LaserWorld
    kind: Int[np.ndarray, "S B"]
    object_id: Int[np.ndarray, "S B"]


# --------------------------------------------------------------------------- the world


def _surface_gap(points: np.ndarray, trees: np.ndarray, tree_radius: np.ndarray) -> np.ndarray:
    """Distance (m) of each of ``points (..., 2)`` to the nearest trunk surface (negative inside)."""
    flat = points.reshape(-1, 2)
    k = min(4, trees.shape[0])
    d, i = cKDTree(trees).query(flat, k=k)
    d, i = d.reshape(flat.shape[0], k), i.reshape(flat.shape[0], k)
    return (d - tree_radius[i]).min(axis=1).reshape(points.shape[:-1])


def _place(rng, n: int, make, lo, hi, ok, key: str) -> list:
    """Rejection-sample ``n`` objects: ``make(rng, centres)`` builds candidates from uniform centres in
    the box, ``ok(candidates)`` says which are clear; raises naming ``key`` when the park cannot hold them."""
    kept: list = []
    for _ in range(200):
        if len(kept) == n:
            return kept
        cand = make(rng, lo + (hi - lo) * rng.random((64, 2)))
        good = np.flatnonzero(ok(cand))
        kept.extend(cand[j] for j in good[: n - len(kept)])
    if len(kept) < n:
        raise ValueError(
            f"sim.{key}: cannot place {n} in the park clear of the trees and the path "
            f"(placed {len(kept)}); lower sim.{key} or sim.laser_clearance"
        )
    return kept


def build_world(raw: RawLog, sim: SimConfig, rng: np.random.Generator) -> LaserWorld:
    """Add walls, fences and bushes (``sim.laser_*``) to the trees of a simulated log.

    Args:
        raw: a log of :func:`nanoslam_jax.sim.park.simulate` (its trees, diameters and true poses).
        sim: the simulator settings.
        rng: the stream the clutter is drawn from.

    Returns:
        The world; clutter lies in the trees' bounding box, ``sim.laser_clearance`` from every trunk
        and 3 m from the true laser path.
    """
    trees = np.asarray(raw.truth_landmarks, dtype=np.float64)
    radius = 0.5 * np.asarray(raw.truth_diameters, dtype=np.float64)
    lo, hi = trees.min(axis=0), trees.max(axis=0)
    assert raw.truth_poses is not None  # a simulated log has its truth
    path = cKDTree(raw.truth_poses[:, 1:3])
    clear = sim.laser_clearance

    def make_line(rng, c):
        length = rng.uniform(*_LINE_LENGTH, c.shape[0])
        th = rng.uniform(0.0, np.pi, c.shape[0])
        half = 0.5 * length[:, None] * np.stack([np.cos(th), np.sin(th)], axis=1)
        return np.concatenate([c - half, c + half], axis=1)

    def line_ok(seg):
        s = np.linspace(0.0, 1.0, 401)
        pts = seg[:, None, :2] + s[None, :, None] * (seg[:, None, 2:] - seg[:, None, :2])
        d_path = path.query(pts.reshape(-1, 2))[0].reshape(pts.shape[:2])
        return (d_path.min(axis=1) >= PATH_CLEARANCE) & (_surface_gap(pts, trees, radius).min(axis=1) >= clear)

    def make_bush(rng, c):
        n = c.shape[0]
        mean_r = rng.uniform(*_BUSH_RADIUS, (n, 1))
        ang = (np.arange(BUSH_VERTICES) + rng.uniform(-0.3, 0.3, (n, BUSH_VERTICES))) * (2 * np.pi / BUSH_VERTICES)
        ang = ang + rng.uniform(0.0, 2 * np.pi, (n, 1))
        r = mean_r * (1.0 + sim.laser_bush_roughness * rng.uniform(-1.0, 1.0, (n, BUSH_VERTICES)))
        vx, vy = c[:, 0:1] + r * np.cos(ang), c[:, 1:2] + r * np.sin(ang)
        return np.concatenate([c, r.max(axis=1, keepdims=True), vx, vy], axis=1)

    def bush_ok(b):
        c, rb = b[:, :2], b[:, 2]
        return (path.query(c)[0] - rb >= PATH_CLEARANCE) & (_surface_gap(c, trees, radius) - rb >= clear)

    segs, kinds, objs = [], [], []
    for kind, n, key in ((KIND_WALL, sim.laser_walls, "laser_walls"), (KIND_FENCE, sim.laser_fences, "laser_fences")):
        if n:
            lines = np.array(_place(rng, n, make_line, lo, hi, line_ok, key))
            segs.append(lines)
            kinds.append(np.full(n, kind))
            objs.append(np.arange(n))
    if sim.laser_bushes:
        bushes = np.array(_place(rng, sim.laser_bushes, make_bush, lo, hi, bush_ok, "laser_bushes"))
        centres, bush_r = bushes[:, :2], bushes[:, 2]
        vx, vy = bushes[:, 3 : 3 + BUSH_VERTICES], bushes[:, 3 + BUSH_VERTICES :]
        segs.append(np.stack([vx, vy, np.roll(vx, -1, axis=1), np.roll(vy, -1, axis=1)], axis=2).reshape(-1, 4))
        kinds.append(np.full(vx.size, KIND_BUSH))
        objs.append(np.repeat(np.arange(sim.laser_bushes), BUSH_VERTICES))
    else:
        centres, bush_r = np.zeros((0, 2)), np.zeros(0)
    return LaserWorld(
        trees=trees,
        tree_radius=radius,
        segments=np.concatenate(segs, axis=0) if segs else np.zeros((0, 4)),
        segment_kind=np.concatenate(kinds).astype(np.int64) if kinds else np.zeros(0, np.int64),
        segment_object=np.concatenate(objs).astype(np.int64) if objs else np.zeros(0, np.int64),
        bush_centres=centres,
        bush_radius=bush_r,
    )


# --------------------------------------------------------------------------- the ray-caster


def _circle_t(ox, oy, dx, dy, cx, cy, r):
    """Distance along each ray to its first crossing of each circle (inf: none; rays starting inside miss).

    ``ox, oy``: ``(C, 1, 1)``; ``dx, dy``: ``(C, B, 1)``; ``cx, cy, r``: ``(1, 1, K)`` or broadcastable.
    """
    wx, wy = cx - ox, cy - oy
    t_ca = wx * dx + wy * dy
    d2 = wx * wx + wy * wy - t_ca * t_ca
    disc = r * r - d2
    t = t_ca - np.sqrt(np.maximum(disc, 0.0))
    return np.where((disc > 0.0) & (t > 0.0), t, np.inf)


def _segment_t(ox, oy, dx, dy, seg):
    """Distance along each ray to each segment ``seg (..., 4)`` (inf: no crossing); broadcasting as
    :func:`_circle_t`."""
    x0, y0, ex, ey = seg[..., 0], seg[..., 1], seg[..., 2] - seg[..., 0], seg[..., 3] - seg[..., 1]
    denom = dx * ey - dy * ex
    px, py = x0 - ox, y0 - oy
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (px * ey - py * ex) / denom
        s = (px * dy - py * dx) / denom
    return np.where((denom != 0.0) & (t > 0.0) & (s >= 0.0) & (s <= 1.0), t, np.inf)


class _Rays(NamedTuple):
    """The beams of a chunk of ``C`` poses, shaped to broadcast against ``K`` surfaces (:func:`_circle_t`).

    Attributes:
        p: ``(C, 3)`` the poses.
        ox, oy: ``(C, 1, 1)`` the beams' origin.
        dx, dy: ``(C, B, 1)`` their unit directions.
    """

    p: np.ndarray
    ox: np.ndarray
    oy: np.ndarray
    dx: np.ndarray
    dy: np.ndarray


class _Nearest(NamedTuple):
    """The nearest surface found so far along each beam of a chunk: ``(C, B)`` its distance (inf: none),
    kind and object; :meth:`offer` keeps the nearer of it and a candidate (the earlier one on a tie)."""

    best: np.ndarray
    kind: np.ndarray
    obj: np.ndarray

    def offer(self, t, k, o) -> None:
        better = t < self.best
        self.best[:] = np.where(better, t, self.best)
        self.kind[:] = np.where(better, k, self.kind)
        self.obj[:] = np.where(better, o, self.obj)


def _rays(p: np.ndarray, angles: np.ndarray) -> _Rays:
    th = p[:, 2, None] + angles[None, :]
    return _Rays(p, p[:, 0, None, None], p[:, 1, None, None], np.cos(th)[..., None], np.sin(th)[..., None])


def _offer_trees(rays: _Rays, world: LaserWorld, max_range: float, nearest: _Nearest, span: np.ndarray) -> None:
    """Offer each beam's nearest trunk among those within ``max_range`` of the chunk's poses; count in ``span``
    (``(C, T)``, in place) the beams that cross each trunk within range."""
    p = rays.p
    near = np.flatnonzero(
        np.min(
            np.hypot(world.trees[None, :, 0] - p[:, 0, None], world.trees[None, :, 1] - p[:, 1, None])
            - world.tree_radius[None, :],
            axis=0,
        )
        < max_range
    )
    if near.size:
        t = _circle_t(
            rays.ox, rays.oy, rays.dx, rays.dy, world.trees[near, 0], world.trees[near, 1], world.tree_radius[near]
        )
        span[:, near] = np.sum(t < max_range, axis=1)
        j = np.argmin(t, axis=2)
        nearest.offer(np.take_along_axis(t, j[..., None], axis=2)[..., 0], KIND_TREE, near[j])


def _offer_lines(rays: _Rays, lines: LaserWorld, fence_return: np.ndarray | None, nearest: _Nearest) -> None:
    """Offer each beam's nearest wall or fence (``lines``: the world's straight segments); a fence only to the
    beams ``fence_return`` (``(C, B)``, or None: all) marks."""
    t = _segment_t(rays.ox, rays.oy, rays.dx, rays.dy, lines.segments[None, None])
    if fence_return is not None:
        t = np.where((lines.segment_kind == KIND_FENCE)[None, None, :] & ~fence_return[:, :, None], np.inf, t)
    j = np.argmin(t, axis=2)
    nearest.offer(np.take_along_axis(t, j[..., None], axis=2)[..., 0], lines.segment_kind[j], lines.segment_object[j])


def _offer_bushes(rays: _Rays, world: LaserWorld, bush_seg: np.ndarray, max_range: float, nearest: _Nearest) -> None:
    """Offer each beam's nearest bush edge (``bush_seg``: ``(K, V, 4)`` the bushes' edges), testing only the
    (scan, beam, bush) triples whose ray crosses the bush's bounding circle."""
    c, n_b = nearest.best.shape
    p, dx, dy = rays.p, rays.dx, rays.dy
    tb = _circle_t(rays.ox, rays.oy, dx, dy, world.bush_centres[:, 0], world.bush_centres[:, 1], world.bush_radius)
    s_i, b_i, k_i = np.nonzero(tb < max_range)
    if s_i.size:
        segs = bush_seg[k_i]  # (n, V, 4)
        t = _segment_t(p[s_i, 0, None], p[s_i, 1, None], dx[s_i, b_i], dy[s_i, b_i], segs).min(axis=1)
        order = np.lexsort((t, s_i * n_b + b_i))
        flat = (s_i * n_b + b_i)[order]
        first = np.concatenate([[True], flat[1:] != flat[:-1]])
        sel = order[first]
        cand = np.full((c, n_b), np.inf)
        cobj = np.full((c, n_b), -1, dtype=np.int64)
        cand[s_i[sel], b_i[sel]] = t[sel]
        cobj[s_i[sel], b_i[sel]] = k_i[sel]
        nearest.offer(cand, KIND_BUSH, cobj)


def ray_cast(
    poses: Float[np.ndarray, "S 3"],
    angles: Float[np.ndarray, " B"],
    world: LaserWorld,
    max_range: float,
    fence_return: Bool[np.ndarray, "S B"] | None = None,
) -> tuple[Float[np.ndarray, "S B"], Int[np.ndarray, "S B"], Int[np.ndarray, "S B"], Int[np.ndarray, "S T"]]:
    """Noise-free ranges of a fan of beams cast from each pose into ``world`` (the nearest surface wins).

    Args:
        poses: ``(S, 3)`` laser poses ``x, y, phi``.
        angles: ``(B,)`` beam bearings in the sensor frame (rad, 0 ahead, left positive).
        world: the scene.
        max_range: surfaces at or beyond this range (m) are not seen.
        fence_return: ``(S, B)`` booleans: which beams return from a fence they cross (``None``: all).

    Returns:
        ``(ranges, kind, object_id, tree_span)``: ``(S, B)`` range to the surface hit (``inf``: none),
        what it is (:data:`KIND_TREE`, :data:`KIND_WALL`, :data:`KIND_FENCE`, :data:`KIND_BUSH`, -1
        none) and which one (tree row, or wall/fence/bush number; -1 none); ``(S, T)`` how many beams of
        each scan cross each trunk within ``max_range``, occluded or not.
    """
    poses = np.asarray(poses, dtype=np.float64)
    angles = np.asarray(angles, dtype=np.float64)
    n_s, n_b, n_t = poses.shape[0], angles.shape[0], world.trees.shape[0]
    ranges = np.full((n_s, n_b), np.inf)
    kind = np.full((n_s, n_b), KIND_NONE, dtype=np.int64)
    obj = np.full((n_s, n_b), -1, dtype=np.int64)
    span = np.zeros((n_s, n_t), dtype=np.int64)
    is_line = world.segment_kind != KIND_BUSH
    lines = world._replace(
        segments=world.segments[is_line],
        segment_kind=world.segment_kind[is_line],
        segment_object=world.segment_object[is_line],
    )
    bush_seg = world.segments[~is_line].reshape(-1, BUSH_VERTICES, 4)
    for a in range(0, n_s, _CHUNK):
        rays = _rays(poses[a : a + _CHUNK], angles)
        c = rays.p.shape[0]
        nearest = _Nearest(
            np.full((c, n_b), np.inf),
            np.full((c, n_b), KIND_NONE, dtype=np.int64),
            np.full((c, n_b), -1, dtype=np.int64),
        )
        if n_t:  # trunks near the chunk's poses
            _offer_trees(rays, world, max_range, nearest, span[a : a + c])
        if lines.segments.shape[0]:
            _offer_lines(rays, lines, None if fence_return is None else fence_return[a : a + c], nearest)
        if bush_seg.shape[0]:
            _offer_bushes(rays, world, bush_seg, max_range, nearest)
        seen = nearest.best < max_range
        ranges[a : a + c] = np.where(seen, nearest.best, np.inf)
        kind[a : a + c] = np.where(seen, nearest.kind, KIND_NONE)
        obj[a : a + c] = np.where(seen, nearest.obj, -1)
    return ranges, kind, obj, span


# --------------------------------------------------------------------------- the simulated log


def _scan_rows(raw: RawLog) -> np.ndarray:
    """Rows of ``raw.truth_poses`` at scan times (the simulator never puts a scan on a DR sample)."""
    rate = 1.0 / np.median(np.diff(raw.dr[:, 0]))
    assert raw.truth_poses is not None  # a simulated log has its truth
    k = raw.truth_poses[:, 0] * rate
    return np.flatnonzero(np.abs(k - np.round(k)) > 1e-6)


def simulate_laser(
    sim: SimConfig | None = None, vehicle: VehicleConfig | None = None, unicycle: UnicycleConfig | None = None
) -> LaserLog:
    """Simulate a log (:func:`nanoslam_jax.sim.park.simulate`) and ray-cast its raw scans.

    Args:
        sim: simulator settings, the ``laser_*`` keys included; ``None``: defaults.
        vehicle: car constants; ``None``: defaults.
        unicycle: a differential-drive robot instead of the car (see :func:`~nanoslam_jax.sim.park.simulate`).

    Returns:
        The log, its scans (one per scan time), the truth of which trees each scan hit, and the world.
        Deterministic for a given ``sim.seed``; the log itself is the one :func:`simulate` returns.
    """
    sim = SimConfig() if sim is None else sim
    raw = simulate(sim, vehicle, unicycle)
    # streams 0-4 are simulate()'s; 5 and 6 are new, so the log does not change
    seeds = np.random.SeedSequence(sim.seed).spawn(7)
    rng_world, rng_noise = np.random.default_rng(seeds[5]), np.random.default_rng(seeds[6])
    world = build_world(raw, sim, rng_world)
    rows = _scan_rows(raw)
    assert raw.truth_poses is not None  # a simulated log has its truth
    scan_t, poses = raw.truth_poses[rows, 0], raw.truth_poses[rows, 1:]
    angles = fan_angles(sim.laser_beams, sim.laser_fov_deg)
    n_s, n_b = scan_t.shape[0], angles.shape[0]
    fence_ok = rng_noise.random((n_s, n_b)) < sim.laser_fence_return
    true_r, kind, obj, span = ray_cast(poses, angles, world, sim.laser_max_range, fence_ok)
    hit = np.isfinite(true_r)
    meas = true_r + rng_noise.normal(0.0, sim.laser_range_noise, (n_s, n_b))
    dropped = hit & (rng_noise.random((n_s, n_b)) < sim.laser_dropout)
    spurious = rng_noise.random((n_s, n_b)) < sim.laser_spurious
    upper = np.where(hit, true_r, sim.laser_max_range)
    spur_r = _SPURIOUS_MIN + rng_noise.random((n_s, n_b)) * np.maximum(upper - _SPURIOUS_MIN, 0.0)
    meas = np.where(dropped | ~hit, NO_RETURN, meas)
    meas = np.where(spurious, np.minimum(spur_r, upper), meas)
    meas = np.where(meas >= sim.laser_max_range, NO_RETURN, np.maximum(meas, 0.0))
    lost = dropped | spurious
    kind = np.where(lost, KIND_NONE, kind)
    obj = np.where(lost, -1, obj)

    # truth: every tree some beam of the scan crosses
    s_i, t_i = np.nonzero(span)
    is_tree = kind == KIND_TREE
    hits = np.zeros_like(span)
    np.add.at(hits, (np.nonzero(is_tree)[0], obj[is_tree]), 1)
    dxy = world.trees[t_i] - poses[s_i, :2]
    truth = np.stack(
        [
            scan_t[s_i],
            t_i,
            hits[s_i, t_i],
            span[s_i, t_i],
            np.hypot(dxy[:, 0], dxy[:, 1]),
            wrap_angle_np(np.arctan2(dxy[:, 1], dxy[:, 0]) - poses[s_i, 2]),
            2 * world.tree_radius[t_i],
        ],
        axis=1,
    ).astype(np.float64)
    scans = LaserScans(time=scan_t, ranges=meas, angles=angles, max_range=sim.laser_max_range, source="simulated")
    return LaserLog(raw=raw, scans=scans, truth=truth, world=world, kind=kind, object_id=obj)


def simulate_laser_to_dir(
    directory: str | os.PathLike,
    sim: SimConfig | None = None,
    vehicle: VehicleConfig | None = None,
    unicycle: UnicycleConfig | None = None,
) -> LaserLog:
    """Simulate a log with raw scans (:func:`simulate_laser`) and write it as a log directory.

    Args:
        directory: output directory (created if needed). Receives the files of
            :func:`nanoslam_jax.sim.park.simulate_to_dir`, plus ``LASER.txt`` (:func:`write_laser`),
            ``laser_truth.csv`` (columns :data:`TRUTH_COLUMNS`, bearing in the vehicle frame in rad) and
            ``laser_world.csv`` (``kind, id, x0, y0, x1, y1``: the wall, fence and bush segments; trees
            as ``tree, id, x, y, diameter, 0``).
        sim, vehicle, unicycle: as for :func:`simulate_laser`.

    Returns:
        The simulated :class:`LaserLog`.
    """
    log = simulate_laser(sim, vehicle, unicycle)
    os.makedirs(directory, exist_ok=True)
    write_victoria_park(directory, log.raw)
    write_laser(os.path.join(directory, "LASER.txt"), log.scans)
    np.savetxt(
        os.path.join(directory, "laser_truth.csv"),
        log.truth,
        delimiter=",",
        fmt=["%.6f", "%d", "%d", "%d", "%.6f", "%.9f", "%.6f"],
        header=",".join(TRUTH_COLUMNS),
        comments="",
    )
    w = log.world
    with open(os.path.join(directory, "laser_world.csv"), "w") as f:
        f.write("kind,id,x0,y0,x1,y1\n")
        f.writelines(
            f"tree,{i},{x:.6f},{y:.6f},{2 * r:.6f},0\n" for i, ((x, y), r) in enumerate(zip(w.trees, w.tree_radius))
        )
        f.writelines(
            f"{_KIND_NAMES[int(k)]},{int(o)}," + ",".join(f"{v:.6f}" for v in seg) + "\n"
            for seg, k, o in zip(w.segments, w.segment_kind, w.segment_object)
        )
    return log
