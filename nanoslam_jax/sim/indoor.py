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
``indoor.fov_deg`` is cast from the true sensor pose with :func:`nanoslam_jax.sim.laser.ray_cast`
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
from scipy.ndimage import maximum_filter1d

from nanoslam_jax.sim._settings import IndoorConfig
from nanoslam_jax.data import LaserScans, fan_angles, write_victoria_park
from nanoslam_jax.data._laser import NO_RETURN, write_laser
from nanoslam_jax.data._types import RawLog
from nanoslam_jax.lib._angles import wrap_angle_np
from nanoslam_jax.sim.laser import KIND_NONE, KIND_TREE, ray_cast
from nanoslam_jax.sim._indoor_types import (
    TRUTH_FILES,
    ACCELERATION,
    BREAK_DOOR,
    BREAK_FREE_END,
    FeatureTruth,
    IndoorLog,
    IndoorPath,
    IndoorWorld,
    TEMPLATES,
    _BREAK_NAMES,
    _SPURIOUS_MIN,
    feature_truth,
    hessian_lines,
    read_feature_truth,
    slope_intercept_lines,
)
from nanoslam_jax.sim._indoor_world import build_world, indoor_laser_world, reference_path

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


class _Drive(NamedTuple):
    """The true drive at the odometry samples.

    Attributes:
        t: ``(N,)`` the sample times ``k dt``.
        controls: ``(N, 2)`` the true ``(v, omega)`` of each sample, held over its period.
        laser: ``(N + 1, 3)`` the laser poses at the samples and one period after the last (heading unwrapped).
        ref: ``(N + 1, 3)`` the reference point's poses there.
    """

    t: np.ndarray
    controls: np.ndarray
    laser: np.ndarray
    ref: np.ndarray


def _drive(cfg: IndoorConfig, path: IndoorPath, sensor: np.ndarray, rng: np.random.Generator) -> _Drive:
    """The true controls along ``path`` and the poses they give under the Euler step (module docstring)."""
    dt = cfg.odom_period
    n = int(math.floor(cfg.duration / dt + 1e-9)) + 1  # samples at k dt, k = 0 .. n - 1
    s = _arc_lengths(path, cfg, rng, n + 2)
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
    return _Drive(t, controls, laser, ref)


def _odometry(cfg: IndoorConfig, drive: _Drive, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(slip, sigma, logged)``: the samples in a slip episode, the noise's standard deviations at each
    and the logged controls (white noise that grows ``slip_factor``-fold in slip episodes, none standing still)."""
    controls = drive.controls
    v, w = controls[:, 0], controls[:, 1]
    slip = _slip_mask(drive.t, cfg, rng)
    turning = (np.abs(v) > 1e-9) | (np.abs(w) > 1e-9)
    factor = np.where(slip, cfg.slip_factor, 1.0) * turning
    sigma = np.stack([cfg.sigma_v * factor, math.radians(cfg.sigma_omega_deg) * factor], axis=1)
    logged = controls + rng.normal(0.0, 1.0, controls.shape) * sigma
    return slip, sigma, logged


class _Scans(NamedTuple):
    """The simulated laser scans.

    Attributes:
        time: ``(S,)`` the scan times.
        pose: ``(S, 3)`` the true laser pose at each (heading unwrapped).
        scans: the measured scans.
        kind: ``(S, B)`` what each beam's return came from (:data:`KIND_NONE` where it was lost).
        obj: ``(S, B)`` which object it came from (-1 where lost).
    """

    time: np.ndarray
    pose: np.ndarray
    scans: LaserScans
    kind: np.ndarray
    obj: np.ndarray


def _laser_scans(
    cfg: IndoorConfig, world: IndoorWorld, drive: _Drive, sensor: np.ndarray, rng: np.random.Generator
) -> _Scans:
    """Ray-cast a fan every ``scan_period`` from the true laser pose, with range noise, dropouts and
    spurious ranges (module docstring)."""
    t = drive.t
    n = t.size
    n_scan = int(math.floor(t[-1] / cfg.scan_period + 1e-9)) + 1
    scan_t = np.arange(n_scan) * cfg.scan_period
    scan_t = scan_t[scan_t <= t[-1]]
    scan_pose = _pose_at(scan_t, t, drive.laser[:n], drive.controls, sensor)
    angles = fan_angles(cfg.laser_beams, cfg.fov_deg)
    true_r, kind, obj, _ = ray_cast(scan_pose, angles, indoor_laser_world(world), cfg.max_range)
    shape = true_r.shape
    hit = np.isfinite(true_r)
    meas = np.where(hit, true_r, 0.0) + rng.normal(0.0, cfg.range_noise, shape)
    dropped = hit & (rng.random(shape) < cfg.dropout)
    spurious = rng.random(shape) < cfg.spurious
    upper = np.where(hit, true_r, cfg.max_range)
    spur_r = _SPURIOUS_MIN + rng.random(shape) * np.maximum(upper - _SPURIOUS_MIN, 0.0)
    meas = np.where(dropped | ~hit, NO_RETURN, meas)
    meas = np.where(spurious, np.minimum(spur_r, upper), meas)
    meas = np.where(meas >= cfg.max_range, NO_RETURN, np.maximum(meas, 0.0))
    lost = dropped | spurious
    kind = np.where(lost, KIND_NONE, kind)
    obj = np.where(lost, -1, obj)
    scans = LaserScans(time=scan_t, ranges=meas, angles=angles, max_range=cfg.max_range, source="simulated")
    return _Scans(scan_t, scan_pose, scans, kind, obj)


def _pillar_detections(
    cfg: IndoorConfig, world: IndoorWorld, sc: _Scans, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray]:
    """The pillars seen by 3 or more beams of a scan: ``(M, 4)`` detections ``time, range, bearing,
    diameter`` of their centres (measurements.dat) and ``(M,)`` the pillar of each."""
    n_scan = sc.time.shape[0]
    n_p = world.pillars.shape[0]
    pillar_beam = sc.kind == KIND_TREE
    counts = np.bincount((np.nonzero(pillar_beam)[0] * n_p + sc.obj[pillar_beam]), minlength=n_scan * n_p)
    si, pi = np.divmod(np.flatnonzero(counts.reshape(n_scan, n_p).ravel() >= 3), n_p)
    dxy = world.pillars[pi, :2] - sc.pose[si, :2]
    rng_true = np.hypot(dxy[:, 0], dxy[:, 1])
    det = np.stack(
        [
            sc.time[si],
            rng_true + rng.normal(0.0, cfg.range_noise, si.size),
            wrap_angle_np(
                np.arctan2(dxy[:, 1], dxy[:, 0])
                - sc.pose[si, 2]
                + rng.normal(0.0, 1.0, si.size) * cfg.range_noise / rng_true
            ),
            np.maximum(2 * world.pillars[pi, 2] + rng.normal(0.0, cfg.range_noise, si.size), 0.0),
        ],
        axis=1,
    ).reshape(-1, 4)
    return det, pi


def _raw_log(
    world: IndoorWorld, drive: _Drive, logged: np.ndarray, sc: _Scans, det: np.ndarray, pillar: np.ndarray
) -> RawLog:
    """The :class:`RawLog`: the logged odometry, the pillar detections, the true laser positions as the GPS and
    the true poses at every sample and scan time."""
    t = drive.t
    n = t.size
    laser = drive.laser
    truth_t = np.concatenate([t, sc.time])
    truth_p = np.concatenate([laser[:n], sc.pose], axis=0)
    truth_t, first = np.unique(truth_t, return_index=True)
    truth_poses = np.concatenate([truth_t[:, None], truth_p[first]], axis=1)
    truth_poses[:, 3] = wrap_angle_np(truth_poses[:, 3])
    return RawLog(
        dr=np.concatenate([t[:, None], logged], axis=1),
        detections=det,
        gps=np.concatenate([t[:, None], laser[:n, :2]], axis=1),
        truth_poses=truth_poses,
        truth_landmarks=world.pillars[:, :2].copy(),
        truth_diameters=2 * world.pillars[:, 2],
        source="simulated",
        detection_ids=pillar.astype(np.int64),
        landmark_ids=np.arange(world.pillars.shape[0]),
    )


def _wrapped(poses: np.ndarray) -> np.ndarray:
    """A copy of ``(N, 3)`` poses with the heading wrapped."""
    out = poses.copy()
    out[:, 2] = wrap_angle_np(out[:, 2])
    return out


def simulate_indoor(cfg: IndoorConfig | None = None) -> IndoorLog:
    """Simulate an indoor log (see the module docstring).

    Args:
        cfg: the ``indoor`` section (:class:`~nanoslam_jax.app.config.IndoorConfig`); ``None``: defaults.

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
    drive = _drive(cfg, path, sensor, rng_drive)
    slip, sigma, logged = _odometry(cfg, drive, rng_odo)
    sc = _laser_scans(cfg, world, drive, sensor, rng_laser)
    det, pillar = _pillar_detections(cfg, world, sc, rng_det)
    raw = _raw_log(world, drive, logged, sc, det, pillar)
    n = drive.t.size
    return IndoorLog(
        raw=raw,
        scans=sc.scans,
        world=world,
        path=path,
        time=drive.t,
        pose=_wrapped(drive.ref[:n]),
        sensor_pose=_wrapped(drive.laser[:n]),
        controls=drive.controls,
        sigma=sigma,
        slip=slip,
        scan_pose=_wrapped(sc.pose),
        kind=sc.kind,
        object_id=sc.obj,
    )


# --------------------------------------------------------------------------- files


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
