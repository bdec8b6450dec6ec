"""One run scored the same way by every command (``run``, ``compare``, ``sweep`` and the study
through the sweep): its estimate smoothed when the smoother is on, checked for a non-finite pose,
measured by :func:`~nanoslam_jax.eval._scoring.score_run` against the log with its companion
tracks and map; and the filter's own statistics of the run."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, NamedTuple, Optional

import numpy as np

from nanoslam_jax.eval import MapEstimate
from nanoslam_jax.eval._scoring import companion_tracks, failure_reason, score_run
from nanoslam_jax.methods import AbstractEstimate
from nanoslam_jax.smoother import Smoothed, smoother_metrics

__all__ = ["Tracks", "Scored", "score_estimate", "filter_statistics"]


class Tracks(NamedTuple):
    """The trajectories of one run, ``(segments, 3)`` each.

    Attributes:
        estimate: the reported one (``filter.estimate``), before the smoother.
        best: the best particle's pose at each segment.
        mean: the weighted mean pose at each segment.
    """

    estimate: np.ndarray
    best: np.ndarray
    mean: np.ndarray


class Scored(NamedTuple):
    """A scored run.

    Attributes:
        metrics: the smoother's figures (when it ran) and :func:`score_run`'s.
        trajectory: the scored trajectory (the smoothed path when the smoother ran).
        before_smoother: the path the smoother started from, or None.
        reason: where the scored trajectory stops being finite (``''``: finite everywhere).
        warnings: the smoother's warnings.
    """

    metrics: dict
    trajectory: np.ndarray
    before_smoother: Optional[np.ndarray]
    reason: str
    warnings: list[str]


def score_estimate(
    log: Any,
    tracks: Tracks,
    estimate: AbstractEstimate,
    metrics_config: Any,
    landmarks: Optional[MapEstimate] = None,
    smooth: Optional[Callable[[np.ndarray], Smoothed]] = None,
    smoother_config: Any = None,
) -> Scored:
    """Score one run.

    Args:
        log: the log it ran on (a loaded log or a sweep's ``LogData``).
        tracks: its trajectories.
        estimate: the run's estimate component (which companion track is scored beside it).
        metrics_config: the ``metrics`` section.
        landmarks: the reported map (None: none).
        smooth: the smoother of this run, path -> :class:`~nanoslam_jax.smoother.Smoothed` (None:
            the smoother is off); it runs only on a finite path.
        smoother_config: the ``smoother`` section (named in its warnings).
    """
    est, before = np.asarray(tracks.estimate), None
    metrics: dict = {}
    warnings: list[str] = []
    if smooth is not None and np.all(np.isfinite(est)):
        sm = smooth(est)
        before, est = est, sm.poses
        report, warnings = smoother_metrics(sm, smoother_config)
        metrics.update(report)
    reason = failure_reason(np.asarray(log.segments.time), est)
    others = companion_tracks(estimate, np.asarray(tracks.best), np.asarray(tracks.mean), before)
    metrics.update(score_run(log, est, metrics_config, landmarks, others))
    return Scored(metrics, est, before, reason, warnings)


def filter_statistics(outputs: Any, overflow: Any, resamples: Any) -> dict:
    """The filter's own counts of one run: landmark and window overflows, resampling, ESS, proposal
    iterations and failures, weight resets, associations per scan.

    Args:
        outputs: the run's per-segment outputs (``ess``, ``iterations``, ``n_associated``,
            ``n_capped``, ``n_nonfinite``, ``window_overflow``, ``weight_reset``).
        overflow: the landmarks the run dropped for want of capacity.
        resamples: how many times it resampled.
    """
    o = outputs
    has = np.asarray(o.n_associated) > 0
    return dict(
        landmark_overflow=int(overflow),
        window_overflow_max=int(np.max(np.asarray(o.window_overflow), initial=0)),
        resample_count=int(resamples),
        ess_mean=float(np.mean(o.ess)),
        ess_min=float(np.min(o.ess)),
        nano_iterations_mean=float(np.mean(np.asarray(o.iterations)[has])) if has.any() else 0.0,
        proposal_capped=int(np.sum(o.n_capped)),
        proposal_nonfinite=int(np.sum(o.n_nonfinite)),
        weight_resets=int(np.sum(o.weight_reset)),
        associations_per_scan=float(np.mean(o.n_associated)),
    )
