"""Offline smoothing of a run: the final best particle's path and map refined by batch least
squares over the whole log, with loop closures (:mod:`._smoother`)."""

from nanoslam_jax.smoother._smoother import (
    DetectionNoise as DetectionNoise,
    LoopClosureSettings as LoopClosureSettings,
    SegmentData as SegmentData,
    SmootherSettings as SmootherSettings,
    Smoothed as Smoothed,
    associate_path as associate_path,
    final_map as final_map,
    held_landmarks as held_landmarks,
    segment_motion as segment_motion,
    smooth_filter_run as smooth_filter_run,
    smooth_path as smooth_path,
    smooth_run as smooth_run,
    smoother_map as smoother_map,
    smoother_metrics as smoother_metrics,
)

__all__ = [
    "DetectionNoise",
    "LoopClosureSettings",
    "SegmentData",
    "SmootherSettings",
    "Smoothed",
    "associate_path",
    "final_map",
    "held_landmarks",
    "segment_motion",
    "smooth_filter_run",
    "smooth_path",
    "smooth_run",
    "smoother_map",
    "smoother_metrics",
]
