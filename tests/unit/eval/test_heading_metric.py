"""The heading metric ``rmse_heading_deg`` (nanoslam_jax/eval/metrics.py): against headings with known
errors across the +-180 deg cut, and in the metrics of a run of a simulated log against the error
computed here by atan2."""

import math

import numpy as np
import pytest

from nanoslam_jax.app.config import load_config
from nanoslam_jax.app.experiment import execute
from nanoslam_jax.eval.metrics import heading_errors, rmse_heading_deg


def test_heading_error_by_hand_across_the_cut():
    """Truth: 179 deg at t = 0, -179 deg (= 181) at t = 1, -170 at t = 2. Estimates: t = 0: -178
    (3 deg ahead across the cut), t = 0.5: -179.5 (truth 180: +0.5), t = 1: 178 (-3), t = 2: -170
    plus 360 (0), t = 3: outside the truth's span, left out."""
    truth = np.array([[0.0, 0, 0, math.radians(179)], [1.0, 0, 0, math.radians(-179)], [2.0, 0, 0, math.radians(-170)]])
    t = np.array([0.0, 0.5, 1.0, 2.0, 3.0])
    est = np.radians([-178.0, -179.5, 178.0, 190.0, 0.0])
    tt, err = heading_errors(t, est, truth)
    np.testing.assert_array_equal(tt, t[:4])
    np.testing.assert_allclose(err, [3.0, 0.5, -3.0, 0.0], atol=1e-9)
    assert rmse_heading_deg(t, est, truth) == pytest.approx(math.sqrt((9 + 0.25 + 9 + 0) / 4))
    with pytest.raises(ValueError, match="time span"):
        heading_errors(np.array([5.0]), np.array([0.0]), truth)
    with pytest.raises(ValueError, match=r"\(N, 4\)"):
        heading_errors(t, est, truth[:, :3])


@pytest.mark.slow
def test_every_run_of_a_simulated_log_reports_its_heading_rmse():
    """Dead reckoning on 20 s of the embedded simulated log: ``rmse_heading_deg`` is the RMS of
    the wrapped difference to the truth at the segment times, computed here by atan2."""
    cfg = load_config(None, ["filter.method=dead_reckoning", "sim.duration=20", "output.progress=false"])
    r = execute(cfg)
    tp = r.log.raw.truth_poses
    truth = np.interp(r.times, tp[:, 0], np.unwrap(tp[:, 3]))
    d = r.trajectory[:, 2] - truth
    ref = math.degrees(math.sqrt(np.mean(np.arctan2(np.sin(d), np.cos(d)) ** 2)))
    assert r.metrics["rmse_heading_deg"] == pytest.approx(ref, rel=1e-9)
    assert r.metrics["rmse_heading_deg"] > 0
