"""Simulated raw scans (nanoslam_jax.sim.laser) against closed forms computed here."""

import numpy as np
import pytest

from nanoslam_jax.app.cli import main
from nanoslam_jax.app.config import ConfigError, SimConfig, load_config
from nanoslam_jax.data import fan_angles, load_laser
from nanoslam_jax.sim.park import simulate
from nanoslam_jax.sim.laser import (
    BUSH_VERTICES,
    KIND_BUSH,
    KIND_FENCE,
    KIND_NONE,
    KIND_TREE,
    KIND_WALL,
    NO_RETURN,
    LaserWorld,
    ray_cast,
    simulate_laser,
    simulate_laser_to_dir,
)

ANGLES = fan_angles(361, 180.0)


def _world(trees=(), radii=(), segments=(), kinds=(), bushes=()):
    """A world from trees, straight segments of the given kinds, and regular 20-gon bushes ``(x, y, r)``
    with a vertex pointing at the origin."""
    segs, kk, oo = [np.reshape(np.asarray(segments, float), (-1, 4))], [np.asarray(kinds, int)], [np.arange(len(kinds))]
    for i, (x, y, r) in enumerate(bushes):
        a = np.arctan2(-y, -x) + np.arange(BUSH_VERTICES) * 2 * np.pi / BUSH_VERTICES
        vx, vy = x + r * np.cos(a), y + r * np.sin(a)
        segs.append(np.stack([vx, vy, np.roll(vx, -1), np.roll(vy, -1)], axis=1))
        kk.append(np.full(BUSH_VERTICES, KIND_BUSH))
        oo.append(np.full(BUSH_VERTICES, i))
    return LaserWorld(
        np.reshape(np.asarray(trees, float), (-1, 2)),
        np.asarray(radii, float),
        np.concatenate(segs),
        np.concatenate(kk),
        np.concatenate(oo),
        np.reshape(np.asarray([b[:2] for b in bushes], float), (-1, 2)),
        np.asarray([b[2] for b in bushes], float),
    )


def _circle_range(pose, angles, c, r):
    """Closed form: range along each beam to a circle (inf where the beam misses)."""
    th = pose[2] + angles
    wx, wy = c[0] - pose[0], c[1] - pose[1]
    along = wx * np.cos(th) + wy * np.sin(th)
    perp = -wx * np.sin(th) + wy * np.cos(th)
    ok = (np.abs(perp) < r) & (along > 0)
    return np.where(ok, along - np.sqrt(np.maximum(r * r - perp * perp, 0.0)), np.inf)


def test_circle_closed_form_and_span():
    pose = np.array([1.0, -2.0, 0.4])
    c, r = np.array([1.0 + 12 * np.cos(0.5), -2.0 + 12 * np.sin(0.5)]), 0.35
    ranges, kind, obj, span = ray_cast(pose[None], ANGLES, _world([c], [r]), 80.0)
    want = _circle_range(pose, ANGLES, c, r)
    hit = np.isfinite(want)
    assert hit.sum() >= 3
    np.testing.assert_allclose(ranges[0, hit], want[hit], rtol=0, atol=1e-9)
    assert np.all(np.isinf(ranges[0, ~hit]))
    assert np.all(kind[0, hit] == KIND_TREE) and np.all(obj[0, hit] == 0) and np.all(kind[0, ~hit] == KIND_NONE)
    assert span[0, 0] == hit.sum()
    # the beam nearest the centre's bearing (0.1 rad in the sensor frame) is 12 - r at the centre line
    b = np.argmin(np.abs(ANGLES - 0.1))
    off = ANGLES[b] - 0.1
    assert abs(ranges[0, b] - (12 * np.cos(off) - np.sqrt(r**2 - (12 * np.sin(off)) ** 2))) < 1e-9


def test_wall_at_perpendicular_distance_and_max_range():
    # a wall 7 m ahead of a laser at (2, 3) heading 90 deg: the line y = 10, x in [-30, 30]
    pose = np.array([2.0, 3.0, np.pi / 2])
    world = _world(segments=[[-30.0, 10.0, 30.0, 10.0]], kinds=[KIND_WALL])
    ranges, kind, _, _ = ray_cast(pose[None], ANGLES, world, 80.0)
    # beam angle a (left positive) meets y = 10 at 7 / cos(a) where x = 2 - 7 tan(a) lies on the wall
    inside = np.abs(np.cos(ANGLES)) > 1e-9
    x_hit = 2.0 - 7.0 * np.tan(ANGLES, where=inside, out=np.full_like(ANGLES, np.inf))
    want = np.where(inside & (np.abs(x_hit) <= 30.0), 7.0 / np.abs(np.cos(ANGLES)), np.inf)
    want = np.where(want < 80.0, want, np.inf)
    hit = np.isfinite(want)
    np.testing.assert_allclose(ranges[0, hit], want[hit], atol=1e-9)
    assert np.all(np.isinf(ranges[0, ~hit])) and np.all(kind[0, hit] == KIND_WALL)
    assert ranges[0, 180] == pytest.approx(7.0, abs=1e-12)
    # with a 7 m maximum range nothing is seen
    assert np.all(np.isinf(ray_cast(pose[None], ANGLES, world, 7.0)[0]))


def test_occlusion_nearer_object_wins_and_fences_pass():
    pose = np.array([0.0, 0.0, 0.0])
    world = _world(
        trees=[[5.0, 0.0]],
        radii=[0.3],
        segments=[[10.0, -50.0, 10.0, 50.0], [8.0, -50.0, 8.0, 50.0]],
        kinds=[KIND_WALL, KIND_FENCE],
        bushes=[(6.5 * np.cos(ANGLES[250]), 6.5 * np.sin(ANGLES[250]), 1.0)],
    )
    ranges, kind, obj, _ = ray_cast(pose[None], ANGLES, world, 80.0)
    tree = _circle_range(pose, ANGLES, (5.0, 0.0), 0.3)
    on_tree = np.isfinite(tree)
    np.testing.assert_allclose(ranges[0, on_tree], tree[on_tree], atol=1e-9)
    assert np.all(kind[0, on_tree] == KIND_TREE)
    # the bush's 20-gon has a vertex 5.5 m out on beam 250: the beam stops there
    assert kind[0, 250] == KIND_BUSH and obj[0, 250] == 0 and ranges[0, 250] == pytest.approx(5.5, abs=1e-9)
    # elsewhere ahead the fence (x = 8) hides the wall (x = 10) ...
    clear = ~on_tree & (kind[0] != KIND_BUSH) & (np.abs(ANGLES) < 1.3)
    np.testing.assert_allclose(ranges[0, clear], 8.0 / np.cos(ANGLES[clear]), atol=1e-9)
    assert np.all(kind[0, clear] == KIND_FENCE)
    # ... unless the beams pass through the fence's mesh
    through = np.ones((1, ANGLES.size), bool)
    through[0, clear] = False
    r2, k2, _, _ = ray_cast(pose[None], ANGLES, world, 80.0, fence_return=through)
    np.testing.assert_allclose(r2[0, clear], 10.0 / np.cos(ANGLES[clear]), atol=1e-9)
    assert np.all(k2[0, clear] == KIND_WALL)
    # a tree hidden behind the wall is crossed by beams (span) but hit by none
    hidden = _world(trees=[[20.0, 0.0]], radii=[0.5], segments=[[10.0, -50.0, 10.0, 50.0]], kinds=[KIND_WALL])
    _, k3, _, span3 = ray_cast(pose[None], ANGLES, hidden, 80.0)
    assert span3[0, 0] == np.isfinite(_circle_range(pose, ANGLES, (20.0, 0.0), 0.5)).sum() > 0
    assert not np.any(k3 == KIND_TREE)


def test_chunks_give_the_same_as_one_scan_at_a_time():
    rng = np.random.default_rng(3)
    world = _world(
        trees=rng.uniform(-30, 30, (40, 2)),
        radii=rng.uniform(0.05, 0.3, 40),
        segments=[[-20.0, 25.0, 20.0, 28.0]],
        kinds=[KIND_WALL],
        bushes=[(10.0, -12.0, 1.5)],
    )
    poses = np.column_stack([rng.uniform(-2, 2, (70, 2)), rng.uniform(-np.pi, np.pi, 70)])
    r, k, _, s = ray_cast(poses, ANGLES, world, 80.0)
    for i in (0, 33, 69):
        r1, k1, _, s1 = ray_cast(poses[i : i + 1], ANGLES, world, 80.0)
        np.testing.assert_array_equal(r1[0], r[i])
        np.testing.assert_array_equal(k1[0], k[i])
        np.testing.assert_array_equal(s1[0], s[i])


@pytest.fixture(scope="module")
def short_log():
    return simulate_laser(SimConfig(seed=4, duration=25.0))


def test_log_and_truth_against_closed_forms(short_log):
    log = short_log
    sim = SimConfig(seed=4, duration=25.0)
    raw = simulate(sim)
    np.testing.assert_array_equal(log.raw.detections, raw.detections)  # the raw scans leave the log alone
    scans, truth = log.scans, log.truth
    assert scans.ranges.shape == (scans.time.size, 361)
    on_grid = np.isclose(scans.time * sim.dr_rate, np.round(scans.time * sim.dr_rate), atol=1e-6, rtol=0)
    assert not on_grid.any()
    poses = raw.truth_poses[np.searchsorted(raw.truth_poses[:, 0], scans.time)]
    np.testing.assert_array_equal(poses[:, 0], scans.time)
    # each truth row: range, bearing and diameter of the tree from the true pose; beams crossing it and
    # beams whose written range lies on its surface, counted here by the closed form
    s = np.searchsorted(scans.time, truth[:, 0])
    tid = truth[:, 1].astype(int)
    c = raw.truth_landmarks[tid]
    np.testing.assert_allclose(truth[:, 4], np.hypot(*(c - poses[s, 1:3]).T), atol=1e-6)
    bearing = np.arctan2(c[:, 1] - poses[s, 2], c[:, 0] - poses[s, 1]) - poses[s, 3]
    np.testing.assert_allclose(np.angle(np.exp(1j * (truth[:, 5] - bearing))), 0.0, atol=1e-8)
    np.testing.assert_allclose(truth[:, 6], raw.truth_diameters[tid], atol=1e-6)
    agree = 0
    for row in range(truth.shape[0]):
        want = _circle_range(poses[s[row], 1:], scans.angles, c[row], raw.truth_diameters[tid[row]] / 2)
        want = np.where(want < 80.0, want, np.inf)
        assert truth[row, 3] == np.isfinite(want).sum()
        on_surface = np.isfinite(want) & (np.abs(scans.ranges[s[row]] - want) < 0.1)
        agree += truth[row, 2] == on_surface.sum()
    assert agree >= 0.995 * truth.shape[0]
    assert (truth[:, 2] >= 3).sum() > 50 and np.all(truth[:, 2] <= truth[:, 3])


def test_clutter_keeps_clear_of_trunks_and_path(short_log):
    world, raw = short_log.world, short_log.raw
    sim = SimConfig()
    assert np.sum(world.segment_kind == KIND_WALL) == sim.laser_walls
    assert np.sum(world.segment_kind == KIND_FENCE) == sim.laser_fences
    assert np.sum(world.segment_kind == KIND_BUSH) == sim.laser_bushes * BUSH_VERTICES
    seg = world.segments
    # distance from every trunk centre to every segment
    p, e = seg[None, :, :2], seg[None, :, 2:] - seg[None, :, :2]
    for pts, need in ((world.trees, world.tree_radius + sim.laser_clearance), (raw.truth_poses[::5, 1:3], 3.0)):
        q = pts[:, None, :]
        u = np.clip(np.sum((q - p) * e, axis=2) / np.sum(e * e, axis=2), 0.0, 1.0)
        d = np.linalg.norm(q - (p + u[..., None] * e), axis=2).min(axis=1)
        assert np.all(d >= np.broadcast_to(need, d.shape) - 1e-2)


@pytest.mark.slow
def test_dropout_spurious_and_noise_rates():
    sim = SimConfig(
        seed=9, duration=60.0, laser_dropout=0.05, laser_spurious=0.02, laser_range_noise=0.03, laser_fences=0
    )
    log = simulate_laser(sim)
    poses = log.raw.truth_poses[np.searchsorted(log.raw.truth_poses[:, 0], log.scans.time), 1:]
    true_r, _, _, _ = ray_cast(poses, log.scans.angles, log.world, sim.laser_max_range)
    r = log.scans.ranges
    surface = np.isfinite(true_r)
    n = r.size
    assert n > 80_000 and surface.mean() > 0.2
    err = r - np.where(surface, true_r, np.inf)
    genuine = surface & (np.abs(err) < 0.3)
    # dropouts: beams with a surface that return nothing (a spurious range may replace a dropout)
    dropout = np.mean(r[surface] == NO_RETURN) / (1 - sim.laser_spurious)
    assert dropout == pytest.approx(sim.laser_dropout, rel=0.1)
    # spurious: ranges that are neither the surface's nor no return, uniform below the surface (or max range)
    spur = (r != NO_RETURN) & ~genuine
    upper = np.where(surface, true_r, sim.laser_max_range)
    expected = sim.laser_spurious * np.mean((upper - 0.5 - 0.3) / (upper - 0.5))
    assert spur.mean() == pytest.approx(expected, rel=0.12)
    assert np.all(r[spur] <= upper[spur] + 1e-9) and np.all(r[spur] >= 0.5 - 1e-9)
    assert np.std(err[genuine]) == pytest.approx(sim.laser_range_noise, rel=0.03)
    # no return is written as the real log's 81.91 and reads as no return
    assert set(np.unique(r[r >= sim.laser_max_range])) == {NO_RETURN}


def test_laser_txt_reads_back(tmp_path, short_log):
    log = simulate_laser_to_dir(tmp_path, SimConfig(seed=4, duration=25.0))
    back = load_laser(tmp_path)
    np.testing.assert_allclose(back.time, log.scans.time, atol=1e-6)
    np.testing.assert_allclose(back.ranges, log.scans.ranges, atol=5e-4 + 1e-12)
    np.testing.assert_allclose(back.angles, log.scans.angles)
    np.testing.assert_array_equal(back.valid, log.scans.valid)
    np.testing.assert_array_equal(log.scans.ranges, short_log.scans.ranges)  # deterministic per seed
    lines = (tmp_path / "LASER.txt").read_text().splitlines()
    assert len(lines) == log.scans.n_scans and len(lines[0].split()) == 362
    truth = np.loadtxt(tmp_path / "laser_truth.csv", delimiter=",", skiprows=1)
    np.testing.assert_allclose(truth, log.truth, atol=1e-5)
    world = (tmp_path / "laser_world.csv").read_text().splitlines()
    assert world[0] == "kind,id,x0,y0,x1,y1" and len(world) == 1 + 250 + log.world.segments.shape[0]


def test_cli_simulate_laser(tmp_path, capsys):
    assert main(["simulate", "--laser", "--out", str(tmp_path), "--seed", "2", "--set", "sim.duration=8"]) == 0
    assert "LASER.txt:" in capsys.readouterr().out
    for name in ("LASER.txt", "laser_truth.csv", "laser_world.csv", "measurements.dat", "inputs.dat"):
        assert (tmp_path / name).is_file()
    assert load_laser(tmp_path).n_beams == 361


@pytest.mark.parametrize(
    "key, value",
    [
        ("sim.laser_dropout", "1.5"),
        ("sim.laser_beams", "1"),
        ("sim.laser_bush_roughness", "0.95"),
        ("sim.laser_walls", "-1"),
    ],
)
def test_bad_laser_keys_name_the_key(key, value):
    with pytest.raises(ConfigError, match=key.split(".")[1]):
        load_config(None, [f"{key}={value}"])


@pytest.mark.slow
def test_a_park_too_crowded_for_the_clutter_names_the_key():
    with pytest.raises(ValueError, match="sim.laser_walls"):
        simulate_laser(SimConfig(duration=5.0, laser_walls=2, laser_clearance=60.0))
