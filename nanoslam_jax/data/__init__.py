"""Logs: Victoria Park-format (detections and raw laser scans; loading and writing) and UTIAS
MRCLAM (loading), and cutting a log into fixed-shape segments."""

from ._laser import (
    LASER_FILES as LASER_FILES,
    LaserScans as LaserScans,
    fan_angles as fan_angles,
    find_laser_file as find_laser_file,
    load_laser as load_laser,
)
from ._loader import (
    LogFormatError as LogFormatError,
    LogWarning as LogWarning,
    load_victoria_park as load_victoria_park,
    write_victoria_park as write_victoria_park,
)
from ._mrclam import (
    MRCLAM_FIRST_LANDMARK as MRCLAM_FIRST_LANDMARK,
    MRCLAM_ROBOTS as MRCLAM_ROBOTS,
    SightingMap as SightingMap,
    dead_reckoning_map as dead_reckoning_map,
    load_mrclam as load_mrclam,
    unicycle_poses as unicycle_poses,
)
from ._segments import make_segments as make_segments, segment_summary as segment_summary
from ._types import RawLog as RawLog, Segments as Segments

__all__ = [
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
    "MRCLAM_ROBOTS",
    "MRCLAM_FIRST_LANDMARK",
    "unicycle_poses",
    "dead_reckoning_map",
    "SightingMap",
    "make_segments",
    "segment_summary",
]
