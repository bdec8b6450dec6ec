"""The raw laser front end: from scans to clusters (adaptive breakpoint detector), split-and-merge
line segments, circle fits, corner and break points, and tree detections (docs/frontend.md)."""

from ._circles import CircleFit as CircleFit
from ._circles import fit_circle as fit_circle
from ._circles import fit_circles as fit_circles
from ._clusters import breakpoint_threshold as breakpoint_threshold
from ._extract import detect_lines as detect_lines
from ._extract import detect_trees as detect_trees
from ._extract import extract_features as extract_features
from ._io import (
    FEATURE_COLUMNS as FEATURE_COLUMNS,
)
from ._io import (
    concatenate_features as concatenate_features,
)
from ._io import (
    detect_log as detect_log,
)
from ._io import (
    extract_features_chunked as extract_features_chunked,
)
from ._io import (
    write_features_csv as write_features_csv,
)
from ._segments import polyline_vertices as polyline_vertices
from ._segments import split_and_merge as split_and_merge
from ._trees import width_radius as width_radius
from ._types import (
    EDGE_NAMES as EDGE_NAMES,
)
from ._types import (
    BreakPoints as BreakPoints,
)
from ._types import (
    Circles as Circles,
)
from ._types import (
    Clusters as Clusters,
)
from ._types import (
    Corners as Corners,
)
from ._types import (
    Features as Features,
)
from ._types import (
    Lines as Lines,
)
from ._types import (
    Points as Points,
)
from ._types import (
    Trees as Trees,
)

__all__ = [
    "EDGE_NAMES",
    "FEATURE_COLUMNS",
    "BreakPoints",
    "CircleFit",
    "Circles",
    "Clusters",
    "Corners",
    "Features",
    "Lines",
    "Points",
    "Trees",
    "breakpoint_threshold",
    "concatenate_features",
    "detect_lines",
    "detect_log",
    "detect_trees",
    "extract_features",
    "extract_features_chunked",
    "fit_circle",
    "fit_circles",
    "polyline_vertices",
    "split_and_merge",
    "width_radius",
    "write_features_csv",
]
