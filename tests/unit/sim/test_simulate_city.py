"""Tests of the city simulator (nanoslam_jax.sim.city).

Independent truths: the configured world (counts and spacings recomputed here from the settings),
the street geometry (centrelines at multiples of the pitch), brute-force range and bearing of
every landmark from every true pose (the simulator only looks at landmarks in nearby grid cells),
and the revisits counted here from the true path.
"""

import contextlib
import dataclasses
import io
import json
import math

import numpy as np
import pytest
from scipy.spatial import cKDTree

from nanoslam_jax.app.cli import main
from nanoslam_jax.app.config import CityConfig, ConfigError, SimConfig, load_config
from nanoslam_jax.app.experiment import load_log
from nanoslam_jax.sim.city import LAMP_POST, STREET_TREE, city_landmark_count, simulate_city

#: A small city: 5 x 5 blocks, 3 km, back to an old street every 800 m.
SMALL = CityConfig(blocks=5, distance_m=3000.0, revisit_every_m=800.0)
EXACT = SimConfig(sigma_r=0.0, sigma_beta_deg=0.0, p_detect=1.0, clutter_rate=0.0)


@pytest.fixture(scope="module")
def small():
    return simulate_city(SMALL, SimConfig())


def wrap(a):
    return (np.asarray(a) + np.pi) % (2 * np.pi) - np.pi


def expected_count(c: CityConfig) -> float:
    """Landmarks the settings ask for: street trees per kerb, interior trees per hectare, 4 lamps per block."""
    kerb = 4 * math.floor(c.block_size / c.tree_spacing)
    interior = c.interior_density * (c.block_size - 10.0) ** 2 / 1e4
    return c.blocks**2 * (kerb + interior + 4 * c.lamp_posts)


def test_default_city_has_about_ten_thousand_landmarks_at_the_configured_density():
    c = dataclasses.replace(CityConfig(), distance_m=200.0)
    w = simulate_city(c).world
    n = w.landmarks.shape[0]
    assert abs(n - expected_count(c)) <= 0.05 * expected_count(c)
    assert 9000 <= n <= 11000 and n == city_landmark_count(c)
    # interior trees: density per hectare of the blocks' interiors
    g = (w.landmarks - w.origin) / w.pitch
    into = np.abs(g - np.round(g)) * w.pitch - 0.5 * c.street_width  # distance into the block from each kerb
    inner = np.all(into >= 5.0 - 1e-9, axis=1)
    area_ha = c.blocks**2 * (c.block_size - 10.0) ** 2 / 1e4
    assert inner.sum() / area_ha == pytest.approx(c.interior_density, rel=0.05)


@pytest.mark.parametrize("spacing", [10.0, 15.0])
def test_street_trees_stand_on_the_kerbs_at_the_configured_spacing(spacing):
    c = CityConfig(blocks=4, distance_m=200.0, tree_spacing=spacing, tree_jitter=1.0)
    w = simulate_city(c).world
    rel = w.landmarks - w.origin
    g = rel / w.pitch
    into = np.abs(g - np.round(g)) * w.pitch - 0.5 * c.street_width
    assert np.all(into.min(axis=1) >= -1e-9)  # nothing stands in a street
    kerb = into.min(axis=1) <= 0.5 + 1e-9
    assert np.array_equal(kerb, w.kind == STREET_TREE)
    n_side = math.floor(c.block_size / spacing)
    assert kerb.sum() == c.blocks**2 * 4 * n_side
    # along each kerb of each block, consecutive trees are spacing apart, up to twice the jitter
    gaps = []
    for along in (0, 1):  # kerbs running along x (near in y), then along y
        on = kerb & (into[:, 1 - along] <= 0.5 + 1e-9)
        pos = rel[on]
        line = np.floor(pos[:, 1 - along] / (0.5 * w.pitch))  # which kerb line: two per street
        block = np.floor(pos[:, along] / w.pitch)
        for key in set(zip(line.tolist(), block.tolist())):
            sel = (line == key[0]) & (block == key[1])
            assert sel.sum() == n_side
            gaps.extend(np.diff(np.sort(pos[sel, along])).tolist())
    gaps = np.asarray(gaps)
    assert gaps.size > 0
    assert np.all(np.abs(gaps - c.block_size / n_side) <= 2 * c.tree_jitter + 0.6)
    assert gaps.mean() == pytest.approx(c.block_size / n_side, rel=0.05)
    lamps = w.landmarks[w.kind == LAMP_POST]
    assert lamps.shape[0] == 4 * c.blocks**2


def test_route_stays_on_the_streets(small):
    w, raw = small.world, small.raw
    rel = raw.truth_poses[:, 1:3] - w.origin
    g = rel / w.pitch
    off = np.abs(g - np.round(g)) * w.pitch
    assert np.all(off.min(axis=1) <= 0.5 * SMALL.street_width)
    extent = (w.n_streets - 1) * w.pitch
    assert np.all(rel >= -0.5 * SMALL.street_width) and np.all(rel <= extent + 0.5 * SMALL.street_width)
    # the drive is as long as asked
    xy = raw.truth_poses[:, 1:3]
    assert np.hypot(*np.diff(xy, axis=0).T).sum() == pytest.approx(SMALL.distance_m, rel=0.02)
    # the laser starts at the origin of the SLAM frame, heading +x
    assert np.allclose(raw.truth_poses[0, 1:], 0.0)


def revisits(raw, radius=10.0, absence=300.0):
    """Times the true path comes within ``radius`` of a place it was at more than ``absence`` s before,
    having been nowhere near it for ``absence`` s (1 s samples; one per 30 s of driving)."""
    t = raw.truth_poses[:, 0]
    sel = np.searchsorted(t, np.arange(0.0, t[-1], 1.0))
    p, tt = raw.truth_poses[sel, 1:3], t[sel]
    events, last = [], -1e9
    for k, nb in enumerate(cKDTree(p).query_ball_point(p, radius)):
        gaps = tt[k] - tt[np.asarray(nb, dtype=int)]
        if np.any(gaps > absence) and not np.any((gaps > 5.0) & (gaps <= absence)):
            if tt[k] - last > 30.0:
                events.append(tt[k])
            last = tt[k]
    return events


def test_loops_revisit_old_streets(small):
    events = revisits(small.raw)
    assert len(events) >= 3 and min(events) > 300.0


def test_detections_match_the_truth_within_the_noise(small):
    raw, sim = small.raw, SimConfig()
    det, ids = raw.detections, raw.detection_ids
    idx = np.searchsorted(raw.truth_poses[:, 0], det[:, 0])
    assert np.all(raw.truth_poses[idx, 0] == det[:, 0])
    pose = raw.truth_poses[idx, 1:]
    real = ids >= 0
    lm = raw.truth_landmarks[ids[real]]
    d = lm - pose[real, :2]
    r_true = np.hypot(d[:, 0], d[:, 1])
    b_true = wrap(np.arctan2(d[:, 1], d[:, 0]) - pose[real, 2])
    dr, db = det[real, 1] - r_true, wrap(det[real, 2] - b_true)
    assert np.all(np.abs(dr) <= 6 * sim.sigma_r) and np.all(np.abs(db) <= 6 * math.radians(sim.sigma_beta_deg))
    assert np.std(dr) == pytest.approx(sim.sigma_r, rel=0.05)
    assert np.std(db) == pytest.approx(math.radians(sim.sigma_beta_deg), rel=0.05)
    assert np.all((det[:, 1] > 0) & (det[:, 1] < sim.max_range)) and np.all(np.abs(det[:, 2]) <= 0.5 * math.pi)
    # clutter at the configured rate
    n_scans = raw.truth_poses.shape[0] - raw.dr.shape[0]
    assert (~real).sum() / n_scans == pytest.approx(sim.clutter_rate, rel=0.1)
    # every detection is of a landmark within range, and the nearest landmark to where it points
    meas = pose[real, :2] + det[real, 1:2] * np.stack(
        [np.cos(pose[real, 2] + det[real, 2]), np.sin(pose[real, 2] + det[real, 2])], axis=1
    )
    _, nearest = cKDTree(raw.truth_landmarks).query(meas)
    assert np.mean(nearest == ids[real]) > 0.97


def test_noise_free_detections_are_every_landmark_in_view():
    """With no noise, misses or clutter, each scan reports exactly the landmarks in view (brute force)."""
    log = simulate_city(dataclasses.replace(SMALL, distance_m=800.0), EXACT)
    raw = log.raw
    scan_t = np.setdiff1d(raw.truth_poses[:, 0], raw.dr[:, 0])
    poses = raw.truth_poses[np.searchsorted(raw.truth_poses[:, 0], scan_t), 1:]
    d = raw.truth_landmarks[None, :, :] - poses[:, None, :2]
    r = np.hypot(d[..., 0], d[..., 1])
    b = wrap(np.arctan2(d[..., 1], d[..., 0]) - poses[:, None, 2])
    si, li = np.nonzero((r > 0) & (r < EXACT.max_range) & (np.abs(b) <= 0.5 * math.radians(EXACT.fov_deg)))
    want = set(zip(scan_t[si].tolist(), li.tolist()))
    got = set(zip(raw.detections[:, 0].tolist(), raw.detection_ids.tolist()))
    assert len(want) > 1000 and got == want


def test_same_seed_same_log_and_seeds_differ():
    c = dataclasses.replace(SMALL, distance_m=400.0)
    a, b = simulate_city(c), simulate_city(c)
    assert np.array_equal(a.raw.detections, b.raw.detections) and np.array_equal(a.raw.dr, b.raw.dr)
    other = simulate_city(dataclasses.replace(c, seed=1))
    assert not np.array_equal(other.world.landmarks, a.world.landmarks)


def test_data_kind_city_simulates_in_memory():
    cfg = load_config(None, ["data.kind=city", "city.blocks=3", "city.distance_m=300"])
    log = load_log(cfg)
    assert log.frame == "slam" and "city" in log.source
    assert log.raw.truth_landmarks.shape[0] == city_landmark_count(cfg.city)
    with pytest.raises(ConfigError, match="city.turn_radius"):
        load_config(None, ["data.kind=city", "city.turn_radius=30", "city.block_size=30", "city.street_width=6"])


def _simulate_city_cli(out, *sets):
    buf = io.StringIO()
    argv = ["simulate", "--scenario", "city", "--out", str(out), "--seed", "2"]
    argv += [a for s in ("city.distance_m=1500", "city.blocks=5", *sets) for a in ("--set", s)]
    with contextlib.redirect_stdout(buf):
        assert main(argv) == 0
    return buf.getvalue()


def test_cli_writes_a_directory_that_run_reads(tmp_path):
    out = tmp_path / "city"
    stdout = _simulate_city_cli(out)
    assert "1750 landmarks" in stdout
    for name in ("inputs.dat", "measurements.dat", "gps.dat", "truth_poses.dat", "truth_landmarks.dat"):
        assert (out / name).is_file()
    cfg = load_config(None, ["data.kind=victoria_park", "data.format=auto"])
    log = load_log(cfg, str(out))
    mem = simulate_city(CityConfig(seed=2, blocks=5, distance_m=1500.0)).raw
    assert log.frame == "slam"
    assert np.allclose(log.raw.truth_landmarks, mem.truth_landmarks, atol=1e-8)
    assert np.allclose(log.raw.detections[:, :3], mem.detections[:, :3], atol=1e-8)


@pytest.mark.slow
def test_nanoslam_run_on_the_city_directory(tmp_path):
    out = tmp_path / "city"
    _simulate_city_cli(out)
    res = tmp_path / "res"
    argv = ["run", "--quiet", "--data", str(out), "--out", str(res)]
    argv += [a for s in ("data.t_end=15", "filter.n_particles=5", "output.plots=false") for a in ("--set", s)]
    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        assert main(argv) == 0
    m = json.loads((res / "metrics.json").read_text())
    assert math.isfinite(m["rmse_fixed"]) and m["n_landmarks"] > 0
