"""The one scorer of a run (``app._scored``): on a log with GPS equal to a known path, the scored
trajectory is the smoother's and the path it started from is scored beside it; a non-finite path
is not smoothed and says where it stopped being finite; the filter's counts are those of the
outputs given."""

from types import SimpleNamespace

import numpy as np
import pytest

from nanoslam_jax.app._scored import Tracks, filter_statistics, score_estimate
from nanoslam_jax.app.config import MetricsConfig
from nanoslam_jax.methods import AncestralPath, BestParticle


def _log(truth: np.ndarray) -> SimpleNamespace:
    """A log whose GPS fixes are the true path at every segment, in the SLAM frame (no alignment)."""
    t = np.arange(len(truth), dtype=float)
    raw = SimpleNamespace(gps=np.c_[t, truth[:, :2]], truth_poses=None)
    return SimpleNamespace(
        segments=SimpleNamespace(time=t, z_id=np.full((len(t), 1), -1)),
        raw=raw,
        frame="slam",
        map_truth=None,
        survey=None,
        feature_truth=None,
        reference=None,
    )


def _smoothed(poses: np.ndarray) -> SimpleNamespace:
    fields = dict(iterations=3, converged=True, associated=5, detections=6, initial_cost=2.0, cost=1.0)
    return SimpleNamespace(poses=poses, seconds=0.1, merged=0, rejected=0, **fields)


@pytest.fixture
def truth() -> np.ndarray:
    s = np.linspace(0.0, 50.0, 60)
    return np.c_[s, 0.1 * s, np.zeros_like(s)]


def test_the_smoothed_path_is_scored_with_the_one_it_started_from(truth):
    path = truth + np.array([2.0, 0.0, 0.0])  # 2 m off everywhere
    smooth = lambda p: _smoothed(p - np.array([1.5, 0.0, 0.0]))  # noqa: E731  0.5 m off
    sc = score_estimate(
        _log(truth), Tracks(path, path, path), AncestralPath(), MetricsConfig(), None, smooth, SimpleNamespace()
    )
    assert sc.reason == "" and sc.warnings == []
    np.testing.assert_allclose(sc.trajectory, truth + np.array([0.5, 0.0, 0.0]))
    np.testing.assert_array_equal(sc.before_smoother, path)
    assert sc.metrics["rmse_fixed"] == pytest.approx(0.5, rel=1e-9)
    assert sc.metrics["rmse_fixed_path"] == pytest.approx(2.0, rel=1e-9)
    assert sc.metrics["smoother_iterations"] == 3 and sc.metrics["smoother_converged"]


def test_a_non_finite_path_is_not_smoothed_and_says_where(truth):
    path = truth.copy()
    path[40:] = np.nan

    def smooth(p):
        raise AssertionError("a non-finite path must not reach the smoother")

    best = truth + np.array([0.0, 1.0, 0.0])
    sc = score_estimate(_log(truth), Tracks(path, best, truth), BestParticle(), MetricsConfig(), None, smooth, None)
    assert sc.reason == "non-finite estimate from segment 40 (t = 40.00 s)"
    assert sc.before_smoother is None and not sc.metrics["finite"]


def test_the_filter_counts_are_those_of_the_outputs():
    out = SimpleNamespace(
        ess=np.array([10.0, 4.0, 6.0]),
        iterations=np.array([0.0, 3.0, 5.0]),
        n_associated=np.array([0, 2, 4]),
        n_capped=np.array([0, 1, 0]),
        n_nonfinite=np.array([0, 0, 2]),
        window_overflow=np.array([0, 3, 1]),
        weight_reset=np.array([False, True, True]),
    )
    st = filter_statistics(out, 7, 2)
    assert st == dict(
        landmark_overflow=7,
        window_overflow_max=3,
        resample_count=2,
        ess_mean=pytest.approx(20.0 / 3.0),
        ess_min=4.0,
        nano_iterations_mean=4.0,  # over the scans with an association only
        proposal_capped=1,
        proposal_nonfinite=2,
        weight_resets=2,
        associations_per_scan=2.0,
    )
