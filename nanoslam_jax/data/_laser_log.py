"""A robot's 2-D laser log with odometry poses: what a CARMEN log or a ROS bag holds.

The readers of those formats return a :class:`LaserOdomLog`; the rest of the package sees only
its arrays (the scans, the odometry pose at each scan, the laser's mounting), never the file.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from jaxtyping import Float

from nanoslam_jax.data._laser import LaserScans

__all__ = ["LaserOdomLog"]


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
