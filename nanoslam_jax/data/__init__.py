"""Logs: Victoria Park-format (detections and raw laser scans; loading and writing), UTIAS
MRCLAM, CARMEN laser logs and ROS bags (loading), reference paths, and cutting a log into fixed-shape segments."""

from nanoslam_jax.data._carmen import load_carmen as load_carmen, read_carmen as read_carmen
from nanoslam_jax.data._laser import (
    LASER_FILES as LASER_FILES,
    LaserScans as LaserScans,
    fan_angles as fan_angles,
    find_laser_file as find_laser_file,
    load_laser as load_laser,
)
from nanoslam_jax.data._laser_log import (
    LaserOdomLog as LaserOdomLog,
    laser_odom_raw as laser_odom_raw,
    odometry_rows as odometry_rows,
    odometry_rows_from_unicycle as odometry_rows_from_unicycle,
    laser_poses as laser_poses,
)
from nanoslam_jax.data._loader import (
    LogFormatError as LogFormatError,
    LogWarning as LogWarning,
    load_victoria_park as load_victoria_park,
    write_victoria_park as write_victoria_park,
)
from nanoslam_jax.data._mrclam import (
    MRCLAM_FIRST_LANDMARK as MRCLAM_FIRST_LANDMARK,
    MRCLAM_ROBOTS as MRCLAM_ROBOTS,
    SightingMap as SightingMap,
    dead_reckoning_map as dead_reckoning_map,
    load_mrclam as load_mrclam,
    unicycle_poses as unicycle_poses,
)
from nanoslam_jax.data._reference import load_reference as load_reference
from nanoslam_jax.data._rosbag import load_rosbag as load_rosbag
from nanoslam_jax.data._segments import make_segments as make_segments, segment_summary as segment_summary
from nanoslam_jax.data._types import RawLog as RawLog, Segments as Segments

__all__ = [
    "load_rosbag",
    "RawLog",
    "LaserScans",
    "load_laser",
    "find_laser_file",
    "fan_angles",
    "LASER_FILES",
    "Segments",
    "LogFormatError",
    "LogWarning",
    "load_victoria_park",
    "write_victoria_park",
    "load_mrclam",
    "load_carmen",
    "read_carmen",
    "LaserOdomLog",
    "laser_odom_raw",
    "odometry_rows",
    "odometry_rows_from_unicycle",
    "laser_poses",
    "load_reference",
    "MRCLAM_ROBOTS",
    "MRCLAM_FIRST_LANDMARK",
    "unicycle_poses",
    "dead_reckoning_map",
    "SightingMap",
    "make_segments",
    "segment_summary",
]
