"""The raw laser front end: from scans to clusters (adaptive breakpoint detector), split-and-merge
line segments, circle fits, corner and break points, and tree detections (docs/frontend.md)."""

from ._circles import CircleFit as CircleFit, fit_circle as fit_circle, fit_circles as fit_circles
from ._clusters import breakpoint_threshold as breakpoint_threshold
from ._extract import detect_trees as detect_trees, extract_features as extract_features
from ._io import (
    FEATURE_COLUMNS as FEATURE_COLUMNS,
    concatenate_features as concatenate_features,
    detect_log as detect_log,
    extract_features_chunked as extract_features_chunked,
    write_features_csv as write_features_csv,
)
from ._segments import polyline_vertices as polyline_vertices, split_and_merge as split_and_merge
from ._trees import width_radius as width_radius
from ._types import (
    EDGE_NAMES as EDGE_NAMES,
    BreakPoints as BreakPoints,
    Circles as Circles,
    Clusters as Clusters,
    Corners as Corners,
    Features as Features,
    Lines as Lines,
    Points as Points,
    Trees as Trees,
)

__all__ = [
    "detect_trees",
    "extract_features",
    "extract_features_chunked",
    "concatenate_features",
    "detect_log",
    "write_features_csv",
    "FEATURE_COLUMNS",
    "Features",
    "Points",
    "Clusters",
    "Lines",
    "Circles",
    "Corners",
    "BreakPoints",
    "Trees",
    "EDGE_NAMES",
    "fit_circle",
    "fit_circles",
    "CircleFit",
    "split_and_merge",
    "polyline_vertices",
    "breakpoint_threshold",
    "width_radius",
]
