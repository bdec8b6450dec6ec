"""The indoor scenario (nanoslam_jax.sim.indoor) against closed forms computed here: ranges by an
independent ray-cast, the truth geometry against the world, the odometry against the motion model, the
front end's lines against the truth walls, the files the command writes and the config's errors."""

import dataclasses
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from nanoslam_jax.app.cli import main
from nanoslam_jax.app.config import ConfigError, DetectorConfig, IndoorConfig, load_config
from nanoslam_jax.data import LaserScans, load_laser, load_victoria_park
from nanoslam_jax.frontend import extract_features
from nanoslam_jax.models import Unicycle
from nanoslam_jax.sim.laser import KIND_WALL
from nanoslam_jax.sim.indoor import (
    BREAK_DOOR,
    TEMPLATES,
    TRUTH_FILES,
    _slip_mask,
    build_world,
    hessian_lines,
    simulate_indoor,
    slope_intercept_lines,
)

CLEAN = dict(range_noise=0.0, dropout=0.0, spurious=0.0)


@pytest.fixture(scope="module")
def clean_logs():
    """A short noise-free log of each template."""
    return {
        t: simulate_indoor(
            IndoorConfig(seed=i + 3, template=t, duration=12.0, sigma_v=0.0, sigma_omega_deg=0.0, **CLEAN)
        )
        for i, t in enumerate(TEMPLATES)
    }


def _cast(pose, angles, walls, pillars, max_range):
    """Closed-form ranges: each beam against every wall (ray-segment, Cramer's rule) and pillar (ray-circle)."""
    th = pose[2] + angles
    dx, dy = np.cos(th), np.sin(th)
    best = np.full(angles.shape, np.inf)
    for x0, y0, x1, y1 in walls:
        ex, ey = x1 - x0, y1 - y0
        det = -dx * ey + dy * ex  # solve t d - u e = a - o
        bx, by = x0 - pose[0], y0 - pose[1]
        with np.errstate(divide="ignore", invalid="ignore"):
            t = (-bx * ey + by * ex) / det
            u = (dx * by - dy * bx) / det
        ok = (det != 0) & (t > 0) & (u >= 0) & (u <= 1)
        best = np.where(ok & (t < best), t, best)
    for xc, yc, r in pillars:
        wx, wy = xc - pose[0], yc - pose[1]
        along = wx * dx + wy * dy
        perp2 = wx * wx + wy * wy - along * along
        t = along - np.sqrt(np.maximum(r * r - perp2, 0.0))
        ok = (perp2 < r * r) & (t > 0)
        best = np.where(ok & (t < best), t, best)
    return np.where(best < max_range, best, np.inf)


@pytest.mark.parametrize("template", TEMPLATES)
def test_ranges_equal_an_independent_ray_cast(clean_logs, template):
    log = clean_logs[template]
    w, scans = log.world, log.scans
    for k in range(0, scans.n_scans, 37):
        want = _cast(log.scan_pose[k], scans.angles, w.walls, w.pillars, scans.max_range)
        got = scans.ranges[k]
        hit = np.isfinite(want)
        np.testing.assert_array_equal(got < scans.max_range, hit)
        np.testing.assert_allclose(got[hit], want[hit], rtol=0, atol=1e-9)
    # the scan poses are the true laser poses at the scan times (scans on the odometry samples here)
    i = np.searchsorted(log.time, scans.time)
    np.testing.assert_allclose(log.scan_pose, log.sensor_pose[i], atol=1e-12)
    # every beam's truth label is the surface the independent cast hit
    assert set(np.unique(log.kind)) <= {-1, 0, 1}


def _on_segment(p, seg, tol=1e-9):
    a, b = seg[:2], seg[2:]
    d = b - a
    t = np.dot(p - a, d) / np.dot(d, d)
    return -tol <= t <= 1 + tol and np.linalg.norm(a + t * d - p) < tol


@pytest.mark.parametrize("template", TEMPLATES)
def test_truth_geometry_is_consistent(clean_logs, template):
    w = clean_logs[template].world
    cfg = IndoorConfig()
    assert w.template == template
    assert w.pillars.shape[0] >= 1 and w.corners.shape[0] >= 4
    assert w.breakpoints.shape[0] == 2 * (cfg.doors + cfg.partitions)
    ends = w.walls.reshape(-1, 2)
    # corners lie on both their walls, at an end of each, and the walls meet at the stated angle
    for p, (a, b), ang in zip(w.corners, w.corner_walls, w.corner_angle):
        assert w.wall_line[a] != w.wall_line[b]
        for s in (w.walls[a], w.walls[b]):
            assert min(np.linalg.norm(s[:2] - p), np.linalg.norm(s[2:] - p)) < 1e-9
        ua = (
            w.walls[a, :2] - w.walls[a, 2:]
            if np.linalg.norm(w.walls[a, 2:] - p) < 1e-9
            else w.walls[a, 2:] - w.walls[a, :2]
        )
        ub = (
            w.walls[b, 2:] - w.walls[b, :2]
            if np.linalg.norm(w.walls[b, :2] - p) < 1e-9
            else w.walls[b, :2] - w.walls[b, 2:]
        )
        between = math.degrees(math.acos(np.dot(ua, ub) / np.linalg.norm(ua) / np.linalg.norm(ub)))
        assert min(abs(ang - between), abs(ang - (360 - between))) < 1e-6
    # break points lie on their wall, at one of its ends; the two jambs of a door are door_width apart on one line
    for p, wid in zip(w.breakpoints, w.breakpoint_wall):
        assert _on_segment(p, w.walls[wid])
        assert min(np.linalg.norm(w.walls[wid, :2] - p), np.linalg.norm(w.walls[wid, 2:] - p)) < 1e-9
    gaps = np.hypot(*(w.breakpoints[0::2] - w.breakpoints[1::2]).T)
    door = w.breakpoint_kind[0::2] == BREAK_DOOR
    np.testing.assert_array_equal(w.breakpoint_kind[0::2], w.breakpoint_kind[1::2])
    assert door.sum() == cfg.doors
    np.testing.assert_allclose(gaps, np.where(door, cfg.door_width, cfg.partition_length), atol=1e-9)
    # a partition's two ends are the two ends of one wall, on no other wall
    for wid in w.breakpoint_wall[0::2][~door]:
        assert (w.wall_line == w.wall_line[wid]).sum() == 1 and not (w.corner_walls == wid).any()
    np.testing.assert_array_equal(w.wall_line[w.breakpoint_wall[0::2]], w.wall_line[w.breakpoint_wall[1::2]])
    # every wall end is a corner or a break point
    marks = np.concatenate([w.corners, w.breakpoints])
    assert (
        np.min(np.hypot(ends[:, None, 0] - marks[None, :, 0], ends[:, None, 1] - marks[None, :, 1]), axis=1).max()
        < 1e-9
    )
    # line parameters: both ends on the line in either form; pieces of one wall share it
    rho, alpha = hessian_lines(w.walls)
    for x, y in (w.walls[:, :2].T, w.walls[:, 2:].T):
        np.testing.assert_allclose(x * np.cos(alpha) + y * np.sin(alpha), rho, atol=1e-9)
    vertical, a, b, c = slope_intercept_lines(w.walls)
    assert (rho >= 0).all() and np.isfinite(np.where(vertical, c, a + b)).all()
    for x, y in (w.walls[:, :2].T, w.walls[:, 2:].T):
        np.testing.assert_allclose(np.where(vertical, x, a * x + b), np.where(vertical, c, y), atol=1e-9)
    for line in np.unique(w.wall_line):
        k = w.wall_line == line
        assert np.ptp(rho[k]) < 1e-9 and np.ptp(alpha[k]) < 1e-9
    # pillars clear of the walls and of the path
    for xc, yc, r in w.pillars:
        dw = [np.linalg.norm(np.array([xc, yc]) - _closest(np.array([xc, yc]), s)) for s in w.walls]
        assert min(dw) >= r + 0.3 - 1e-9
    assert (cfg.pillar_radius_min <= w.pillars[:, 2]).all() and (w.pillars[:, 2] <= cfg.pillar_radius_max).all()


def _closest(p, seg):
    a, d = seg[:2], seg[2:] - seg[:2]
    return a + np.clip(np.dot(p - a, d) / np.dot(d, d), 0, 1) * d


def test_templates_sizes_and_mirroring_vary_by_seed():
    seen, mirrored = set(), set()
    for seed in range(12):
        cfg = IndoorConfig(seed=seed)
        w, path = build_world(cfg, np.random.default_rng(np.random.SeedSequence(seed).spawn(5)[0]))
        seen.add(w.template)
        mirrored.add(path.turn < 0)
        # the laser starts at the origin heading +x: the reference point Ls ahead of it
        p, h, _ = path.at(np.zeros(1))
        np.testing.assert_allclose(p[0], [cfg.sensor_ls, 0.0], atol=1e-12)
        assert abs(h[0]) < 1e-12
    assert seen == set(TEMPLATES) and mirrored == {True, False}


def test_odometry_integrates_to_the_truth_path(clean_logs):
    log = clean_logs["corridor"]
    cfg = IndoorConfig()
    model = Unicycle(sensor_x=-cfg.sensor_ls, sensor_y=0.0)
    dr = log.raw.dr

    def step(x, row):
        x = model.step(x, row[1:], cfg.odom_period)
        return x, x

    _, xs = jax.lax.scan(step, jnp.asarray(log.sensor_pose[0]), jnp.asarray(dr[:-1]))
    xs = np.asarray(xs)
    np.testing.assert_allclose(xs[:, :2], log.sensor_pose[1:, :2], atol=1e-9)
    np.testing.assert_allclose(np.angle(np.exp(1j * (xs[:, 2] - log.sensor_pose[1:, 2]))), 0.0, atol=1e-9)
    np.testing.assert_allclose(log.sensor_pose[0], 0.0, atol=1e-12)
    # the reference point (Ls ahead of the laser) lies on the desired path, at low speed
    track, _, _ = log.path.at(np.linspace(0.0, log.path.total, 200001))
    moved = log.pose[:, :2]
    d = np.min(
        np.hypot(moved[::20, None, 0] - track[None, ::10, 0], moved[::20, None, 1] - track[None, ::10, 1]), axis=1
    )
    assert d.max() < log.path.total / 20000  # the sampling of the track, not the vehicle, sets this bound
    np.testing.assert_allclose(
        log.pose[:, :2] - log.sensor_pose[:, :2],
        cfg.sensor_ls * np.stack([np.cos(log.pose[:, 2]), np.sin(log.pose[:, 2])], 1),
        atol=1e-12,
    )
    v, omega = log.controls.T
    # the Euler step's second-order term makes v exceed the reference point's speed by up to 0.2 %
    assert (v[log.time < cfg.static_time] == 0).all() and v.max() <= 1.002 * cfg.speed_max and v.min() >= 0
    assert np.abs(omega).max() <= math.radians(cfg.max_turn_rate_deg) * 1.05
    assert v[log.time > cfg.static_time + 4].min() > 0.05


def test_slip_episodes_change_the_odometry_noise():
    cfg = IndoorConfig(seed=5, duration=40.0, slip_fraction=0.5, slip_duration=3.0, **CLEAN)
    log = simulate_indoor(cfg)
    moving = log.time > cfg.static_time + 0.1
    err = log.raw.dr[:, 1:] - log.controls
    still = np.abs(log.controls).max(axis=1) < 1e-9
    assert still[log.time < cfg.static_time - 0.03].all() and not still[log.time > cfg.static_time + 0.03].any()
    np.testing.assert_array_equal(err[still], 0.0)  # still wheels read zero
    for slip, f in ((False, 1.0), (True, cfg.slip_factor)):
        k = moving & (log.slip == slip)
        np.testing.assert_allclose(log.sigma[k, 0], cfg.sigma_v * f)
        np.testing.assert_allclose(log.sigma[k, 1], math.radians(cfg.sigma_omega_deg) * f)
        z = err[k] / log.sigma[k]
        assert k.sum() > 200 and abs(z.std() - 1.0) < 0.1
    # the slip process: its long-run fraction and mean episode length
    t = np.arange(0.0, 20000.0, 0.025)
    m = _slip_mask(t, cfg, np.random.default_rng(1))
    starts = np.flatnonzero(np.diff(m.astype(int)) == 1)
    assert abs(m.mean() - cfg.slip_fraction) < 0.03
    assert abs(m.sum() * 0.025 / starts.size - cfg.slip_duration) < 0.1 * cfg.slip_duration


def _sensor_line(rho, alpha, pose):
    """A world line (rho, alpha) in the frame of the laser at ``pose``."""
    r = rho - (pose[0] * np.cos(alpha) + pose[1] * np.sin(alpha))
    a = alpha - pose[2]
    a = np.where(r < 0, a + np.pi, a)
    return np.abs(r), np.angle(np.exp(1j * a))


@pytest.mark.parametrize("template", TEMPLATES)
def test_front_end_recovers_the_truth_walls(clean_logs, template):
    """Split-and-merge lines on noise-free scans against the truth walls in the laser frame: exact for a line
    whose returns all lie on one wall; within 1 cm and 0.5 deg for one that shares a corner's return with the
    wall beside it (the vertex split-and-merge gives both segments). Corners and arcs against the truth too."""
    log = clean_logs[template]
    scans, w = log.scans, log.world
    pick = np.arange(0, scans.n_scans, 30)
    feats = extract_features(
        LaserScans(scans.time[pick], scans.ranges[pick], scans.angles, scans.max_range), DetectorConfig()
    )
    rho, alpha = hessian_lines(w.walls)
    ln = feats.lines
    pure = shared = seen_total = seen_found = 0
    for j, k in enumerate(pick):
        lr, la = _sensor_line(rho, alpha, log.scan_pose[k])
        found = set()
        for q in np.flatnonzero(ln.scan == j):
            hit = log.object_id[k, ln.first_beam[q] : ln.last_beam[q] + 1]
            walls = np.unique(w.wall_line[hit[hit >= 0]])
            wall = np.bincount(hit[hit >= 0]).argmax()  # the wall most of its beams hit
            found.add(int(w.wall_line[wall]))
            d_rho, d_alpha = abs(ln.rho[q] - lr[wall]), abs(np.angle(np.exp(1j * (ln.alpha[q] - la[wall]))))
            if walls.size == 1:
                assert d_rho < 1e-6 and d_alpha < 1e-6
                pure += 1
            else:
                assert d_rho < 0.01 and d_alpha < math.radians(0.5)
                shared += 1
        # the walls seen by 40 or more beams are found
        ids = log.object_id[k][log.kind[k] == KIND_WALL]
        seen = np.flatnonzero(np.bincount(w.wall_line[ids], minlength=w.wall_line.max() + 1) >= 40)
        seen_total += seen.size
        seen_found += len(found & set(seen.tolist()))
    assert pure >= pick.size and seen_found >= 0.9 * seen_total
    # corner points within 3 cm of a truth corner (the vertex return lies within a beam step of it); arcs exact
    pose = log.scan_pose[pick]
    c, si = np.cos(pose[:, 2]), np.sin(pose[:, 2])

    def world(scan, x, y):
        return np.stack([pose[scan, 0] + c[scan] * x - si[scan] * y, pose[scan, 1] + si[scan] * x + c[scan] * y], 1)

    corners = world(feats.corners.scan, feats.corners.x, feats.corners.y)
    assert corners.shape[0] >= pick.size
    gap = np.hypot(corners[:, None, 0] - w.corners[None, :, 0], corners[:, None, 1] - w.corners[None, :, 1]).min(axis=1)
    assert gap.max() < 0.03
    centres = world(feats.circles.scan, feats.circles.cx, feats.circles.cy)
    d = np.hypot(centres[:, None, 0] - w.pillars[None, :, 0], centres[:, None, 1] - w.pillars[None, :, 1])
    np.testing.assert_allclose(d.min(axis=1), 0.0, atol=1e-6)
    np.testing.assert_allclose(feats.circles.radius, w.pillars[d.argmin(axis=1), 2], atol=1e-6)
    assert template != "room" or centres.shape[0] >= 3


def test_cli_writes_the_documented_files(tmp_path):
    out = tmp_path / "indoor"
    assert (
        main(
            [
                "simulate",
                "--scenario",
                "indoor",
                "--out",
                str(out),
                "--seed",
                "4",
                "--set",
                "indoor.duration=3",
                "--set",
                "indoor.template=corridor",
            ]
        )
        == 0
    )
    for name, cols in TRUTH_FILES.items():
        assert (out / name).read_text().splitlines()[0] == ",".join(cols)
    cfg = IndoorConfig(seed=4, duration=3.0, template="corridor")
    log = simulate_indoor(cfg)
    walls = np.genfromtxt(out / "truth_walls.csv", delimiter=",", names=True)
    np.testing.assert_allclose(
        np.stack([walls["x0"], walls["y0"], walls["x1"], walls["y1"]], 1), log.world.walls, atol=1e-8
    )
    corners = np.genfromtxt(out / "truth_corners.csv", delimiter=",", names=True)
    np.testing.assert_allclose(np.stack([corners["x"], corners["y"]], 1), log.world.corners, atol=1e-8)
    arcs = np.genfromtxt(out / "truth_arcs.csv", delimiter=",", names=True, ndmin=1)
    np.testing.assert_allclose(np.stack([arcs["xc"], arcs["yc"], arcs["radius"]], 1), log.world.pillars, atol=1e-8)
    path = np.loadtxt(out / "truth_path.csv", delimiter=",", skiprows=1)
    np.testing.assert_allclose(path[:, 1:4], log.pose, atol=1e-8)
    raw = load_victoria_park(out, detections=False)  # the pillar is not seen in 3 s: measurements.dat is empty
    assert (out / "measurements.dat").read_text() == ""
    np.testing.assert_allclose(raw.dr, log.raw.dr, atol=1e-8)
    np.testing.assert_allclose(raw.truth_poses, log.raw.truth_poses, atol=1e-8)
    np.testing.assert_allclose(raw.gps[:, 1:], log.sensor_pose[:, :2], atol=1e-8)
    scans = load_laser(out)
    np.testing.assert_allclose(scans.time, log.scans.time, atol=1e-6)
    valid = log.scans.valid
    np.testing.assert_array_equal(scans.valid, valid)
    np.testing.assert_allclose(scans.ranges[valid], log.scans.ranges[valid], atol=5e-4 + 1e-9)
    assert "indoor" in (out / "scenario.yaml").read_text()
    beams = np.load(out / "beam_truth.npz")
    np.testing.assert_array_equal(beams["kind"], log.kind)
    np.testing.assert_array_equal(beams["object_id"], log.object_id)
    for name in ("inputs.dat", "gps.dat", "truth_poses.dat", "truth_landmarks.dat", "truth_diameters.dat", "LASER.txt"):
        assert (out / name).is_file()


def test_detect_runs_on_an_indoor_log(tmp_path, capsys):
    out = tmp_path / "indoor"
    assert main(["simulate", "--scenario", "indoor", "--out", str(out), "--set", "indoor.duration=5"]) == 0
    assert main(["detect", "--data", str(out), "--out", str(tmp_path / "det"), "--quiet"]) == 0
    text = (tmp_path / "det" / "features.csv").read_text()
    assert "line" in text and "corner" in text


@pytest.mark.parametrize(
    "override, key",
    [
        ("indoor.bogus=1", "indoor.bogus"),
        ("indoor.speed_max=-0.3", "indoor.speed_max"),
        ("indoor.template=cave", "indoor.template"),
        ("indoor.slip_fraction=1.5", "indoor.slip_fraction"),
        ("indoor.laser_beams=2.5", "indoor.laser_beams"),
        ("indoor.speed_min=0.6", "indoor.speed_min"),
        ("indoor.pillar_radius_min=0.5", "indoor.pillar_radius_min"),
    ],
)
def test_bad_keys_name_the_key(override, key):
    with pytest.raises(ConfigError, match=key.replace(".", r"\.")):
        load_config(None, [override])


def test_world_that_cannot_hold_the_doors_names_the_key(tmp_path, capsys):
    assert (
        main(
            [
                "simulate",
                "--scenario",
                "indoor",
                "--out",
                str(tmp_path),
                "--set",
                "indoor.doors=40",
                "--set",
                "indoor.duration=1",
            ]
        )
        == 2
    )
    assert "indoor.doors" in capsys.readouterr().err


def test_deterministic_by_seed():
    cfg = IndoorConfig(seed=9, duration=2.0)
    a, b = simulate_indoor(cfg), simulate_indoor(cfg)
    np.testing.assert_array_equal(a.scans.ranges, b.scans.ranges)
    np.testing.assert_array_equal(a.raw.dr, b.raw.dr)
    c = simulate_indoor(dataclasses.replace(cfg, seed=10))
    assert c.world.walls.shape != a.world.walls.shape or not np.allclose(c.world.walls, a.world.walls)
