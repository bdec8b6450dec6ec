"""Known data association (``filter.association: known``): every method matches detections to
landmarks by the log's ids, on a simulated log whose detections carry the tree they are of."""

import numpy as np
import pytest

import nanoslam_jax as ns
from nanoslam_jax.app.config import load_config
from nanoslam_jax.data import make_segments
from nanoslam_jax.sim.park import simulate

SETTINGS = [
    "sim.duration=40",
    "sim.clutter_rate=1.0",
    "filter.n_particles=6",
    "filter.association=known",
    "output.plots=false",
    # chunks and detection rows fixed (this log's k_max): the last test's known-association run is
    # then NANO-SLAM's program of the first test, loaded instead of compiled
    "data.k_max=13",
    "output.chunk=100",
]


def test_segments_carry_the_detection_ids():
    cfg = load_config(None, SETTINGS)
    raw = simulate(cfg.sim, cfg.vehicle)
    seg = make_segments(raw, max_range=cfg.data.max_range)
    kept = raw.detections[:, 1] < cfg.data.max_range
    ids = np.asarray(seg.z_id)[np.asarray(seg.z_mask)]
    np.testing.assert_array_equal(np.sort(ids), np.sort(raw.detection_ids[kept]))
    assert np.all(np.asarray(seg.z_id)[~np.asarray(seg.z_mask)] == -1)
    assert np.any(ids == -1)  # clutter has no id


@pytest.mark.parametrize("method", ["nano", "fastslam1", "ekf_slam", "nasrukf"])
@pytest.mark.slow
def test_known_association_maps_each_seen_tree_once(method):
    """One landmark per tree the log saw, none from clutter (which carries no id), each near its tree."""
    cfg = load_config(None, SETTINGS + [f"filter.method={method}", "map.manage=false"])
    raw = simulate(cfg.sim, cfg.vehicle)
    result = ns.run(cfg)
    seen = np.unique(raw.detection_ids[(raw.detection_ids >= 0) & (raw.detections[:, 1] < cfg.data.max_range)])
    lm = result.landmarks
    assert lm.shape[0] == seen.size
    trees = raw.truth_landmarks[seen]
    d = np.hypot(lm[:, None, 0] - trees[None, :, 0], lm[:, None, 1] - trees[None, :, 1])
    assert np.median(d.min(axis=1)) < 1.0, np.median(d.min(axis=1))


@pytest.mark.slow
def test_known_and_nearest_differ_only_by_the_rule():
    """Without clutter and with trees far apart, the ids pick what nearest neighbour picks."""
    base = [
        "sim.duration=30",
        "sim.clutter_rate=0",
        "sim.n_trees=60",
        "filter.n_particles=6",
        "map.manage=false",
        "output.plots=false",
        "data.k_max=13",
        "output.chunk=100",
    ]
    near = ns.run(overrides=base)
    known = ns.run(overrides=base + ["filter.association=known"])
    assert known.landmarks.shape[0] <= near.landmarks.shape[0]
    assert known.metrics["rmse_fixed"] < 2.0 * near.metrics["rmse_fixed"] + 0.1
