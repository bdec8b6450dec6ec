"""A robot's 2-D laser log with odometry poses: what a CARMEN log or a ROS bag holds.

The readers of those formats return a :class:`LaserOdomLog`; the rest of the package sees only
its arrays (the scans, the odometry pose at each scan, the laser's mounting), never the file.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np
from jaxtyping import Float

from nanoslam_jax.data._laser import LaserScans
from nanoslam_jax.data._types import RawLog

__all__ = [
    "CONTROL_LAYOUTS",
    "LaserOdomLog",
    "laser_odom_raw",
    "laser_poses",
    "odometry_rows",
    "odometry_rows_from_unicycle",
]

#: The control layouts :func:`laser_odom_raw` writes.
CONTROL_LAYOUTS = ("unicycle", "odometry")


@dataclass(frozen=True)
class LaserOdomLog:
    """Laser scans with the robot's odometry pose at each scan.

    Attributes:
        scans: the scans (time sorted, ranges at or above ``scans.max_range`` are no returns,
            beam angles in the laser's frame: 0 straight ahead, left positive).
        odom: ``(S, 3)`` the robot's odometry pose ``(x, y, theta)`` (m, m, rad) at each scan's
            time, in the odometry frame (the robot's base, not the laser).
        laser_pose: ``(3,)`` the laser's mounting ``(x, y, theta)`` in the robot's base frame.
        out_of_order: how many scan (or odometry) records of the file were not in time order
            and were sorted.
        source: the file the log came from.
    """

    scans: LaserScans
    odom: Float[np.ndarray, "S 3"]
    laser_pose: Float[np.ndarray, "3"]
    out_of_order: int = 0
    source: str = ""

    def __post_init__(self):
        odom = np.asarray(self.odom, dtype=np.float64)
        pose = np.asarray(self.laser_pose, dtype=np.float64)
        if odom.shape != (self.scans.n_scans, 3):
            raise ValueError(f"LaserOdomLog: odom must have shape ({self.scans.n_scans}, 3), got {odom.shape}")
        if pose.shape != (3,):
            raise ValueError(f"LaserOdomLog: laser_pose must have shape (3,), got {pose.shape}")
        object.__setattr__(self, "odom", odom)
        object.__setattr__(self, "laser_pose", pose)

    @property
    def n_scans(self) -> int:
        return self.scans.n_scans


def _wrap(a):
    return (np.asarray(a) + np.pi) % (2 * np.pi) - np.pi


def laser_poses(log: LaserOdomLog) -> Float[np.ndarray, "S 3"]:
    """The laser's pose at each scan in the odometry frame: the robot's odometry pose (+) the mounting."""
    o, m = log.odom, log.laser_pose
    c, s = np.cos(o[:, 2]), np.sin(o[:, 2])
    x = o[:, 0] + c * m[0] - s * m[1]
    y = o[:, 1] + s * m[0] + c * m[1]
    return np.stack([x, y, _wrap(o[:, 2] + m[2])], axis=1)


def _unicycle_rows(t: np.ndarray, pose: np.ndarray) -> np.ndarray:
    """Two ``(time, v, omega)`` rows per interval between consecutive poses, reproducing the poses
    under the unicycle model's first-order step: over the first half the robot turns half the
    heading change in place; over the second it moves the chord along the middle heading and turns
    the rest. The last row (at the last time) holds no motion."""
    dt = np.diff(t)
    d = np.diff(pose[:, :2], axis=0)
    dth = _wrap(np.diff(pose[:, 2]))
    mid = pose[:-1, 2] + dth / 2
    along = d[:, 0] * np.cos(mid) + d[:, 1] * np.sin(mid)
    omega = dth / dt
    turn = np.stack([t[:-1], np.zeros_like(dt), omega], axis=1)
    move = np.stack([t[:-1] + dt / 2, 2 * along / dt, omega], axis=1)
    rows = np.stack([turn, move], axis=1).reshape(-1, 3)
    return np.concatenate([rows, [[t[-1], 0.0, 0.0]]], axis=0)


def odometry_rows(t: Float[np.ndarray, " n"], pose: Float[np.ndarray, "n 3"]) -> Float[np.ndarray, "n 4"]:
    """One ``(time, vx, vy, omega)`` row per interval between consecutive odometry poses: the
    increment from pose ``i`` to pose ``i + 1`` in the body frame of pose ``i`` (forward, left,
    heading change wrapped), divided by the interval, the controls of the ``odometry`` motion
    model, which composes them back into the poses exactly. The last row (at the last time) holds
    no motion.

    Args:
        t: strictly increasing times (s).
        pose: the odometry pose ``(x, y, theta)`` at each time.
    """
    t, pose = np.asarray(t, dtype=np.float64), np.asarray(pose, dtype=np.float64)
    dt = np.diff(t)
    d = np.diff(pose[:, :2], axis=0)
    c, s = np.cos(pose[:-1, 2]), np.sin(pose[:-1, 2])
    fwd = c * d[:, 0] + s * d[:, 1]
    left = -s * d[:, 0] + c * d[:, 1]
    dth = _wrap(np.diff(pose[:, 2]))
    rows = np.stack([t[:-1], fwd / dt, left / dt, dth / dt], axis=1)
    return np.concatenate([rows, [[t[-1], 0.0, 0.0, 0.0]]], axis=0)


def odometry_rows_from_unicycle(dr: Float[np.ndarray, "n 3"]) -> Float[np.ndarray, "n 4"]:
    """``(time, v, omega)`` rows of a differential-drive robot as the ``odometry`` model's
    ``(time, vx, vy, omega)`` rows: the odometry pose stream that the unicycle's first-order step
    integrates moves the robot's centre by ``dt (v, 0, omega)`` in its own frame each row, so the
    rows are ``(time, v, 0, omega)``."""
    dr = np.asarray(dr, dtype=np.float64)
    if dr.ndim != 2 or dr.shape[1] != 3:
        raise ValueError(f"odometry_rows_from_unicycle: expected (time, v, omega) rows, got shape {dr.shape}")
    return np.stack([dr[:, 0], dr[:, 1], np.zeros(dr.shape[0]), dr[:, 2]], axis=1)


def laser_odom_raw(log: LaserOdomLog, controls: str = "unicycle") -> tuple[RawLog, LaserScans]:
    """What the filter runs on from a laser log: the odometry as controls and the scans.

    The filter's pose is the laser's position with the robot's heading: the motion model's sensor
    offset must be the mounting's ``(x, y)`` (``unicycle.sensor_x`` / ``sensor_y``), and the beam
    angles are turned by the mounting's angle so that they are measured from the robot's heading.

    Args:
        log: the laser log (time sorted; scans with equal times share one pose).
        controls: the layout of the controls written to ``dr``: ``'unicycle'``: ``(time, v,
            omega)`` rows, forward speed (m/s) and turn rate (rad/s) of the robot's centre, each held
            from its time to the next row's; two rows per interval between consecutive scan times (a
            turn in place by half the heading change, then the chord along the middle heading with
            the other half), which the unicycle model's step follows exactly with no sensor offset,
            and a last row of no motion at the last scan; ``'odometry'``: ``(time, vx, vy, omega)``
            rows, one per interval between consecutive scan times, the body-frame increment of the
            robot's odometry pose over the interval as rates (:func:`odometry_rows`), the controls
            of the ``odometry`` motion model (its sensor offset the mounting's ``(x, y)``).

    Returns:
        ``(raw, scans)``: a :class:`~nanoslam_jax.data.RawLog` with the controls in ``dr`` (no
        detections, no GPS) and the scans with beam angles from the robot's heading.

    Raises:
        ValueError: an unknown control layout, or a log with fewer than two distinct scan times.
    """
    if controls not in CONTROL_LAYOUTS:
        raise ValueError(f"laser_odom_raw: controls must be one of {', '.join(CONTROL_LAYOUTS)}, got {controls!r}")
    t_all = log.scans.time
    t, first = np.unique(t_all, return_index=True)
    if t.size < 2:
        raise ValueError(f"{log.source or 'laser log'}: needs at least two distinct scan times, got {t.size}")
    pose = log.odom[first]
    dr = _unicycle_rows(t, pose) if controls == "unicycle" else odometry_rows(t, pose)
    scans = dataclasses.replace(log.scans, angles=log.scans.angles + log.laser_pose[2])
    raw = RawLog(dr=dr, detections=np.zeros((0, 4)), gps=np.zeros((0, 3)), source=log.source)
    return raw, scans
