"""Evaluation on the host: metrics against GPS, truth or a survey (:mod:`.metrics`), the feature
errors of line and arc maps, a path against a reference path, the scoring of a run and the summary over seeds (one scorer for
every command), the figures of a run (:mod:`.plotting`) and the GPS floor (:mod:`.gps_floor`)."""

from nanoslam_jax.eval._reference_metrics import (
    ReferencePath as ReferencePath,
    align_on_reference as align_on_reference,
    reference_report as reference_report,
    relative_motion_error as relative_motion_error,
    score_reference as score_reference,
    trajectory_error as trajectory_error,
)
from nanoslam_jax.eval._scoring import (
    MapEstimate as MapEstimate,
    metric_goal as metric_goal,
    score_run as score_run,
    seed_summary as seed_summary,
    summarize_runs as summarize_runs,
)
from nanoslam_jax.eval._settings import MetricsConfig as MetricsConfig

__all__ = [
    "MapEstimate",
    "MetricsConfig",
    "ReferencePath",
    "align_on_reference",
    "metric_goal",
    "reference_report",
    "relative_motion_error",
    "score_reference",
    "score_run",
    "seed_summary",
    "summarize_runs",
    "trajectory_error",
]
