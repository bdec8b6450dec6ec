"""Victoria Park-format logs: loading, writing and cutting into fixed-shape segments."""

from ._loader import (
    LogFormatError as LogFormatError,
    load_victoria_park as load_victoria_park,
    write_victoria_park as write_victoria_park,
)
from ._segments import make_segments as make_segments, segment_summary as segment_summary
from ._types import RawLog as RawLog, Segments as Segments

__all__ = [
    "RawLog",
    "Segments",
    "LogFormatError",
    "load_victoria_park",
    "write_victoria_park",
    "make_segments",
    "segment_summary",
]
