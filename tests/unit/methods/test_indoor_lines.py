"""SLAM with line landmarks on indoor logs, end to end: the front end's segments as detections against
the true walls (computed here from the wall segments and the true laser pose), the local window's
search by a measurement model's distance, a short run's map against the true walls with Table 1's
metrics recomputed here, and the config's errors."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from nanoslam_jax.app.config import ConfigError, DetectorConfig, IndoorConfig, load_config
from nanoslam_jax.data import RawLog, make_segments
from nanoslam_jax.app.experiment import MAP_COLUMNS, execute, load_log, with_scan_detections
from nanoslam_jax.methods import LandmarkMap, gather_window
from nanoslam_jax.frontend import detect_lines
from nanoslam_jax.eval.metrics import feature_map_errors
from nanoslam_jax.models import LineSegment, RangeBearing
from nanoslam_jax.sim.indoor import feature_truth, read_feature_truth, simulate_indoor, simulate_indoor_to_dir

CLEAN = dict(range_noise=0.0, dropout=0.0, spurious=0.0)


def _wall_lines_in_sensor_frame(walls: np.ndarray, pose: np.ndarray) -> np.ndarray:
    """``(W, 2)`` the line ``(rho, alpha)`` of every wall segment in the frame of a laser at ``pose``."""
    x, y, th = pose
    c, s = np.cos(th), np.sin(th)
    ends = []
    for p in (walls[:, :2] - [x, y], walls[:, 2:] - [x, y]):
        ends.append(np.stack([c * p[:, 0] + s * p[:, 1], -s * p[:, 0] + c * p[:, 1]], axis=1))
    d = ends[1] - ends[0]
    n = np.stack([-d[:, 1], d[:, 0]], axis=1) / np.hypot(d[:, 0], d[:, 1])[:, None]
    rho = np.sum(n * ends[0], axis=1)
    n = np.where((rho < 0)[:, None], -n, n)
    return np.stack([np.abs(rho), np.arctan2(n[:, 1], n[:, 0])], axis=1)


def _line_distance(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``|rho_a - rho_b| + |alpha_a - alpha_b|`` (wrapped) of every row of ``a`` against every row of ``b``."""
    d_alpha = np.angle(np.exp(1j * (a[:, None, 1] - b[None, :, 1])))
    return np.abs(a[:, None, 0] - b[None, :, 0]) + np.abs(d_alpha)


@pytest.mark.slow
@pytest.mark.parametrize("template,seed", [("room", 3), ("corridor", 5)])
def test_segments_as_detections_match_true_walls(template, seed):
    """On a noise-free scan every segment's (rho, alpha) is a true wall's line in the laser's frame
    (exact unless the segment takes in a corner's or a jamb's return), and load_log puts them into
    the segments with the point detections' masks and padding."""
    cfg = IndoorConfig(seed=seed, template=template, duration=12.0, scan_period=0.5, **CLEAN)
    log = simulate_indoor(cfg)
    det_cfg = DetectorConfig(max_range=cfg.max_range, min_line_length=0.5)
    rows = detect_lines(log.scans, det_cfg)
    assert rows.shape[1] == 4 and rows.shape[0] > 2 * log.scans.time.size
    assert (rows[:, 3] >= 0.5).all() and (rows[:, 1] >= 0).all() and (np.abs(rows[:, 2]) <= np.pi).all()
    errors = []
    for t, rho, alpha, _ in rows:
        k = int(np.flatnonzero(log.scans.time == t)[0])
        true = _wall_lines_in_sensor_frame(log.world.walls, log.scan_pose[k])
        errors.append(_line_distance(np.array([[rho, alpha]]), true).min())
    errors = np.array(errors)
    assert np.median(errors) < 1e-8
    assert np.mean(errors < 2e-3) > 0.8 and errors.max() < 0.02
    # a shorter L_min gives more segments, all the longer ones among them
    shorter = detect_lines(log.scans, dataclasses.replace(det_cfg, min_line_length=0.2))
    assert shorter.shape[0] > rows.shape[0]

    # the detections of a run: every scan with a segment is a segment of the log, its lines in order
    raw = with_scan_detections(log.raw, log.scans, "laser_lines", det_cfg)
    assert raw.detection_ids is None
    seg = make_segments(raw, k_max=16)
    z, mask = np.asarray(seg.z), np.asarray(seg.z_mask)
    times = np.asarray(seg.time)[np.asarray(seg.is_scan)]
    np.testing.assert_array_equal(times, np.unique(rows[:, 0]))
    for i, t in enumerate(np.asarray(seg.time)):
        mine = rows[rows[:, 0] == t]
        assert mask[i].sum() == mine.shape[0] and not mask[i, mine.shape[0] :].any()
        np.testing.assert_array_equal(z[i, : mine.shape[0]], mine[:, 1:3])
        np.testing.assert_array_equal(np.asarray(seg.diam)[i, : mine.shape[0]], mine[:, 3])
        assert (z[i, mine.shape[0] :] == 0).all()


def _map(means: np.ndarray, capacity: int = 16) -> LandmarkMap:
    """A map holding ``means`` in its leading slots."""
    n = means.shape[0]
    lm = LandmarkMap.empty(capacity)
    return lm._replace(mean=lm.mean.at[:n].set(jnp.asarray(means)), active=jnp.arange(capacity) < n)


@pytest.mark.slow
def test_window_range_bearing_unchanged():
    """The default search (no model, range-bearing) picks the points within the radius of the
    position, the same bit for bit with and without the model."""
    rng = np.random.default_rng(0)
    pts = rng.uniform(-20.0, 20.0, (13, 2))
    lm = _map(pts)
    pos = jnp.array([1.5, -2.0])
    gather = jax.jit(gather_window, static_argnums=(2, 4))
    ref, idx_ref, over_ref = gather(lm, pos, 8, 12.0, None, None)
    got, idx, over = gather(lm, pos, 8, 12.0, None, RangeBearing())
    near = np.flatnonzero(np.hypot(pts[:, 0] - 1.5, pts[:, 1] + 2.0) < 12.0)
    np.testing.assert_array_equal(np.asarray(idx_ref)[: near.size], near[:8])
    assert int(over_ref) == max(near.size - 8, 0)
    for a, b in zip(jax.tree.leaves((ref, idx_ref, over_ref)), jax.tree.leaves((got, idx, over))):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))


@pytest.mark.slow
def test_window_searches_lines_by_perpendicular_distance():
    """A line landmark is in the window when the line passes within the radius of the position,
    wherever its (rho, alpha) lies: far lines near the position are in, lines through the origin
    far from the position are out."""
    pos = np.array([30.0, 40.0])
    radius = 5.0
    # lines through points at known distances from pos, in random directions
    rng = np.random.default_rng(1)
    dist = np.array([1.0, 4.9, 5.1, 20.0, 0.0, 3.0, 45.0])
    normal = rng.uniform(-np.pi, np.pi, dist.size)
    foot = pos + dist[:, None] * np.stack([np.cos(normal), np.sin(normal)], axis=1)
    rho = np.sum(foot * np.stack([np.cos(normal), np.sin(normal)], axis=1), axis=1)
    lines = np.stack([np.abs(rho), np.angle(np.exp(1j * np.where(rho < 0, normal + np.pi, normal)))], axis=1)
    lm = _map(lines)
    _, idx, over = jax.jit(gather_window, static_argnums=(2, 4))(lm, jnp.asarray(pos), 8, radius, None, LineSegment())
    expected = np.flatnonzero(dist < radius)
    np.testing.assert_array_equal(np.asarray(idx)[: expected.size], expected)
    assert (np.asarray(idx)[expected.size :] == 16).all() and int(over) == 0
    # the Euclidean distance to (rho, alpha) would pick other landmarks
    euclid = np.flatnonzero(np.hypot(lines[:, 0] - pos[0], lines[:, 1] - pos[1]) < radius)
    assert set(euclid) != set(expected)


def _true_lines_by_hand(world) -> tuple[np.ndarray, np.ndarray]:
    """The distinct walls' lines and the corners' rows, from the wall segments (not simulate_indoor's)."""
    ids = np.unique(world.wall_line)
    walls = np.array([world.walls[np.flatnonzero(world.wall_line == i)[0]] for i in ids])
    lines = _wall_lines_in_sensor_frame(walls, np.zeros(3))
    corners = np.searchsorted(ids, world.wall_line[world.corner_walls])
    return lines, corners


@pytest.mark.slow
def test_short_indoor_run_recovers_walls(tmp_path):
    """configs/indoor_lines.yaml on a short simulated room: the final map's lines lie within a few cm
    of the true walls, the metrics are feature_map_errors of that map computed here, and the same log
    written by the simulator and read with --data gives the same truth and a map as good."""
    over = [
        "indoor.template=room",
        "indoor.seed=2",
        "indoor.duration=40",
        "indoor.scan_period=0.2",
        "seed=2",
        "output.progress=false",
        "output.plots=false",
    ]
    cfg = load_config("configs/indoor_lines.yaml", over)
    res = execute(cfg, progress=False)
    m = res.metrics
    assert m["finite"] and m["rmse_fixed"] < 0.05 and m["rmse_heading_deg"] < 1.0
    log = simulate_indoor(cfg.indoor)
    lines, corners = _true_lines_by_hand(log.world)
    truth = feature_truth(log.world)
    np.testing.assert_allclose(truth.lines, lines, atol=1e-9)
    np.testing.assert_array_equal(truth.corners, corners)
    conf = res.landmarks[:, MAP_COLUMNS.index("confirmed")] > 0
    est = res.landmarks[conf, :2]
    table = feature_map_errors(est, lines, corners=corners)["summary"]
    for k, v in table.items():
        np.testing.assert_allclose(m[k], v, rtol=1e-9, atol=1e-12, err_msg=k)
    assert m["n_lines_matched"] >= m["n_lines"] - 1 and m["n_lines_est"] == est.shape[0]
    assert m["line_intercept_median"] < 0.03 and m["line_slope_median"] < 0.01 and m["corner_median"] < 0.05
    # every matched wall within a few cm and a degree of its true line
    d = _line_distance(est, lines)
    assert np.sort(d.min(axis=0))[: m["n_lines_matched"]].max() < 0.06

    # the same log from a directory (nanoslam simulate --scenario indoor), truth read from its files
    simulate_indoor_to_dir(tmp_path, cfg.indoor)
    read = read_feature_truth(tmp_path)
    np.testing.assert_allclose(read.lines, truth.lines, atol=1e-8)
    np.testing.assert_array_equal(read.corners, truth.corners)
    res_dir = execute(cfg, str(tmp_path), progress=False)
    assert res_dir.log.feature_truth is not None
    assert res_dir.metrics["line_intercept_median"] < 0.03 and res_dir.metrics["rmse_fixed"] < 0.05


@pytest.mark.slow
def test_indoor_log_carries_truth_and_line_segments():
    """data.kind indoor: the log's detections are the front end's segments of its scans, its truth
    path the laser's, its line truth the world's; a point map keeps the pillars as its map truth."""
    over = ["indoor.template=room", "indoor.seed=1", "indoor.duration=4", "indoor.scan_period=0.5"]
    cfg = load_config("configs/indoor_lines.yaml", over)
    log = load_log(cfg)
    ind = simulate_indoor(cfg.indoor)
    assert log.frame == "slam" and log.map_truth is None and log.feature_truth is not None
    np.testing.assert_array_equal(log.raw.truth_poses, ind.raw.truth_poses)
    rows = detect_lines(ind.scans, cfg.detector)
    z = np.asarray(log.segments.z)[np.asarray(log.segments.z_mask)]
    np.testing.assert_array_equal(z, rows[:, 1:3])
    points = load_config(None, ["data.kind=indoor", *over, "data.detections=file"])
    point_log = load_log(points)
    assert point_log.feature_truth is None and point_log.map_truth is not None


@pytest.mark.parametrize(
    "overrides,key",
    [
        (["data.detections=laser_lines"], "model.measurement"),
        (["data.kind=indoor", "model.measurement=line"], "data.detections"),
        (["data.kind=simulated", "data.detections=laser_lines", "model.measurement=line"], "data.detections"),
        (
            ["data.format=mrclam", "data.detections=laser_lines", "model.measurement=line", "model.motion=unicycle"],
            "data.detections",
        ),
        (["data.detections=lines"], "data.detections"),
        (["data.kind=room"], "data.kind"),
    ],
)
def test_bad_keys_name_the_key(overrides, key):
    with pytest.raises(ConfigError, match=f"'{key}'"):
        load_config(None, overrides)


@pytest.mark.slow
def test_no_lines_is_a_clear_error():
    """A log whose scans give no segment as long as detector.min_line_length names the key."""
    cfg = load_config(
        "configs/indoor_lines.yaml", ["indoor.duration=2", "indoor.scan_period=1.0", "detector.min_line_length=50"]
    )
    with pytest.raises(ValueError, match="detector.min_line_length"):
        load_log(cfg)


def test_raw_log_rows_are_lines():
    """The rows a line log holds: time, rho, alpha, length; make_segments keeps rho within the range
    limits (rho is the line's distance from the laser)."""
    raw = RawLog(
        dr=np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]]),
        detections=np.array([[0.5, 0.1, 0.0, 1.0], [0.5, 2.0, 1.0, 2.0], [0.5, 12.0, -1.0, 3.0]]),
        gps=np.zeros((0, 3)),
    )
    seg = make_segments(raw, min_range=0.2, max_range=10.0)
    np.testing.assert_array_equal(np.asarray(seg.z)[np.asarray(seg.z_mask)], [[2.0, 1.0]])
