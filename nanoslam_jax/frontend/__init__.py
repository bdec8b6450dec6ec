"""The raw laser front end: from scans to clusters (adaptive breakpoint detector), split-and-merge
line segments, circle fits, corner and break points, and tree detections (docs/frontend.md)."""

from nanoslam_jax.frontend._circles import CircleFit as CircleFit
from nanoslam_jax.frontend._circles import fit_circle as fit_circle
from nanoslam_jax.frontend._circles import fit_circles as fit_circles
from nanoslam_jax.frontend._clusters import breakpoint_threshold as breakpoint_threshold
from nanoslam_jax.frontend._extract import detect_lines as detect_lines
from nanoslam_jax.frontend._extract import detect_trees as detect_trees
from nanoslam_jax.frontend._extract import extract_features as extract_features
from nanoslam_jax.frontend._io import (
    FEATURE_COLUMNS as FEATURE_COLUMNS,
)
from nanoslam_jax.frontend._io import (
    concatenate_features as concatenate_features,
)
from nanoslam_jax.frontend._io import (
    detect_log as detect_log,
)
from nanoslam_jax.frontend._io import (
    extract_features_chunked as extract_features_chunked,
)
from nanoslam_jax.frontend._io import (
    write_features_csv as write_features_csv,
)
from nanoslam_jax.frontend._segments import polyline_vertices as polyline_vertices
from nanoslam_jax.frontend._segments import split_and_merge as split_and_merge
from nanoslam_jax.frontend._trees import width_radius as width_radius
from nanoslam_jax.frontend._types import (
    EDGE_NAMES as EDGE_NAMES,
)
from nanoslam_jax.frontend._types import (
    BreakPoints as BreakPoints,
)
from nanoslam_jax.frontend._types import (
    Circles as Circles,
)
from nanoslam_jax.frontend._types import (
    Clusters as Clusters,
)
from nanoslam_jax.frontend._types import (
    Corners as Corners,
)
from nanoslam_jax.frontend._types import (
    Features as Features,
)
from nanoslam_jax.frontend._types import (
    Lines as Lines,
)
from nanoslam_jax.frontend._types import (
    Points as Points,
)
from nanoslam_jax.frontend._types import (
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
