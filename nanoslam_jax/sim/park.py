"""A Victoria Park-like simulated log with ground truth (``data.kind = simulated``).

The simulator builds a :class:`~nanoslam_jax.data._types.RawLog` in exactly the conventions of
the real log (docs/method/victoria-park.md), so every part of the pipeline can be run and
checked against a known truth:

* **Trees.** ``sim.n_trees`` trees are scattered uniformly over a square park of side
  ``sim.area`` by sequential rejection (Poisson-disc-like): a candidate is kept only when it is
  at least :data:`TREE_SPACING` metres from every kept tree and :data:`PATH_CLEARANCE` metres
  from the driven reference path. If the park is too crowded for ``n_trees`` at that spacing
  the spacing is reduced (see :func:`_place_trees`; never silently fewer trees).
* **Path.** The vehicle laps a smooth closed curve, a superellipse ``|x/A|^4 + |y/B|^4 = 1``
  (aspect ``A/B = 1.3``, curvature continuous everywhere), ``sim.loops`` times. The curve is
  scaled so that its perimeter is the expected distance driven divided by ``sim.loops``
  (``loops <= 0`` is read as 1); its semi-axes are clamped to ``B >= MIN_SEMI_AXIS`` (the
  tightest turn then needs ``|alpha| < 0.35`` rad) and ``A <= 0.4 * area`` (it fits the park,
  which must be at least about 70 m wide); when clamped, the number of laps differs from
  ``sim.loops``. The park square is centred on the curve; the rear axle starts on the curve's
  lowest point heading +x, so the **laser** starts at pose ``(0, 0, 0)``: the simulator's frame
  *is* the SLAM frame.
* **Controls.** A pure-pursuit controller on the rear axle (lookahead ``max(5, 2 * speed)`` m,
  steering lag 0.25 s, rate limit 0.6 rad/s, ``|alpha| <= 0.45`` rad) produces the TRUE steering
  at every DR sample; the TRUE encoder speed is ``speed * ramp(t) * (1 + 0.1 sin(...))`` with a
  3 s smooth start from rest. The truth is integrated with the model of
  :mod:`nanoslam_jax.models` (one Euler step of :func:`~nanoslam_jax.models.vehicle_step` per DR
  interval, controls held, the same discretisation the filters use, so a filter fed the true
  controls has zero model error). The LOGGED controls (``RawLog.dr``) are the true ones plus
  white noise (``sim.sigma_v``, ``sim.sigma_alpha_deg``) plus a constant steering bias
  (``sim.steering_bias_deg``).
* **Time.** DR samples at ``k / sim.dr_rate`` for ``k = 0 .. floor(duration * dr_rate)`` (first
  at t = 0). Scans at about ``sim.scan_rate`` Hz (random phase, +-5 % jitter), nudged so that no
  scan coincides with a DR sample. The pose at a scan time integrates the remaining fraction of
  the DR interval, as in docs/method/victoria-park.md, "Time and segments".
* **Detections.** For every tree the true ``(r, beta)`` from the laser pose at the scan time is
  perturbed by ``N(0, sigma_r)``, ``N(0, sigma_beta)``; the tree is detected with probability
  ``sim.p_detect`` and reported when the *measured* range is in ``(0, max_range)`` and the
  measured bearing is within ``fov/2`` of the forward axis (the sensor reports what it measures,
  like the real log's range cut). Clutter: ``Poisson(sim.clutter_rate)`` false detections per
  scan, uniform over the sensor footprint (a disc sector of radius ``max_range`` and angle
  ``fov``). Diameters: each tree has a diameter drawn in ``[0.1, 0.6]`` m, reported with
  ``N(0, 0.02)`` noise (clipped to ``[0.1, 0.6]``); clutter diameters are uniform in that range.
  Scans with no detection are absent from ``detections`` (as in the real log). Within a scan the
  rows are sorted by bearing (the laser sweeps right to left).
* **Ground truth.** ``truth_poses`` holds the true laser pose at every DR sample time and every
  scan time (sorted); ``truth_landmarks`` the trees; ``gps`` the true laser positions at 5 Hz
  (times ``j / 5``, exactly on DR samples when ``dr_rate`` is a multiple of 5), noise-free and in
  the SLAM frame (evaluate with ``frame="slam"``).

Everything is deterministic for a given ``sim.seed`` (independent numpy ``Generator`` streams for
trees, speed profile/scan times, control noise, detections and clutter are spawned from one
``SeedSequence``). The default configuration (240 s at 40 Hz) takes well under a second.
"""

from __future__ import annotations

import math
import os
from typing import Union

import numpy as np
from scipy.spatial import cKDTree

from nanoslam_jax.sim._common import (
    DriveTruth,
    GPS_RATE,
    MAX_STEER,
    detections,
    drive,
    logged_controls,
    poses_at,
    scan_times,
    simulated_log,
    speed_profile,
    vehicle_for,
)
from nanoslam_jax.sim._settings import SimConfig
from nanoslam_jax.models._settings import UnicycleConfig, VehicleConfig
from nanoslam_jax.data._types import RawLog

__all__ = [
    "simulate",
    "simulate_to_dir",
    "reference_path",
    "TREE_SPACING",
    "PATH_CLEARANCE",
    "MIN_SEMI_AXIS",
    "GPS_RATE",
    "MAX_STEER",
]

#: Minimum distance between two trees (m); reduced only when the park cannot hold them.
TREE_SPACING = 5.0
#: Minimum distance of a tree from the rear-axle reference path (m).
PATH_CLEARANCE = 3.0
#: Smallest semi-axis B of the reference path (m); the tightest turn radius is about 0.4 B.
MIN_SEMI_AXIS = 20.0
#: Aspect ratio A / B of the reference superellipse.
PATH_ASPECT = 1.3
#: Path polyline spacing (m).
_PATH_DS = 0.25


# --------------------------------------------------------------------------- helpers


def _superellipse(aspect: float, n: int = 20000) -> tuple[np.ndarray, float]:
    """Unit superellipse ``|x/aspect|^4 + |y|^4 = 1`` resampled uniformly in arc length.

    Returns:
        ``(pts, perimeter)``: ``(m, 2)`` points starting at the lowest point ``(0, -1)`` and running
        counter-clockwise (closed: the last point is not repeated), and the perimeter.
    """
    th = np.linspace(-0.5 * np.pi, 1.5 * np.pi, n + 1)
    r = (np.abs(np.cos(th)) ** 4 / aspect**4 + np.abs(np.sin(th)) ** 4) ** -0.25
    x, y = r * np.cos(th), r * np.sin(th)
    seg = np.hypot(np.diff(x), np.diff(y))
    s = np.concatenate([[0.0], np.cumsum(seg)])
    return np.stack([x, y], axis=1), float(s[-1])


def reference_path(sim: SimConfig, vehicle: VehicleConfig, distance: float) -> tuple[np.ndarray, np.ndarray]:
    """The closed rear-axle reference path and the park centre, in the SLAM frame.

    Args:
        sim: simulator settings (``area``, ``loops``).
        vehicle: car constants (the rear axle starts at ``-(a, b)`` so the laser starts at 0).
        distance: expected distance driven (m); the perimeter is ``distance / loops``.

    Returns:
        ``(path, centre)``: ``(m, 2)`` points spaced about 0.25 m along the closed curve (the
        first point is the rear axle's start, the curve runs counter-clockwise), and the ``(2,)``
        centre of the curve and of the park square.
    """
    unit_dense, unit_perimeter = _superellipse(PATH_ASPECT)
    loops = sim.loops if sim.loops > 0 else 1.0
    b_axis = distance / loops / unit_perimeter
    b_axis = float(np.clip(b_axis, MIN_SEMI_AXIS, max(MIN_SEMI_AXIS, 0.4 * sim.area / PATH_ASPECT)))
    perimeter = unit_perimeter * b_axis
    m = max(int(round(perimeter / _PATH_DS)), 16)
    # resample uniformly in arc length
    seg = np.hypot(*np.diff(unit_dense, axis=0).T) * b_axis
    s = np.concatenate([[0.0], np.cumsum(seg)])
    s_new = np.arange(m) * (s[-1] / m)
    pts = np.stack([np.interp(s_new, s, unit_dense[:, 0]), np.interp(s_new, s, unit_dense[:, 1])], axis=1) * b_axis
    # lowest point (0, -B) -> rear-axle start (-a, -b)
    start = np.array([-vehicle.laser_a, -vehicle.laser_b])
    centre = start + np.array([0.0, b_axis])
    return pts + centre, centre


def _place_trees(rng: np.random.Generator, n: int, lo: np.ndarray, side: float, path: np.ndarray) -> np.ndarray:
    """Sequential rejection sampling of ``n`` trees in the square ``[lo, lo + side]^2``.

    Candidates come in vectorised batches; a candidate is accepted when it keeps
    :data:`PATH_CLEARANCE` from the path and the current spacing from every accepted tree
    (earlier candidates of its batch included, in order). The spacing starts at
    ``min(TREE_SPACING, 2 sqrt(0.3 side^2 / (pi n)))`` (discs of that diameter cover at most 30 %
    of the park, well below the ~55 % jamming limit of random sequential packing); after 10
    batches in a row that accept almost nothing the spacing shrinks by 20 %.

    Returns:
        ``(n, 2)`` tree positions.
    """
    spacing = min(TREE_SPACING, 2.0 * math.sqrt(0.3 * side * side / (math.pi * n)))
    trees = np.empty((0, 2))
    path_tree = cKDTree(path)
    fails = 0
    while trees.shape[0] < n:
        need = n - trees.shape[0]
        cand = lo + side * rng.random((min(4 * need + 64, 4096), 2))
        d_path, _ = path_tree.query(cand)
        cand = cand[d_path >= PATH_CLEARANCE]
        if trees.shape[0] and cand.shape[0]:
            d_tree, _ = cKDTree(trees).query(cand)
            cand = cand[d_tree >= spacing]
        # greedy acceptance inside the batch, in order
        neighbours = cKDTree(cand).query_ball_point(cand, spacing * (1.0 - 1e-12)) if cand.shape[0] else []
        accepted: list[int] = []
        blocked = np.zeros(cand.shape[0], dtype=bool)
        for i in range(cand.shape[0]):
            if not blocked[i]:
                accepted.append(i)
                blocked[neighbours[i]] = True
                if len(accepted) == need:
                    break
        if accepted:
            trees = np.vstack([trees, cand[accepted]])
        if len(accepted) > max(0.01 * need, 0.5):
            fails = 0
        else:
            fails += 1
            if fails >= 10:
                spacing *= 0.8
                fails = 0
                if spacing < 1e-3:
                    raise ValueError(f"cannot place {n} trees in a {side} m park")
    return trees


# --------------------------------------------------------------------------- public API


def simulate(
    sim: SimConfig | None = None, vehicle: VehicleConfig | None = None, unicycle: UnicycleConfig | None = None
) -> RawLog:
    """Simulate a Victoria Park-like log with ground truth (see the module docstring).

    Args:
        sim: simulator settings (:class:`~nanoslam_jax.app.config.SimConfig`); ``None``: defaults.
        vehicle: car constants (:class:`~nanoslam_jax.app.config.VehicleConfig`) of the vehicle
            model used for the truth; ``None``: defaults.
        unicycle: given, a differential-drive robot is simulated instead of the car: the sensor
            sits ``(unicycle.sensor_x, unicycle.sensor_y)`` from the robot's centre, which
            follows the same path, and ``dr`` logs ``time, v, omega`` (the centre's speed and
            turn rate, plus white noise ``sim.sigma_v`` and ``sim.sigma_omega_deg`` and a constant
            turn-rate bias ``sim.omega_bias_deg``), the controls of
            :class:`~nanoslam_jax.models.Unicycle`.

    Returns:
        A :class:`RawLog` with ``source="simulated"``:

        * ``dr``: ``(N, 3)`` ``time, ve, alpha`` LOGGED controls (true + noise + bias),
          ``N = floor(duration * dr_rate) + 1``, times ``k / dr_rate``;
        * ``detections``: ``(M, 4)`` ``time, range, bearing, diameter``, bearing in the vehicle
          frame in ``[-fov/2, fov/2]``, ``0 < range < max_range``;
        * ``gps``: ``(G, 3)`` ``time, x, y`` true laser positions at 5 Hz in the SLAM frame;
        * ``truth_poses``: ``(N + S, 4)`` ``time, x, y, phi`` at every DR and scan time, sorted;
        * ``truth_landmarks``: ``(n_trees, 2)`` tree positions;
        * ``truth_diameters``: ``(n_trees,)`` tree diameters;
        * ``detection_ids``: ``(M,)`` the tree each detection is of (its row of
          ``truth_landmarks``), -1 for clutter; ``landmark_ids``: ``0 .. n_trees - 1``.
    """
    sim = SimConfig() if sim is None else sim
    vehicle = vehicle_for(VehicleConfig() if vehicle is None else vehicle, unicycle)
    rng_tree, rng_prof, rng_ctrl, rng_det, rng_clut = (
        np.random.default_rng(s) for s in np.random.SeedSequence(sim.seed).spawn(5)
    )

    # ---- time base and true speed profile
    n_dr = int(math.floor(sim.duration * sim.dr_rate + 1e-9)) + 1
    dr_t = np.arange(n_dr) / sim.dr_rate
    dt = 1.0 / sim.dr_rate
    ve_true = speed_profile(sim.speed, dr_t, rng_prof)
    distance = float(np.sum(ve_true[:-1]) * dt)

    # ---- path, park and trees
    path, centre = reference_path(sim, vehicle, distance)
    lo = centre - 0.5 * sim.area
    trees = _place_trees(rng_tree, sim.n_trees, lo, sim.area, path)
    tree_diam = rng_tree.uniform(0.1, 0.6, size=sim.n_trees)

    # ---- truth at DR samples (closed-loop driver) and logged controls
    lookahead = max(5.0, 2.0 * sim.speed)
    dr_poses, alpha_true = drive(path, ve_true, dt, vehicle, lookahead)
    u_true = np.stack([ve_true, alpha_true], axis=1)
    dr = logged_controls(dr_t, ve_true, alpha_true, sim, vehicle, rng_ctrl, unicycle=unicycle is not None)

    # ---- scans, detections, truth
    scan_t = scan_times(dr_t[-1], sim, rng_prof)
    scan_poses = poses_at(scan_t, dr_t, dr_poses, u_true, vehicle)
    det, det_ids = detections(scan_t, scan_poses, trees, tree_diam, sim, rng_det, rng_clut)
    drive_truth = DriveTruth(dr, dr_poses, u_true, scan_t, scan_poses)
    return simulated_log(drive_truth, det, det_ids, trees, tree_diam, vehicle)


def simulate_config(cfg) -> RawLog:
    """:func:`simulate` with the settings of a run configuration: its ``sim`` and ``vehicle``
    sections, and a differential-drive robot (section ``unicycle``) when ``model.motion`` is
    ``unicycle``."""
    return simulate(cfg.sim, cfg.vehicle, cfg.unicycle if cfg.model.motion == "unicycle" else None)


def simulate_to_dir(
    directory: Union[str, os.PathLike],
    sim: SimConfig | None = None,
    vehicle: VehicleConfig | None = None,
    unicycle: UnicycleConfig | None = None,
) -> RawLog:
    """Simulate a log (:func:`simulate`) and write it as a Victoria Park-format directory.

    Args:
        directory: output directory (created if needed); receives ``inputs.dat``,
            ``measurements.dat`` (bearing + pi/2, as in the real file), ``gps.dat``,
            ``truth_poses.dat``, ``truth_landmarks.dat`` and ``truth_diameters.dat`` through
            :func:`nanoslam_jax.data._loader.write_victoria_park`.
        sim: simulator settings; ``None``: defaults.
        vehicle: car constants; ``None``: defaults.
        unicycle: a differential-drive robot instead of the car (see :func:`simulate`).

    Returns:
        The simulated :class:`RawLog` (as returned by :func:`simulate`, not re-read).
    """
    raw = simulate(sim, vehicle, unicycle)
    os.makedirs(directory, exist_ok=True)
    from nanoslam_jax.data import write_victoria_park

    write_victoria_park(directory, raw)
    return raw
