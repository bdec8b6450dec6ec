"""A city-sized simulated log with ground truth (``nanoslam simulate --scenario city``, ``data.kind: city``).

A car drives a street grid lined with trees and lamp posts, about 20 km among about 10,000 point
landmarks, returning to streets it left long before: a log to measure what a scan costs when the
map is city-sized. Everything but the world and the route is the park's (:mod:`.park`, through
:mod:`._common`): the car and its vehicle model, the pure-pursuit driver, the speed profile
(``sim.speed``), the DR and scan rates, the range-bearing sensor with its noise, misses and clutter,
the logged controls' noise and steering bias, the truth and the GPS (section ``sim``; its
``duration``, ``n_trees``, ``area``, ``loops`` and ``laser_*`` keys do not apply).

* **World** (section ``city``). ``city.blocks`` x ``city.blocks`` square blocks of side
  ``city.block_size``, separated by streets ``city.street_width`` wide: ``blocks + 1`` streets run
  each way, street ``i``'s centreline at ``i * pitch`` (``pitch = block_size + street_width``) in
  the grid frame. Each side of each block has ``floor(block_size / tree_spacing)`` street trees on
  its kerb, evenly spaced (the first half a spacing from the corner), each moved by up to
  ``city.tree_jitter`` along the kerb and up to 0.5 m into the block. Each block's interior (the
  block less a 5 m margin) holds ``round(interior_density * area / 1e4)`` trees on a jittered grid;
  with ``city.lamp_posts`` each block has a lamp post 1 m in from both kerbs at each corner. Tree
  diameters are drawn in ``[0.1, 0.6]`` m, lamp posts' in ``[0.15, 0.25]`` m.
* **Route.** It starts half a block west of the intersection nearest the centre, heading east,
  and walks the street graph: at each intersection straight on with probability
  ``city.p_straight``, else left or right, never back and never off the grid. Every
  ``city.revisit_every_m`` metres it drives the shortest way (without U-turns) to the street that
  it drove least recently among those it left at least that far back, drives along it and walks
  on. Turns are arcs of radius ``city.turn_radius`` tangent to both centrelines; the route is as
  long as the drive (``city.distance_m``) plus a margin. The car follows it with the park's
  driver, so it stays within a metre or two of the centreline.
* **Time.** The drive lasts ``distance_m / sim.speed + 1.5`` s (the speed's 3 s ramp from rest).
* **Detections.** Per scan only the landmarks in the 3 x 3 cells of a grid (cells of
  ``sim.max_range + 6 sim.sigma_r + 1`` m) around the pose are candidates; each is then detected
  exactly as in the park. A landmark beyond that radius would need a range error below
  ``-6 sim.sigma_r`` to be reported.

The frame: the rear axle starts at ``-(laser_a, laser_b)`` heading +x, so the laser starts at pose
``(0, 0, 0)`` and the simulator's frame is the SLAM frame (the grid frame shifted by
:attr:`CityWorld.origin`). Deterministic for a given ``city.seed``.
"""

from __future__ import annotations

import math
import os
from collections import deque
from dataclasses import dataclass
from typing import Optional, Union

import numpy as np

from nanoslam_jax.data._types import RawLog
from nanoslam_jax.models._settings import UnicycleConfig, VehicleConfig
from nanoslam_jax.sim._common import (
    DriveTruth,
    detections,
    drive,
    logged_controls,
    poses_at,
    scan_times,
    simulated_log,
    speed_profile,
    vehicle_for,
)
from nanoslam_jax.sim._settings import CityConfig, SimConfig

__all__ = ["CityWorld", "CityLog", "simulate_city", "simulate_city_to_dir", "city_landmark_count", "INTERIOR_MARGIN"]

#: Margin (m) between a block's kerbs and its interior trees.
INTERIOR_MARGIN = 5.0
#: The landmark kinds of :attr:`CityWorld.kind`.
STREET_TREE, INTERIOR_TREE, LAMP_POST = 0, 1, 2
#: Headings of the street graph: east, north, west, south; left of ``d`` is ``(d + 1) % 4``.
_DIRS = np.array([[1.0, 0.0], [0.0, 1.0], [-1.0, 0.0], [0.0, -1.0]])
_STEPS = ((1, 0), (0, 1), (-1, 0), (0, -1))
#: Route polyline spacing (m).
_PATH_DS = 0.25


@dataclass(frozen=True)
class CityWorld:
    """The street grid and its landmarks, in the SLAM frame.

    Attributes:
        origin: ``(2,)`` the SLAM-frame position of intersection ``(0, 0)``; street ``i``'s centreline
            runs at ``origin + i * pitch`` (x for the north-south streets, y for the east-west ones).
        pitch: distance between neighbouring centrelines (m).
        n_streets: streets each way (``blocks + 1``).
        landmarks: ``(L, 2)`` positions; diameters: ``(L,)``.
        kind: ``(L,)`` 0 street tree, 1 interior tree, 2 lamp post.
        nodes: ``(K, 2)`` the intersections the route passes, in order (grid indices).
    """

    origin: np.ndarray
    pitch: float
    n_streets: int
    landmarks: np.ndarray
    diameters: np.ndarray
    kind: np.ndarray
    nodes: np.ndarray


@dataclass(frozen=True)
class CityLog:
    """A simulated city log: the :class:`RawLog` (with its truth) and the world it was driven in."""

    raw: RawLog
    world: CityWorld


def city_landmark_count(city: CityConfig) -> int:
    """The number of landmarks a city of these settings holds (street trees, interior trees, lamp posts)."""
    b = city.block_size
    per_block = (
        4 * max(1, int(math.floor(b / city.tree_spacing))) + _interior_count(city) + (4 if city.lamp_posts else 0)
    )
    return city.blocks * city.blocks * per_block


def _interior_count(city: CityConfig) -> int:
    side = city.block_size - 2.0 * INTERIOR_MARGIN
    return int(round(city.interior_density * side * side / 1e4))


def _landmarks(city: CityConfig, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Street trees, interior trees and lamp posts of every block, in the grid frame."""
    b, w = city.block_size, city.street_width
    pitch = b + w
    n_b = city.blocks
    corners = np.stack(np.meshgrid(np.arange(n_b), np.arange(n_b), indexing="ij"), axis=-1).reshape(-1, 2)
    lo = corners * pitch + 0.5 * w  # (n_blocks, 2) lower-left corners of the blocks
    n_blocks = lo.shape[0]

    # street trees: four kerbs per block, n per kerb
    n = max(1, int(math.floor(b / city.tree_spacing)))
    along = (np.arange(n) + 0.5) * (b / n) + rng.uniform(-city.tree_jitter, city.tree_jitter, (n_blocks, 4, n))
    along = np.clip(along, 0.0, b)
    inward = rng.uniform(0.0, 0.5, (n_blocks, 4, n))
    x0, y0 = lo[:, 0, None], lo[:, 1, None]
    sides = [
        (x0 + along[:, 0], y0 + inward[:, 0]),  # south kerb
        (x0 + b - inward[:, 1], y0 + along[:, 1]),  # east kerb
        (x0 + b - along[:, 2], y0 + b - inward[:, 2]),  # north kerb
        (x0 + inward[:, 3], y0 + b - along[:, 3]),  # west kerb
    ]
    street = np.stack([np.stack([sx, sy], axis=-1) for sx, sy in sides], axis=1).reshape(-1, 2)

    # interior trees: a jittered grid of k x k cells, c of them drawn per block
    c = _interior_count(city)
    parts = [street]
    kinds = [np.full(street.shape[0], STREET_TREE)]
    if c > 0:
        side = b - 2.0 * INTERIOR_MARGIN
        k = int(math.ceil(math.sqrt(c)))
        cell = side / k
        margin = min(1.5, 0.25 * cell)
        chosen = np.argsort(rng.random((n_blocks, k * k)), axis=1)[:, :c]
        cij = np.stack([chosen // k, chosen % k], axis=-1).astype(float)
        inner = (
            lo[:, None, :] + INTERIOR_MARGIN + cij * cell + margin + rng.random((n_blocks, c, 2)) * (cell - 2 * margin)
        )
        parts.append(inner.reshape(-1, 2))
        kinds.append(np.full(n_blocks * c, INTERIOR_TREE))
    n_trees = sum(p.shape[0] for p in parts)
    diam = [rng.uniform(0.1, 0.6, n_trees)]
    if city.lamp_posts:
        offs = np.array([[1.0, 1.0], [b - 1.0, 1.0], [b - 1.0, b - 1.0], [1.0, b - 1.0]])
        lamps = (lo[:, None, :] + offs[None]).reshape(-1, 2)
        parts.append(lamps)
        kinds.append(np.full(lamps.shape[0], LAMP_POST))
        diam.append(rng.uniform(0.15, 0.25, lamps.shape[0]))
    return np.concatenate(parts), np.concatenate(diam), np.concatenate(kinds)


def _plan(n_streets: int, node: tuple[int, int], d_in: int, target: tuple) -> Optional[list[int]]:
    """The shortest sequence of headings from ``node`` (arrived heading ``d_in``) whose last move drives
    the street segment ``target`` (a sorted pair of nodes), without U-turns; ``None``: unreachable."""
    start = (node, d_in)
    parent: dict = {start: None}
    queue = deque([start])
    while queue:
        state = queue.popleft()
        (i, j), d = state
        for d2, (di, dj) in enumerate(_STEPS):
            if d2 == (d + 2) % 4:
                continue
            nxt = (i + di, j + dj)
            if not (0 <= nxt[0] < n_streets and 0 <= nxt[1] < n_streets):
                continue
            if tuple(sorted(((i, j), nxt))) == target:
                moves = [d2]
                s = state
                while parent[s] is not None:
                    moves.append(s[1])
                    s = parent[s]
                return moves[::-1]
            s2 = (nxt, d2)
            if s2 not in parent:
                parent[s2] = state
                queue.append(s2)
    return None


def _walk(city: CityConfig, rng: np.random.Generator, length: float) -> tuple[list[tuple[int, int]], list[int]]:
    """The intersections the route passes and the heading it leaves each with, until it is ``length`` long."""
    n_s = city.blocks + 1
    pitch = city.block_size + city.street_width
    turn_loss = (2.0 - 0.5 * math.pi) * city.turn_radius  # an arc is shorter than the corner it cuts
    node, d = (n_s // 2, n_s // 2), 0
    start = (node[0] - 1, node[1])
    last_visit: dict = {tuple(sorted((start, node))): 0.0}
    dist, since_revisit = 0.5 * pitch, 0.5 * pitch
    nodes: list[tuple[int, int]] = []
    outs: list[int] = []
    plan: list[int] = []
    while dist < length:
        if not plan and city.revisit_every_m > 0 and since_revisit >= city.revisit_every_m:
            old = [(t, e) for e, t in last_visit.items() if t <= dist - city.revisit_every_m]
            if old:
                target = min(old)[1]
                plan = _plan(n_s, node, d, target) or []
                since_revisit = 0.0
        if plan:
            d2 = plan.pop(0)
        else:
            options, weights = [], []
            for d2, w in (
                (d, city.p_straight),
                ((d + 1) % 4, 0.5 * (1 - city.p_straight)),
                ((d + 3) % 4, 0.5 * (1 - city.p_straight)),
            ):
                i, j = node[0] + _STEPS[d2][0], node[1] + _STEPS[d2][1]
                if 0 <= i < n_s and 0 <= j < n_s:
                    options.append(d2)
                    weights.append(w)
            p = np.asarray(weights) + 1e-12
            d2 = options[int(rng.choice(len(options), p=p / p.sum()))]
        nxt = (node[0] + _STEPS[d2][0], node[1] + _STEPS[d2][1])
        step = pitch - (turn_loss if d2 != d else 0.0)
        nodes.append(node)
        outs.append(d2)
        dist += step
        since_revisit += step
        last_visit[tuple(sorted((node, nxt)))] = dist
        node, d = nxt, d2
    nodes.append(node)
    outs.append(d)
    return nodes, outs


def _line(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    n = max(1, int(math.ceil(float(np.hypot(*(q - p))) / (0.2 * _PATH_DS))))
    return p + np.arange(n)[:, None] / n * (q - p)


def _route_path(nodes: list[tuple[int, int]], outs: list[int], pitch: float, radius: float) -> np.ndarray:
    """The rear-axle route in the grid frame, resampled every 0.25 m: lines along the centrelines, arcs at turns."""
    first = np.asarray(nodes[0], float) * pitch
    p, d = first - 0.5 * pitch * _DIRS[0], 0
    pieces = []
    for node, d_out in zip(nodes, outs):
        if d_out == d:
            continue
        xy = np.asarray(node, float) * pitch
        t_in = xy - radius * _DIRS[d]
        pieces.append(_line(p, t_in))
        turn = 1.0 if d_out == (d + 1) % 4 else -1.0
        centre = t_in + radius * _DIRS[(d + (1 if turn > 0 else 3)) % 4]
        a0 = math.atan2(*(t_in - centre)[::-1])
        n_arc = max(2, int(math.ceil(0.5 * math.pi * radius / (0.2 * _PATH_DS))))
        ang = a0 + turn * 0.5 * math.pi * np.arange(n_arc) / n_arc
        pieces.append(centre + radius * np.stack([np.cos(ang), np.sin(ang)], axis=1))
        p, d = xy + radius * _DIRS[d_out], d_out
    end = np.asarray(nodes[-1], float) * pitch
    pieces.append(np.vstack([_line(p, end), end[None]]))
    dense = np.concatenate(pieces)
    s = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(dense, axis=0).T))])
    s_new = np.arange(0.0, s[-1], _PATH_DS)
    return np.stack([np.interp(s_new, s, dense[:, 0]), np.interp(s_new, s, dense[:, 1])], axis=1)


def _grid_pairs(xy: np.ndarray, landmarks: np.ndarray, radius: float) -> tuple[np.ndarray, np.ndarray]:
    """``(scan, landmark)`` index pairs of the landmarks in the 3 x 3 grid cells (side ``radius``) around each
    position: every landmark within ``radius`` of a position, and some farther; grouped by scan, in scan order."""
    lo = landmarks.min(axis=0) - radius
    cl = np.floor((landmarks - lo) / radius).astype(np.int64)
    nx, ny = int(cl[:, 0].max()) + 2, int(cl[:, 1].max()) + 2
    key = cl[:, 0] * ny + cl[:, 1]
    order = np.argsort(key, kind="stable")
    counts = np.bincount(key, minlength=nx * ny)
    starts = np.cumsum(counts) - counts
    cs = np.floor((xy - lo) / radius).astype(np.int64)
    cx = np.clip(cs[:, 0], 0, nx - 1)[:, None] + np.array([-1, -1, -1, 0, 0, 0, 1, 1, 1])
    cy = np.clip(cs[:, 1], 0, ny - 1)[:, None] + np.array([-1, 0, 1, -1, 0, 1, -1, 0, 1])
    valid = (cx >= 0) & (cx < nx) & (cy >= 0) & (cy < ny)
    nb = np.where(valid, cx * ny + cy, 0)
    cnt = np.where(valid, counts[nb], 0).ravel()
    total = int(cnt.sum())
    si = np.repeat(np.repeat(np.arange(xy.shape[0]), 9), cnt)
    first = np.cumsum(cnt) - cnt
    offset = np.arange(total) - np.repeat(first, cnt)
    li = order[np.repeat(starts[nb].ravel(), cnt) + offset]
    return si, li


def simulate_city(
    city: CityConfig | None = None,
    sim: SimConfig | None = None,
    vehicle: VehicleConfig | None = None,
    unicycle: UnicycleConfig | None = None,
) -> CityLog:
    """Simulate a city log with ground truth (see the module docstring).

    Args:
        city: the world and the route (:class:`~nanoslam_jax.sim._settings.CityConfig`); ``None``: defaults.
        sim: the sensor, its noise, the rates, the speed and the odometry noise
            (:class:`~nanoslam_jax.sim._settings.SimConfig`; its world and duration keys do not
            apply); ``None``: defaults.
        vehicle: car constants; ``None``: defaults.
        unicycle: a differential-drive robot instead of the car, as in :func:`nanoslam_jax.sim.park.simulate`.

    Returns:
        A :class:`CityLog`: its ``raw`` in the conventions of :func:`nanoslam_jax.sim.park.simulate`
        (``detection_ids`` name each detection's landmark, -1 for clutter) and its ``world``.
    """
    city = CityConfig() if city is None else city
    sim = SimConfig() if sim is None else sim
    vehicle = vehicle_for(VehicleConfig() if vehicle is None else vehicle, unicycle)
    if city.turn_radius > 0.5 * city.street_width + 0.25 * city.block_size:
        raise ValueError(
            f"city.turn_radius {city.turn_radius} m: expected at most street_width / 2 + block_size / 4 "
            f"({0.5 * city.street_width + 0.25 * city.block_size} m)"
        )
    rng_world, rng_route, rng_prof, rng_ctrl, rng_det, rng_clut = (
        np.random.default_rng(s) for s in np.random.SeedSequence(city.seed).spawn(6)
    )

    # ---- time base and true speed profile
    duration = city.distance_m / sim.speed + 1.5
    n_dr = int(math.floor(duration * sim.dr_rate + 1e-9)) + 1
    dr_t = np.arange(n_dr) / sim.dr_rate
    dt = 1.0 / sim.dr_rate
    ve_true = speed_profile(sim.speed, dr_t, rng_prof)
    distance = float(np.sum(ve_true[:-1]) * dt)

    # ---- world and route (grid frame), then the SLAM frame: the rear axle starts at -(a, b)
    pitch = city.block_size + city.street_width
    landmarks, diam, kind = _landmarks(city, rng_world)
    lookahead = max(5.0, 2.0 * sim.speed)
    nodes, outs = _walk(city, rng_route, distance + 2.0 * lookahead + 10.0)
    path = _route_path(nodes, outs, pitch, city.turn_radius)
    origin = np.array([-vehicle.laser_a, -vehicle.laser_b]) - path[0]
    path, landmarks = path + origin, landmarks + origin

    # ---- truth, controls, scans, detections
    dr_poses, alpha_true = drive(path, ve_true, dt, vehicle, lookahead, closed=False)
    u_true = np.stack([ve_true, alpha_true], axis=1)
    dr = logged_controls(dr_t, ve_true, alpha_true, sim, vehicle, rng_ctrl, unicycle=unicycle is not None)
    scan_t = scan_times(dr_t[-1], sim, rng_prof)
    scan_poses = poses_at(scan_t, dr_t, dr_poses, u_true, vehicle)
    pairs = _grid_pairs(scan_poses[:, :2], landmarks, sim.max_range + 6.0 * sim.sigma_r + 1.0)
    det, det_ids = detections(scan_t, scan_poses, landmarks, diam, sim, rng_det, rng_clut, pairs)
    raw = simulated_log(DriveTruth(dr, dr_poses, u_true, scan_t, scan_poses), det, det_ids, landmarks, diam, vehicle)
    world = CityWorld(
        origin=origin,
        pitch=pitch,
        n_streets=city.blocks + 1,
        landmarks=landmarks,
        diameters=diam,
        kind=kind,
        nodes=np.asarray(nodes, dtype=np.int64),
    )
    return CityLog(raw=raw, world=world)


def simulate_city_to_dir(
    directory: Union[str, os.PathLike],
    city: CityConfig | None = None,
    sim: SimConfig | None = None,
    vehicle: VehicleConfig | None = None,
    unicycle: UnicycleConfig | None = None,
) -> CityLog:
    """Simulate a city log (:func:`simulate_city`) and write it as a Victoria Park-format directory.

    The files are those of :func:`nanoslam_jax.sim.park.simulate_to_dir` (``inputs.dat``,
    ``measurements.dat``, ``gps.dat``, ``truth_poses.dat``, ``truth_landmarks.dat``,
    ``truth_diameters.dat``): ``nanoslam run --data DIR`` reads them and scores against the truth.
    """
    log = simulate_city(city, sim, vehicle, unicycle)
    os.makedirs(directory, exist_ok=True)
    from nanoslam_jax.data import write_victoria_park

    write_victoria_park(directory, log.raw)
    return log
