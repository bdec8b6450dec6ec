"""Victoria Park-format logs: loading (detections and raw laser scans), writing and cutting into
fixed-shape segments."""

from ._laser import (
    LASER_FILES as LASER_FILES,
    LaserScans as LaserScans,
    fan_angles as fan_angles,
    find_laser_file as find_laser_file,
    load_laser as load_laser,
)
from ._loader import (
    LogFormatError as LogFormatError,
    load_victoria_park as load_victoria_park,
    write_victoria_park as write_victoria_park,
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
    "load_victoria_park",
    "write_victoria_park",
    "make_segments",
    "segment_summary",
]
