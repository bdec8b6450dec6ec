"""Tests of the raw laser front end against independent truths: closed-form circles and polylines,
the breakpoint rule's threshold, and scans ray-cast here from known scenes."""

from pathlib import Path

import numpy as np
import pytest

from nanoslam_jax.app.config import ConfigError, DetectorConfig, load_config
from nanoslam_jax.data import LaserScans, fan_angles, load_laser, load_victoria_park
from nanoslam_jax.frontend import (
    breakpoint_threshold,
    detect_log,
    detect_trees,
    extract_features,
    fit_circle,
    polyline_vertices,
    width_radius,
)
from tests.helpers.paths import SHARED_DATA

BEAMS = 361
ANGLES = fan_angles(BEAMS)  # vehicle frame, -90..90 deg in 0.5 deg steps
NO_RETURN = 81.91


# --------------------------------------------------------------------------- a ray caster (the test's own)


def ray_cast(origin, heading, trees=(), walls=(), max_range=80.0, angles=ANGLES):
    """Ranges of the beams from ``origin`` (world frame) at ``heading`` to circles ``(x, y, d)`` and
    segments ``((x0, y0), (x1, y1))``; ``NO_RETURN`` where nothing is hit within ``max_range``."""
    ox, oy = origin
    ux, uy = np.cos(heading + angles), np.sin(heading + angles)
    r = np.full(angles.shape, np.inf)
    for cx, cy, d in trees:
        px, py = cx - ox, cy - oy
        along = ux * px + uy * py
        disc = (d / 2) ** 2 - (px * px + py * py - along**2)
        t = along - np.sqrt(np.maximum(disc, 0.0))
        r = np.where((disc >= 0) & (t > 0), np.minimum(r, t), r)
    for (x0, y0), (x1, y1) in walls:
        ex, ey = x1 - x0, y1 - y0
        den = ux * (-ey) - uy * (-ex)  # solve o + t u = p + s e
        wx, wy = x0 - ox, y0 - oy
        with np.errstate(divide="ignore", invalid="ignore"):
            t = (wx * (-ey) - wy * (-ex)) / den
            s = (ux * wy - uy * wx) / den
        hit = (np.abs(den) > 1e-12) & (t > 0) & (s >= 0) & (s <= 1)
        r = np.where(hit, np.minimum(r, t), r)
    return np.where(r < max_range, r, NO_RETURN)


def scans_of(rows, times=None):
    rows = np.atleast_2d(rows)
    t = np.arange(rows.shape[0]) * 0.2 if times is None else np.asarray(times)
    return LaserScans(t, rows, ANGLES)


# --------------------------------------------------------------------------- circle fit


@pytest.mark.parametrize("arc_deg, noise", [(180.0, 0.005), (90.0, 0.002), (360.0, 0.01)])
def test_circle_fit_recovers_a_circle_from_noisy_arc_points(arc_deg, noise):
    rng = np.random.default_rng(1)
    cx, cy, radius = 7.3, -2.1, 0.42
    th = np.deg2rad(np.linspace(-arc_deg / 2, arc_deg / 2, 40)) + np.pi
    x = cx + radius * np.cos(th) + rng.normal(0, noise, th.size)
    y = cy + radius * np.sin(th) + rng.normal(0, noise, th.size)
    fit = fit_circle(x, y)
    tol = 6 * noise * (180.0 / arc_deg)
    assert abs(fit.cx - cx) < tol and abs(fit.cy - cy) < tol and abs(fit.radius - radius) < tol
    assert fit.rms == pytest.approx(noise, rel=0.4)
    # noise-free: exact
    exact = fit_circle(cx + radius * np.cos(th), cy + radius * np.sin(th))
    np.testing.assert_allclose([exact.cx, exact.cy, exact.radius], [cx, cy, radius], atol=1e-9)


def test_circle_fit_of_a_straight_line_has_a_huge_radius():
    x = np.linspace(0, 2, 20)
    fit = fit_circle(x, 3.0 + 0.0 * x + np.random.default_rng(0).normal(0, 1e-3, 20))
    assert not np.isfinite(fit.radius) or fit.radius > 50


# --------------------------------------------------------------------------- split-and-merge


def test_split_and_merge_returns_the_vertices_of_a_polyline():
    corners = np.array([[0.0, 0.0], [3.0, 0.0], [3.0, 2.0], [5.0, 3.5], [8.0, 3.5]])
    xs, ys, vertex_index = [], [], [0]
    for a, b in zip(corners[:-1], corners[1:]):
        n = int(np.hypot(*(b - a)) / 0.05)
        s = np.linspace(0, 1, n, endpoint=False)
        xs.append(a[0] + s * (b - a)[0])
        ys.append(a[1] + s * (b - a)[1])
        vertex_index.append(vertex_index[-1] + n)
    x = np.concatenate(xs + [corners[-1:, 0]])
    y = np.concatenate(ys + [corners[-1:, 1]])
    rng = np.random.default_rng(3)
    v = polyline_vertices(x + rng.normal(0, 0.005, x.size), y + rng.normal(0, 0.005, y.size), 0.08, 0.03)
    np.testing.assert_array_equal(v, vertex_index)
    # a straight run with noise below the thresholds stays one segment
    x = np.linspace(0, 5, 100)
    np.testing.assert_array_equal(polyline_vertices(x, 0.01 * np.sin(7 * x), 0.08, 0.03), [0, 99])


def test_collinear_segments_merge_and_a_bend_below_d_max_does_not_split():
    # two pieces meeting at an angle whose apex lies 5 cm off the chord: one segment at d_max 8 cm
    x = np.linspace(0, 4, 81)
    y = 0.05 * (1 - np.abs(x - 2) / 2)
    np.testing.assert_array_equal(polyline_vertices(x, y, 0.08, 0.03), [0, 80])
    # at d_max 3 cm the apex splits it
    assert len(polyline_vertices(x, y, 0.03, 0.03)) == 3


# --------------------------------------------------------------------------- adaptive breakpoints


@pytest.mark.parametrize("r0", [5.0, 20.0])
def test_breakpoint_rule_splits_at_the_configured_jump_and_not_below(r0):
    cfg = DetectorConfig()
    dphi = np.deg2rad(0.5)
    # returns along one beam direction pair: beam k at r0, beam k+1 at r1; the gap is |p1 - p0|
    thr = float(breakpoint_threshold(np.array(r0), np.array(r0), np.array(dphi), cfg))
    lam = np.deg2rad(cfg.breakpoint_lambda_deg)
    assert thr == pytest.approx(r0 * np.sin(dphi) / np.sin(lam - dphi) + 3 * cfg.breakpoint_sigma_r)

    def clusters_with_gap(gap):
        # a flat arc at range r0 on beams 100..179, then beams 180..260 at the range giving that gap
        r = np.full(BEAMS, NO_RETURN)
        r[100:180] = r0
        # |p(r0, a) - p(r1, a + dphi)| = gap  ->  r1 from the law of cosines (r1 > r0)
        c = np.cos(dphi)
        r1 = r0 * c + np.sqrt(gap**2 - r0**2 * (1 - c * c))
        r[180:261] = r1
        f = extract_features(scans_of(r), cfg)
        return f.clusters.scan.size

    assert clusters_with_gap(1.05 * thr) == 2
    assert clusters_with_gap(0.95 * thr) == 1


def test_dropouts_up_to_the_configured_count_do_not_split():
    r = np.full(BEAMS, NO_RETURN)
    r[100:200] = 10.0
    r[150] = NO_RETURN
    cfg = DetectorConfig(max_dropout_beams=1)
    assert extract_features(scans_of(r), cfg).clusters.scan.size == 1
    r[151] = NO_RETURN
    assert extract_features(scans_of(r), cfg).clusters.scan.size == 2


# --------------------------------------------------------------------------- trees in a ray-cast scene

TREES = [(8.0, 3.0, 0.40), (15.0, -6.0, 0.60), (24.0, 5.0, 0.30), (5.0, -3.5, 0.25)]
WALL = ((12.0, 14.0), (26.0, 16.0))
FENCE = ((4.0, -14.0), (20.0, -16.0))


def _scene_scan(noise=0.0, seed=0, trees=TREES, walls=(WALL, FENCE)):
    r = ray_cast((0.0, 0.0), 0.0, trees, walls)
    if noise:
        hit = r < 80
        r = np.where(hit, r + np.random.default_rng(seed).normal(0, noise, r.shape), r)
    return r


@pytest.mark.parametrize("noise", [0.0, 0.01])
def test_trees_of_a_ray_cast_scene_have_the_right_centre_range_and_diameter(noise):
    trees = detect_trees(scans_of([_scene_scan(noise, seed=k) for k in range(5)]), DetectorConfig())
    truth = np.array([[np.hypot(x, y), np.arctan2(y, x), d] for x, y, d in TREES])
    for scan in range(5):
        got = trees[trees[:, 0] == scan * 0.2]
        assert got.shape[0] == len(TREES), got  # every tree, and nothing on the wall or the fence
        for rng_, brg, d in truth:
            k = np.argmin(np.abs(got[:, 2] - brg))
            # the angular width is quantised to a beam (0.5 deg): radius and range within half a beam's
            # width at the tree's range, the diameter within one
            beam = np.deg2rad(0.5) * rng_
            assert got[k, 1] == pytest.approx(rng_, abs=0.5 * beam + 0.02)
            assert abs(got[k, 2] - brg) < np.deg2rad(0.3)
            assert abs(got[k, 3] - d) < beam + 0.03


def test_no_tree_on_walls_fences_or_a_half_hidden_trunk():
    # a trunk partly hidden behind a nearer one is not a tree; the nearer one is
    near, far = (6.0, 0.0, 0.5), (12.0, 0.35, 0.5)
    r = ray_cast((0.0, 0.0), 0.0, [near, far], [WALL, FENCE])
    trees = detect_trees(scans_of(r), DetectorConfig(tree_min_clearance=0.0, tree_min_separation=0.0))
    assert trees.shape[0] == 1
    assert trees[0, 1] == pytest.approx(6.0, abs=0.02) and trees[0, 3] == pytest.approx(0.5, abs=0.02)
    # the walls alone: no tree, but line segments along them with break points at their ends
    r = ray_cast((0.0, 0.0), 0.0, [], [WALL, FENCE])
    f = extract_features(scans_of(r), DetectorConfig())
    assert f.trees.scan.size == 0
    assert f.lines.scan.size == 2
    for (x0, y0), (x1, y1) in (WALL, FENCE):
        k = np.argmin(np.abs(f.lines.y0 + f.lines.y1 - y0 - y1))
        ends = sorted([(f.lines.x0[k], f.lines.y0[k]), (f.lines.x1[k], f.lines.y1[k])])
        # the ends lie within one beam step along the wall of the true ones (0.5 deg at 30.5 m, on a wall
        # meeting the beam at 23 deg: 0.68 m)
        np.testing.assert_allclose(ends, sorted([(x0, y0), (x1, y1)]), atol=0.7)
        normal = np.array([-(y1 - y0), x1 - x0]) / np.hypot(x1 - x0, y1 - y0)
        rho = abs(normal @ [x0, y0])
        assert f.lines.rho[k] == pytest.approx(rho, abs=1e-6)
        assert f.lines.rms[k] < 1e-6
    assert f.breakpoints.scan.size == 4


def test_a_corner_of_two_walls_is_found_where_they_meet():
    walls = [((10.0, -5.0), (10.0, 4.0)), ((10.0, 4.0), (4.0, 10.0))]
    f = extract_features(scans_of(ray_cast((0.0, 0.0), 0.0, [], walls)), DetectorConfig())
    assert f.corners.scan.size == 1
    assert f.corners.x[0] == pytest.approx(10.0, abs=0.05) and f.corners.y[0] == pytest.approx(4.0, abs=0.05)
    assert f.corners.angle[0] == pytest.approx(np.pi / 4, abs=0.02)
    assert f.trees.scan.size == 0


def test_trees_at_the_edge_of_the_field_of_view_are_partly_seen():
    trees = [(0.3, 6.0, 0.4), (10.0, 0.0, 0.4)]  # the first straddles the +90 deg edge
    got = detect_trees(scans_of(ray_cast((0.0, 0.0), 0.0, trees)), DetectorConfig())
    assert got.shape[0] == 1 and got[0, 2] == pytest.approx(0.0, abs=1e-3)


def test_a_single_stray_return_is_no_tree_when_two_returns_are_required():
    thin = (12.0 * np.cos(0.1), 12.0 * np.sin(0.1), 0.15)  # hit by two beams
    r = ray_cast((0.0, 0.0), 0.0, [thin])
    assert (r < 80).sum() == 2
    stray = int(np.argmin(np.abs(ANGLES + 0.5)))  # a lone return in open space, 12 m at -29 deg
    r[stray] = 12.0
    got = detect_trees(scans_of(r), DetectorConfig(tree_min_returns=2))
    assert got.shape[0] == 1 and got[0, 2] == pytest.approx(0.1, abs=np.deg2rad(0.25))
    # by default (as the Victoria Park log's detector) a lone return is a thin trunk
    assert detect_trees(scans_of(r), DetectorConfig()).shape[0] == 2


def test_trunk_diameter_is_measured_below_the_beam_spacing():
    # one trunk per scan at 41 positions of its edges between beams (4 or 5 beams hit it)
    rng_, d = 10.0, 0.4
    b = np.deg2rad(np.linspace(-30.0, 30.0, 41) + 0.5 * np.linspace(0.0, 1.0, 41))
    rows = [ray_cast((0.0, 0.0), 0.0, [(rng_ * np.cos(x), rng_ * np.sin(x), d)]) for x in b]
    got = detect_trees(scans_of(rows), DetectorConfig(tree_range_noise=0.002))
    assert got.shape[0] == b.size
    # the angular width alone is off by up to half a beam's width (8.7 cm at 10 m) at each edge
    n = np.array([(r < 80).sum() for r in rows])
    width = 2 * width_radius(np.array([r.min() for r in rows]), n, np.deg2rad(0.5))
    assert np.abs(width - d).max() > 0.04
    assert np.abs(got[:, 3] - d).max() < 0.02
    assert np.abs(got[:, 1] - rng_).max() < 0.02
    assert np.abs(got[:, 2] - b).max() < np.deg2rad(0.05)


def test_ranges_no_trunk_as_wide_explains_are_no_tree():
    # a concave piece 1 m wide at 15 m (a bush's notch: its middle 0.8 m farther than its ends),
    # seen by 7 beams, too few for the circle fit's tests; a trunk as wide beside it is a tree
    notch = [((15.0, -0.5), (15.8, 0.0)), ((15.8, 0.0), (15.0, 0.5))]
    trunk = (15.0 * np.cos(0.6), 15.0 * np.sin(0.6), 1.0)
    r = ray_cast((0.0, 0.0), 0.0, [trunk], notch)
    got = detect_trees(scans_of(r), DetectorConfig())
    assert got.shape[0] == 1 and got[0, 2] == pytest.approx(0.6, abs=np.deg2rad(0.1))
    assert got[0, 3] == pytest.approx(1.0, abs=0.05)
    assert detect_trees(scans_of(r), DetectorConfig(tree_max_profile_residual=10.0)).shape[0] == 2


@pytest.mark.parametrize(
    "key, value", [("tree_min_returns", "0"), ("tree_range_noise", "0"), ("tree_max_profile_residual", "-0.1")]
)
def test_tree_keys_are_validated(key, value):
    with pytest.raises(ConfigError, match=f"detector.{key}"):
        load_config(None, [f"detector.{key}={value}"])


# --------------------------------------------------------------------------- detect and data.detections: laser


def _write_short_log(directory: Path, n_scans=40):
    """A car driving straight at 2 m/s past trees: LASER.txt ray-cast from the laser's poses, inputs.dat
    (speed, zero steering at 40 Hz), gps.dat."""
    directory.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(5)
    trees = [
        (x, y, d)
        for x, y, d in zip(
            np.arange(3.0, 60.0, 4.0), np.tile([6.0, -7.0, 11.0, -9.0], 4)[:15], rng.uniform(0.2, 0.6, 15)
        )
    ]
    t_scan = 1.0 + 0.2 * np.arange(n_scans)
    rows = []
    for t in t_scan:
        x = 2.0 * t + 3.78  # the laser 3.78 m ahead of the rear axle
        r = np.round(ray_cast((x, 0.5), 0.0, trees, [((0.0, 20.0), (80.0, 20.0))]), 2)
        rows.append("\t".join([f"{t:.3f}"] + [f"{v:.2f}" for v in r]))
    (directory / "LASER.txt").write_text("\t".join(rows))
    t_dr = np.arange(0.0, t_scan[-1] + 0.5, 0.025)
    np.savetxt(directory / "inputs.dat", np.stack([t_dr, np.full_like(t_dr, 2.0), np.zeros_like(t_dr)], 1), fmt="%.6f")
    t_g = np.arange(0.0, t_scan[-1] + 0.5, 0.2)
    np.savetxt(directory / "gps.dat", np.stack([t_g, 2.0 * t_g, 0.0 * t_g], 1), fmt="%.6f")
    return trees


def test_detect_writes_a_complete_log(tmp_path, capsys):
    from nanoslam_jax.app.cli import main

    _write_short_log(tmp_path / "log")
    assert (
        main(["detect", "--data", str(tmp_path / "log"), "--out", str(tmp_path / "det"), "--plot", "0,3-4", "--quiet"])
        == 0
    )
    out = tmp_path / "det"
    for name in (
        "measurements.dat",
        "inputs.dat",
        "gps.dat",
        "features.csv",
        "scans/scan_00000.png",
        "scans/scan_00004.png",
    ):
        assert (out / name).is_file(), name
    assert (out / "inputs.dat").read_bytes() == (tmp_path / "log" / "inputs.dat").read_bytes()
    m = np.loadtxt(out / "measurements.dat")
    assert m.shape[1] == 4 and np.all((m[:, 2] >= 0) & (m[:, 2] <= np.pi))
    expected = detect_trees(load_laser(tmp_path / "log"), DetectorConfig())
    np.testing.assert_allclose(m[:, [0, 1, 3]], expected[:, [0, 1, 3]], atol=1e-8)
    np.testing.assert_allclose(m[:, 2] - np.pi / 2, expected[:, 2], atol=1e-8)
    header = (out / "features.csv").read_text().splitlines()[0]
    assert header.startswith("kind,scan,time,first_beam,last_beam")
    kinds = {line.split(",")[0] for line in (out / "features.csv").read_text().splitlines()[1:]}
    assert {"tree", "line", "breakpoint"} <= kinds
    assert "wrote" in capsys.readouterr().out
    assert main(["detect", "--data", str(tmp_path / "log"), "--out", str(tmp_path / "d2"), "--plot", "x"]) == 2


def test_detections_laser_loads_the_same_log_as_the_written_directory(tmp_path):
    from nanoslam_jax.app.experiment import load_log

    _write_short_log(tmp_path / "log")
    detect_log(tmp_path / "log", tmp_path / "det", DetectorConfig())
    cfg = load_config(
        "configs/victoria_park_nano.yaml" if Path("configs").is_dir() else None, ["data.kind=victoria_park"]
    )
    a = load_log(load_config(None, ["data.kind=victoria_park", "data.detections=laser"]), str(tmp_path / "log"))
    b = load_log(load_config(None, ["data.kind=victoria_park"]), str(tmp_path / "det"))
    assert cfg.data.detections == "file"
    assert a.raw.detections.shape[0] > 20
    np.testing.assert_allclose(a.raw.detections, b.raw.detections, atol=1e-8)
    for x, y in zip(a.segments, b.segments):
        np.testing.assert_allclose(np.asarray(x), np.asarray(y), atol=1e-8)


@pytest.mark.slow
def test_slam_from_laser_equals_slam_on_the_written_log(tmp_path):
    from nanoslam_jax.app.experiment import execute

    _write_short_log(tmp_path / "log")
    detect_log(tmp_path / "log", tmp_path / "det", DetectorConfig())
    common = ["data.kind=victoria_park", "filter.n_particles=4", "output.plots=false", "output.progress=false"]
    a = execute(load_config(None, common + ["data.detections=laser"]), str(tmp_path / "log"))
    b = execute(load_config(None, common), str(tmp_path / "det"))
    np.testing.assert_allclose(a.trajectory, b.trajectory, atol=1e-6)
    assert a.metrics["n_landmarks"] == b.metrics["n_landmarks"]


REAL = SHARED_DATA / "victoria_park"


@pytest.mark.slow
@pytest.mark.data
@pytest.mark.skipif(
    not (REAL / "LASER.txt").is_file(), reason="the Victoria Park raw scans (../shared/data) are missing"
)
def test_real_log_trees_match_the_datasets_detections_in_a_stretch():
    scans = load_laser(REAL).select(slice(2000, 2300))
    ours = detect_trees(scans, DetectorConfig())
    ref = load_victoria_park(REAL).detections
    ref = ref[(ref[:, 0] >= scans.time[0] - 1e-6) & (ref[:, 0] <= scans.time[-1] + 1e-6) & (ref[:, 1] < 30)]
    found = 0
    for t, r, b, _ in ref:
        same = ours[np.abs(ours[:, 0] - t) < 5e-4]
        found += np.any((np.abs(same[:, 1] - r) <= 0.5) & (np.abs(same[:, 2] - b) <= np.deg2rad(1.5)))
    assert found / len(ref) > 0.97
