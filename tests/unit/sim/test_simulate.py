"""Tests of the Victoria Park-like simulator (nanoslam_jax.sim.park).

Independent truths: the JAX vehicle and measurement models of nanoslam_jax.models (the simulator
uses its own numpy/Python integration), geometry recomputed here from truth_poses and
truth_landmarks, and statistics of the injected noise.
"""

import dataclasses
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from nanoslam_jax.app.config import SimConfig, VehicleConfig
from nanoslam_jax.models import VehicleParams, range_bearing, vehicle_step
from nanoslam_jax.sim.park import PATH_CLEARANCE, TREE_SPACING, simulate, simulate_to_dir

EXACT = dict(
    sigma_r=0.0,
    sigma_beta_deg=0.0,
    sigma_v=0.0,
    sigma_alpha_deg=0.0,
    steering_bias_deg=0.0,
    p_detect=1.0,
    clutter_rate=0.0,
)


def sim_cfg(**kw) -> SimConfig:
    return dataclasses.replace(SimConfig(), **kw)


@pytest.fixture(scope="module")
def default_log():
    return simulate(SimConfig(), VehicleConfig())


@pytest.fixture(scope="module")
def exact_log():
    """Noise-free, every visible tree detected, no clutter, 90 s."""
    return simulate(sim_cfg(duration=90.0, **EXACT), VehicleConfig())


def truth_at(log, times):
    """Rows of truth_poses at exactly the given times (each must be present)."""
    idx = np.searchsorted(log.truth_poses[:, 0], times)
    assert np.all(log.truth_poses[idx, 0] == times)
    return log.truth_poses[idx, 1:]


def predicted(poses, trees):
    """(S, L, 2) range-bearing of every tree from every pose, with the JAX model."""
    f = jax.jit(jax.vmap(jax.vmap(range_bearing, in_axes=(None, 0)), in_axes=(0, None)))
    return np.asarray(f(jnp.asarray(poses), jnp.asarray(trees)))


def wrap(a):
    return (np.asarray(a) + np.pi) % (2 * np.pi) - np.pi


def associate(log):
    """For each detection: index of its tree (nearest in normalised range-bearing), z_hat, z."""
    det = log.detections
    scan_t, inv = np.unique(det[:, 0], return_inverse=True)
    z_hat = predicted(truth_at(log, scan_t), log.truth_landmarks)[inv]  # (M, L, 2)
    d2 = (det[:, None, 1] - z_hat[..., 0]) ** 2 + (10.0 * wrap(det[:, None, 2] - z_hat[..., 1])) ** 2
    j = np.argmin(d2, axis=1)
    return j, z_hat[np.arange(det.shape[0]), j]


# --------------------------------------------------------------------------- determinism, shapes, speed


def test_same_seed_identical_different_seed_differs():
    cfg = sim_cfg(duration=60.0)
    a, b, c = simulate(cfg), simulate(cfg), simulate(dataclasses.replace(cfg, seed=1))
    for name in ("dr", "detections", "gps", "truth_poses", "truth_landmarks"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
    assert not np.array_equal(a.truth_landmarks, c.truth_landmarks)
    assert not np.array_equal(a.dr[:, 1:], c.dr[:, 1:])
    assert a.detections.shape != c.detections.shape or not np.array_equal(a.detections, c.detections)


def test_default_is_well_formed(default_log):
    """(Its speed, at most 2 s, is measured by experiments/benchmark.py --only data.)"""
    log, sim = default_log, SimConfig()
    assert log.source == "simulated"
    n = int(sim.duration * sim.dr_rate) + 1
    assert log.dr.shape == (n, 3) and log.dr[0, 0] == 0.0
    np.testing.assert_allclose(np.diff(log.dr[:, 0]), 1.0 / sim.dr_rate, atol=1e-12)
    assert log.truth_landmarks.shape == (sim.n_trees, 2)
    assert log.detections.shape[1] == 4 and log.gps.shape[1] == 3 and log.truth_poses.shape[1] == 4
    assert np.all(np.diff(log.detections[:, 0]) >= 0)
    assert np.all(np.diff(log.truth_poses[:, 0]) > 0)  # sorted, no duplicated time
    np.testing.assert_array_equal(log.truth_poses[0], [0.0, 0.0, 0.0, 0.0])
    # scans at about scan_rate, never on a DR sample; truth holds every DR and scan time
    scans = log.scan_times
    frac = scans * sim.dr_rate - np.round(scans * sim.dr_rate)
    assert np.all(np.abs(frac) > 1e-3)
    assert np.mean(np.diff(scans)) == pytest.approx(1.0 / sim.scan_rate, rel=0.1)
    assert np.all(np.isin(log.dr[:, 0], log.truth_poses[:, 0]))
    assert np.all(np.isin(scans, log.truth_poses[:, 0]))
    n_all_scans = log.truth_poses.shape[0] - n
    assert n_all_scans == pytest.approx(sim.duration * sim.scan_rate, abs=2)
    # detections: diameters plausible, ranges positive, bearings wrapped
    assert np.all((log.detections[:, 3] >= 0.1) & (log.detections[:, 3] <= 0.6))
    assert np.all(log.detections[:, 1] > 0)
    assert np.all(np.abs(log.detections[:, 2]) <= np.pi)


def test_trees_are_spaced():
    log = simulate(sim_cfg(duration=30.0))
    tr = log.truth_landmarks
    d = np.hypot(*(tr[:, None, :] - tr[None, :, :]).transpose(2, 0, 1))
    np.fill_diagonal(d, np.inf)
    assert d.min() >= TREE_SPACING - 1e-9


# --------------------------------------------------------------------------- truth vs models


@pytest.mark.slow
def test_logged_controls_reproduce_truth_with_jax_model(exact_log):
    """Noise-free logged controls integrated with nanoslam_jax.models.vehicle_step give the truth."""
    log, params = exact_log, VehicleParams()
    t, u = jnp.asarray(log.dr[:, 0]), jnp.asarray(log.dr[:, 1:])
    dts = jnp.diff(t)

    @jax.jit
    def integrate(u, dts):
        def body(x, inp):
            x = vehicle_step(x, inp[:2], inp[2], params)
            return x, x

        _, xs = jax.lax.scan(body, jnp.zeros(3), jnp.concatenate([u[:-1], dts[:, None]], axis=1))
        return jnp.concatenate([jnp.zeros((1, 3)), xs])

    dr_poses = np.asarray(integrate(u, dts))
    truth_dr = truth_at(log, log.dr[:, 0])
    np.testing.assert_allclose(dr_poses[:, :2], truth_dr[:, :2], atol=1e-7)
    np.testing.assert_allclose(wrap(dr_poses[:, 2] - truth_dr[:, 2]), 0.0, atol=1e-9)

    # scan times: the held control over the remaining fraction of the DR interval
    scan_mask = ~np.isin(log.truth_poses[:, 0], log.dr[:, 0])
    ts = log.truth_poses[scan_mask, 0]
    k = np.searchsorted(log.dr[:, 0], ts, side="right") - 1
    step = jax.vmap(vehicle_step, in_axes=(0, 0, 0, None))
    xs = np.asarray(step(jnp.asarray(dr_poses[k]), u[k], jnp.asarray(ts - log.dr[k, 0]), params))
    np.testing.assert_allclose(xs[:, :2], log.truth_poses[scan_mask, 1:3], atol=1e-7)
    np.testing.assert_allclose(wrap(xs[:, 2] - log.truth_poses[scan_mask, 3]), 0.0, atol=1e-9)


def test_noise_and_bias_enter_only_the_logged_controls():
    base = simulate(sim_cfg(duration=60.0, sigma_v=0.0, sigma_alpha_deg=0.0, steering_bias_deg=0.0))
    noisy = simulate(sim_cfg(duration=60.0, sigma_v=0.2, sigma_alpha_deg=1.0, steering_bias_deg=2.0))
    np.testing.assert_array_equal(base.truth_poses, noisy.truth_poses)
    dv = noisy.dr[:, 1] - base.dr[:, 1]
    da = noisy.dr[:, 2] - base.dr[:, 2]
    assert np.std(dv) == pytest.approx(0.2, rel=0.1) and abs(np.mean(dv)) < 0.02
    assert np.mean(da) == pytest.approx(math.radians(2.0), abs=math.radians(0.1))
    assert np.std(da) == pytest.approx(math.radians(1.0), rel=0.1)


def test_exact_detections_match_geometry(exact_log):
    """Zero noise, p_detect 1, no clutter: detections are exactly the visible trees."""
    log, sim = exact_log, sim_cfg(duration=90.0, **EXACT)
    j, z_hat = associate(log)
    det = log.detections
    np.testing.assert_allclose(det[:, 1], z_hat[:, 0], atol=1e-9)
    np.testing.assert_allclose(wrap(det[:, 2] - z_hat[:, 1]), 0.0, atol=1e-9)
    # every scan (including those without detections) reports exactly the trees in the footprint
    scan_t = log.truth_poses[~np.isin(log.truth_poses[:, 0], log.dr[:, 0]), 0]
    z = predicted(truth_at(log, scan_t), log.truth_landmarks)
    visible = (z[..., 0] < sim.max_range) & (np.abs(z[..., 1]) <= math.radians(sim.fov_deg) / 2)
    counts = dict(zip(*np.unique(det[:, 0], return_counts=True)))
    np.testing.assert_array_equal(visible.sum(axis=1), [counts.get(t, 0) for t in scan_t])
    assert visible.sum() == det.shape[0]
    # scans with no detection are absent
    assert set(np.unique(det[:, 0])) == set(scan_t[visible.any(axis=1)])


def test_noisy_residuals_have_unit_variance():
    sim = sim_cfg(duration=120.0, clutter_rate=0.0, sigma_r=0.3, sigma_beta_deg=1.0)
    log = simulate(sim)
    _, z_hat = associate(log)
    nr = (log.detections[:, 1] - z_hat[:, 0]) / sim.sigma_r
    nb = wrap(log.detections[:, 2] - z_hat[:, 1]) / math.radians(sim.sigma_beta_deg)
    assert log.detections.shape[0] > 1000
    for res in (nr, nb):
        assert abs(np.mean(res)) < 0.1
        assert np.var(res) == pytest.approx(1.0, rel=0.12)


@pytest.mark.parametrize("fov", [180.0, 90.0])
def test_detections_within_range_and_fov(fov):
    sim = sim_cfg(duration=60.0, fov_deg=fov, max_range=25.0, clutter_rate=0.0)
    log = simulate(sim)
    det = log.detections
    assert det.shape[0] > 50
    assert np.all((det[:, 1] > 0) & (det[:, 1] < sim.max_range))
    assert np.all(np.abs(det[:, 2]) <= math.radians(fov) / 2)
    # no detection of a tree truly out of range or out of view (beyond the noise)
    j, z_hat = associate(log)
    assert np.all(z_hat[:, 0] < sim.max_range + 6 * sim.sigma_r)
    assert np.all(np.abs(z_hat[:, 1]) <= math.radians(fov) / 2 + 6 * math.radians(sim.sigma_beta_deg))
    assert np.all(np.abs(det[:, 1] - z_hat[:, 0]) < 6 * sim.sigma_r)


def test_clutter_rate_and_footprint():
    sim = sim_cfg(duration=120.0, p_detect=0.0, clutter_rate=2.0, fov_deg=120.0)
    log = simulate(sim)
    n_scans = log.truth_poses.shape[0] - log.dr.shape[0]
    det = log.detections
    assert det.shape[0] / n_scans == pytest.approx(2.0, rel=0.1)
    assert np.all((det[:, 1] > 0) & (det[:, 1] < sim.max_range))
    assert np.all(np.abs(det[:, 2]) <= math.radians(60.0))
    # uniform over the sector area: P(r < R / 2) = 1/4
    assert np.mean(det[:, 1] < sim.max_range / 2) == pytest.approx(0.25, abs=0.04)


# --------------------------------------------------------------------------- trajectory


def test_trajectory_stays_in_park_and_loops(default_log):
    log, sim = default_log, SimConfig()
    xy, phi = log.truth_poses[:, 1:3], log.truth_poses[:, 3]
    trees = log.truth_landmarks
    assert np.all(xy >= trees.min(axis=0)) and np.all(xy <= trees.max(axis=0))
    assert np.all(np.ptp(trees, axis=0) <= sim.area)
    assert np.all(np.ptp(xy, axis=0) < sim.area)
    # no tree on the road: the laser keeps some clearance
    d = np.hypot(*(xy[::20, None, :] - trees[None]).transpose(2, 0, 1))
    assert d.min() > PATH_CLEARANCE - 2.0
    # heading turns sim.loops times around
    turns = (np.unwrap(phi)[-1] - phi[0]) / (2 * np.pi)
    assert turns == pytest.approx(sim.loops, abs=0.15)
    # revisits: most positions of the second half are within 2 m of the first half
    n = xy.shape[0]
    first, second = xy[: n // 2 : 10], xy[n // 2 + n // 10 :: 10]
    near = np.min(np.hypot(*(second[:, None, :] - first[None]).transpose(2, 0, 1)), axis=1) < 2.0
    assert near.mean() > 0.8


def test_controls_bounded_and_speed(exact_log):
    sim = SimConfig()
    assert np.max(np.abs(exact_log.dr[:, 2])) < 0.5
    ve = exact_log.dr[exact_log.dr[:, 0] > 5.0, 1]
    assert np.mean(ve) == pytest.approx(sim.speed, rel=0.15)
    # smooth steering: bounded rate
    assert np.max(np.abs(np.diff(exact_log.dr[:, 2]))) * sim.dr_rate < 1.0


def test_three_loops():
    log = simulate(sim_cfg(loops=3.0, duration=180.0))
    phi = log.truth_poses[:, 3]
    assert (np.unwrap(phi)[-1] - phi[0]) / (2 * np.pi) == pytest.approx(3.0, abs=0.2)


def test_gps_is_truth_at_5hz(default_log):
    log = default_log
    np.testing.assert_allclose(np.diff(log.gps[:, 0]), 0.2, atol=1e-12)
    assert log.gps[0, 0] == 0.0
    np.testing.assert_array_equal(log.gps[:, 1:], truth_at(log, log.gps[:, 0])[:, :2])


# --------------------------------------------------------------------------- files


def test_write_and_load_round_trip(tmp_path):
    loader = pytest.importorskip("nanoslam_jax.data._loader")
    sim = sim_cfg(duration=30.0)
    raw = simulate_to_dir(tmp_path / "sim", sim)
    for name in (
        "inputs.dat",
        "measurements.dat",
        "gps.dat",
        "truth_poses.dat",
        "truth_landmarks.dat",
        "truth_diameters.dat",
    ):
        assert (tmp_path / "sim" / name).is_file(), name
    # the file convention: bearing + pi/2
    meas = np.loadtxt(tmp_path / "sim" / "measurements.dat")
    np.testing.assert_allclose(meas[:, 2], raw.detections[:, 2] + np.pi / 2, atol=1e-8)
    back = loader.load_victoria_park(tmp_path / "sim")
    for name in ("dr", "detections", "gps", "truth_poses", "truth_landmarks", "truth_diameters"):
        np.testing.assert_allclose(getattr(back, name), getattr(raw, name), atol=1e-8, err_msg=name)
    assert back.truth_diameters.shape == (sim.n_trees,)
    np.testing.assert_array_equal(back.scan_times.shape, raw.scan_times.shape)
