"""The odometry motion model (``model.motion: odometry``): its step against closed forms, its
Jacobians against finite differences, its noise against a Monte Carlo sample of Thrun's
sample_motion_model_odometry written here in numpy, the odometry-increment rows of the data
layer, dead reckoning over them against the pose stream, the config section, and SLAM against
dead reckoning on a simulated differential-drive log."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import nanoslam_jax as ns
from nanoslam_jax.app.config import ConfigError, load_config
from nanoslam_jax.app.config_reference import reference_markdown
from nanoslam_jax.app.experiment import load_log
from nanoslam_jax.app.filters import settings_from_config
from nanoslam_jax.data import RawLog, make_segments, odometry_rows, odometry_rows_from_unicycle
from nanoslam_jax.data import laser_odom_raw, laser_poses, load_carmen
from nanoslam_jax.methods import dead_reckoning
from nanoslam_jax.models import Odometry, Unicycle, check_motion_model, rot_trans_rot

ALPHAS = dict(alpha1=0.02, alpha2=0.01, alpha3=0.03, alpha4=0.005)


def _wrap(a):
    return (np.asarray(a) + np.pi) % (2 * np.pi) - np.pi


def _compose(a, b):
    """Pose ``a (+) b`` (``b`` in the frame of ``a``)."""
    c, s = math.cos(a[2]), math.sin(a[2])
    return np.array([a[0] + c * b[0] - s * b[1], a[1] + s * b[0] + c * b[1], _wrap(a[2] + b[2])])


def _relative(a, b):
    """Pose ``b`` in the frame of ``a`` (``a (-) b``)."""
    c, s = math.cos(a[2]), math.sin(a[2])
    dx, dy = b[0] - a[0], b[1] - a[1]
    return np.array([c * dx + s * dy, -s * dx + c * dy, _wrap(b[2] - a[2])])


def _sensor(base, s):
    """The sensor pose (its position, the robot's heading) of a base pose with the mounting ``s``."""
    return _compose(base, (s[0], s[1], 0.0))


def _pose_stream(n=40, seed=0):
    """A wiggly path with sideways motion, turns in place and a reversal, at uneven times."""
    rng = np.random.default_rng(seed)
    t = np.cumsum(rng.uniform(0.05, 0.3, n))
    poses = [np.array([1.0, -2.0, 3.0])]
    for k in range(n - 1):
        inc = rng.normal([0.3, 0.05, 0.1], [0.2, 0.05, 0.3])
        if k % 9 == 4:
            inc[:2] = 0.0  # a turn in place
        poses.append(_compose(poses[-1], inc))
    return t, np.array(poses)


# ----------------------------------------------------------------------------- the model


def test_step_closed_forms_pure_rotation_pure_translation_and_composition():
    m = Odometry()
    check_motion_model(m)
    x, dt = jnp.array([1.0, -2.0, 0.7]), 0.2
    y = np.asarray(m.step(x, jnp.array([0.0, 0.0, 1.5]), dt))
    np.testing.assert_allclose(y, [1.0, -2.0, 1.0], atol=1e-12)
    y = np.asarray(m.step(x, jnp.array([2.0, -0.5, 0.0]), dt))
    c, s = math.cos(0.7), math.sin(0.7)
    np.testing.assert_allclose(y, [1.0 + 0.2 * (2 * c + 0.5 * s), -2.0 + 0.2 * (2 * s - 0.5 * c), 0.7], atol=1e-12)
    np.testing.assert_allclose(np.asarray(m.step(x, jnp.array([1.0, 2.0, 3.0]), 0.0)), x, atol=0)
    # a turn in place moves a sensor mounted off the base on a circle about the base
    off = Odometry(sensor_x=0.4, sensor_y=0.1)
    base = _compose(np.asarray(x), (-0.4, -0.1, 0.0))
    y = np.asarray(off.step(x, jnp.array([0.0, 0.0, 2.0]), 0.5))
    np.testing.assert_allclose(y, _sensor(_compose(base, (0, 0, 1.0)), (0.4, 0.1)), atol=1e-12)
    # the increment between two poses as one row's rates moves the first onto the second
    t, poses = _pose_stream(12, seed=3)
    rows = odometry_rows(t, poses)
    for k in range(t.size - 1):
        dt = t[k + 1] - t[k]
        y = np.asarray(m.step(jnp.asarray(poses[k]), jnp.asarray(rows[k, 1:]), dt))
        np.testing.assert_allclose(y[:2], poses[k + 1, :2], atol=1e-12)
        assert abs(_wrap(y[2] - poses[k + 1, 2])) < 1e-12
        sk, sk1 = _sensor(poses[k], (0.4, 0.1)), _sensor(poses[k + 1], (0.4, 0.1))
        y = np.asarray(off.step(jnp.asarray(sk), jnp.asarray(rows[k, 1:]), dt))
        np.testing.assert_allclose(y[:2], sk1[:2], atol=1e-12)


def test_jacobians_against_finite_differences():
    m = Odometry(sensor_x=0.3, sensor_y=-0.2, **ALPHAS)
    x, u, dt = jnp.array([1.0, -2.0, 0.7]), jnp.array([0.8, 0.2, -0.6]), 0.25
    F, G = m.jacobians(x, u, dt)
    assert F.shape == (3, 3) and G.shape == (3, 3)
    h = 1e-6
    fd_x = np.stack([(m.step(x + h * e, u, dt) - m.step(x - h * e, u, dt)) / (2 * h) for e in jnp.eye(3)], axis=1)
    w0 = jnp.zeros(3)
    fd_w = np.stack(
        [(m.noisy_step(x, u, w0 + h * e, dt) - m.noisy_step(x, u, w0 - h * e, dt)) / (2 * h) for e in jnp.eye(3)], 1
    )
    np.testing.assert_allclose(np.asarray(F), fd_x, atol=1e-8)
    np.testing.assert_allclose(np.asarray(G), fd_w, atol=1e-8)
    # with the sensor on the base, the noise in the world frame is the increment's covariance
    # turned by the heading
    m = Odometry(**ALPHAS)
    _, G = m.jacobians(x, u, dt)
    c, s = math.cos(0.7), math.sin(0.7)
    R = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
    Q = np.asarray(m.increment_cov(u, dt))
    np.testing.assert_allclose(np.asarray(G @ m.noise_cov(dt) @ G.T), R @ Q @ R.T, atol=1e-14)


def _thrun_sample(delta, alphas, n, rng):
    """Thrun's sample_motion_model_odometry (Probabilistic Robotics, table 5.6; ``sample(b^2)`` a
    zero-mean normal of variance ``b^2``) from the origin, for odometry moving from the origin to
    the pose ``delta``."""
    a1, a2, a3, a4 = alphas
    rot1 = math.atan2(delta[1], delta[0])
    trans = math.hypot(delta[0], delta[1])
    rot2 = delta[2] - rot1
    r1 = rot1 - rng.normal(0, 1, n) * math.sqrt(a1 * rot1**2 + a2 * trans**2)
    tr = trans - rng.normal(0, 1, n) * math.sqrt(a3 * trans**2 + a4 * (rot1**2 + rot2**2))
    r2 = rot2 - rng.normal(0, 1, n) * math.sqrt(a1 * rot2**2 + a2 * trans**2)
    return np.stack([tr * np.cos(r1), tr * np.sin(r1), r1 + r2], axis=1)


@pytest.mark.parametrize("delta", [(0.5, 0.1, 0.3), (0.3, -0.05, -0.5), (1.0, 0.0, 0.0)])
def test_noise_covariance_against_a_monte_carlo_sample_of_thrun(delta):
    m = Odometry(floor_xy=1e-9, floor_phi=1e-9, **ALPHAS)
    dt = 0.5
    u = jnp.asarray(delta) / dt
    Q = np.asarray(m.increment_cov(u, dt))
    ys = _thrun_sample(delta, tuple(ALPHAS.values()), 400_000, np.random.default_rng(0))
    np.testing.assert_allclose(np.cov(ys.T), Q, atol=0.03 * np.abs(Q).max())
    # sampling the model's noise gives its covariance (the filters' sigma points and particles)
    w = np.random.default_rng(1).normal(size=(100_000, 3))
    x = jax.vmap(m.noisy_step, (None, None, 0, None))(jnp.zeros(3), u, jnp.asarray(w), dt)
    np.testing.assert_allclose(np.cov(np.asarray(x).T), Q, atol=0.02 * np.abs(Q).max())


def test_decomposition_and_the_floor():
    np.testing.assert_allclose(
        np.asarray(rot_trans_rot(jnp.array([1.0, 1.0, 1.0]))), [math.pi / 4, math.sqrt(2), 1 - math.pi / 4]
    )
    # backward: a negative translation, not a half turn; a turn in place: no first rotation
    np.testing.assert_allclose(np.asarray(rot_trans_rot(jnp.array([-1.0, 0.0, 0.0]))), [0.0, -1.0, 0.0], atol=1e-15)
    np.testing.assert_allclose(np.asarray(rot_trans_rot(jnp.array([0.0, 0.0, 0.4]))), [0.0, 0.0, 0.4])
    m = Odometry()
    for u in (jnp.zeros(3), jnp.array([0.0, 0.0, 1.0]), jnp.array([1.0, 0.0, 0.0])):
        Q = np.asarray(m.increment_cov(u, 0.1))
        assert np.linalg.eigvalsh(Q).min() >= min(float(m.floor_xy), float(m.floor_phi)) ** 2 * (1 - 1e-9)
    assert np.all(np.isfinite(np.asarray(m.noisy_step(jnp.zeros(3), jnp.zeros(3), jnp.ones(3), 0.0))))


# ----------------------------------------------------------------------------- data and dead reckoning


def _dummy_detections(t):
    return np.stack([t, np.full(t.size, 5.0), np.zeros(t.size), np.full(t.size, 0.3)], axis=1)


@pytest.mark.parametrize("mount", [(0.0, 0.0), (0.4, -0.1)])
def test_dead_reckoning_over_odometry_rows_reproduces_the_pose_stream(mount):
    t, poses = _pose_stream()
    raw = RawLog(dr=odometry_rows(t, poses), detections=_dummy_detections(t[1:]), gps=np.zeros((0, 3)))
    seg = make_segments(raw, max_dr_per_segment=4)
    assert np.asarray(seg.u).shape[-1] == 3
    cfg = load_config(None, ["model.motion=odometry", f"odometry.sensor_x={mount[0]}", f"odometry.sensor_y={mount[1]}"])
    _, params = settings_from_config(cfg, seg.k_max)
    with ns.float64():
        dr = np.asarray(dead_reckoning(params, seg))
    s0 = _sensor(poses[0], mount)
    want = np.array([_relative(s0, _sensor(p, mount)) for p in poses[1:]])
    np.testing.assert_allclose(dr[:, :2], want[:, :2], atol=1e-9)
    np.testing.assert_allclose(_wrap(dr[:, 2] - want[:, 2]), 0, atol=1e-9)


def test_segments_carry_every_control_column_and_a_short_log_is_refused():
    t, poses = _pose_stream(10)
    rows = odometry_rows(t, poses)
    raw = RawLog(dr=rows, detections=_dummy_detections(t[1:] - 0.01), gps=np.zeros((0, 3)))
    seg = make_segments(raw, max_dr_per_segment=3)
    u, mask = np.asarray(seg.u), np.asarray(seg.dr_mask)
    assert u.shape == mask.shape + (3,) and np.all(u[~mask] == 0)
    assert {tuple(r) for r in u[mask]} <= {tuple(r) for r in rows[:, 1:]}
    two = make_segments(RawLog(dr=rows[:, :3], detections=raw.detections, gps=raw.gps), max_dr_per_segment=3)
    assert np.asarray(two.u).shape[-1] == 2
    _, params = settings_from_config(load_config(None, ["model.motion=odometry"]), two.k_max)
    with pytest.raises(
        ValueError, match=r"model.motion: Odometry reads 3 controls per DR piece, the log's segments hold 2"
    ):
        dead_reckoning(params, two)
    np.testing.assert_array_equal(odometry_rows_from_unicycle(np.array([[0.0, 1.0, 0.5]])), [[0.0, 1.0, 0.0, 0.5]])


def _flaser(ranges, laser, odom, t):
    r = " ".join(f"{v:.2f}" for v in ranges)
    p = " ".join(f"{v:.6f}" for v in (*laser, *odom))
    return f"FLASER {len(ranges)} {r} {p} {t:.6f} host {t:.6f}"


def test_carmen_odometry_rows_move_the_laser_onto_its_poses(tmp_path):
    # a robot sliding sideways while turning (what (v, omega) rows cannot hold), laser 0.3 m ahead
    t = 50.0 + 0.2 * np.arange(25)
    th = 0.3 * (t - t[0])
    x, y = 0.2 * (t - t[0]), 0.1 * np.sin(t - t[0])
    lines = []
    for k in range(t.size):
        laser = _sensor((x[k], y[k], th[k]), (0.3, 0.0))
        lines.append(_flaser([1.0] * 4, (laser[0], laser[1], th[k]), (x[k], y[k], th[k]), t[k]))
    (tmp_path / "c.clf").write_text("\n".join(lines) + "\n")
    log = load_carmen(tmp_path / "c.clf")
    np.testing.assert_allclose(log.laser_pose, (0.3, 0.0, 0.0), atol=1e-5)
    default, _ = laser_odom_raw(log)
    assert default.dr.shape == (2 * t.size - 1, 3)  # the unicycle rows stay the default
    raw, _ = laser_odom_raw(log, controls="odometry")
    assert raw.dr.shape == (t.size, 4) and np.abs(raw.dr[:-1, 2]).max() > 0.1  # sideways motion kept
    np.testing.assert_allclose(raw.dr[:, 0], t)
    m = Odometry(sensor_x=0.3)
    p = jnp.asarray(laser_poses(log)[0])
    step = jax.jit(lambda p, u, dt: m.step(p, u, dt))
    for k in range(t.size - 1):
        p = step(p, jnp.asarray(raw.dr[k, 1:]), t[k + 1] - t[k])
        np.testing.assert_allclose(np.asarray(p[:2]), laser_poses(log)[k + 1, :2], atol=1e-5)
        assert abs(_wrap(float(p[2]) - log.odom[k + 1, 2])) < 1e-5


# ----------------------------------------------------------------------------- the configuration


def test_config_section_defaults_reference_and_a_negative_alpha():
    from tests.helpers.internals import motion_model_from_config
    from nanoslam_jax.models._settings import OdometryConfig

    cfg = load_config(None, ["model.motion=odometry", "odometry.alpha3=0.2", "odometry.floor_phi_deg=0.1"])
    m = motion_model_from_config(cfg)
    assert isinstance(m, Odometry) and float(m.alpha3) == 0.2 and math.isclose(float(m.floor_phi), math.radians(0.1))
    assert cfg.odometry == OdometryConfig(alpha3=0.2, floor_phi_deg=0.1)
    default = Odometry()
    assert float(default.alpha1) == OdometryConfig().alpha1 and float(default.floor_xy) == OdometryConfig().floor_xy
    text = reference_markdown()
    assert "odometry.alpha1" in text and "odometry.floor_xy" in text and "'odometry'" in text
    with pytest.raises(ConfigError, match=r"odometry\.alpha2"):
        load_config(None, ["model.motion=odometry", "odometry.alpha2=-0.1"])


def test_a_simulated_log_with_the_odometry_model_has_the_unicycle_rows_as_increments():
    cfg = load_config(None, ["model.motion=odometry", "sim.duration=5"])
    log = load_log(cfg)
    uni = load_log(load_config(None, ["model.motion=unicycle", "sim.duration=5"]))
    np.testing.assert_array_equal(log.raw.dr, odometry_rows_from_unicycle(uni.raw.dr))
    # the same dead reckoning as the unicycle model's (no sensor offset: both move the centre alike)
    with ns.float64():
        a = dead_reckoning(settings_from_config(cfg, log.segments.k_max)[1], log.segments)
        ucfg = load_config(None, ["model.motion=unicycle", "sim.duration=5"])
        b = dead_reckoning(settings_from_config(ucfg, uni.segments.k_max)[1], uni.segments)
    np.testing.assert_allclose(np.asarray(a), np.asarray(b), atol=1e-9)
    assert isinstance(settings_from_config(ucfg, 4)[1].motion, Unicycle)


# ----------------------------------------------------------------------------- SLAM against dead reckoning

#: A differential-drive robot with noisy (v, omega) odometry and a turn-rate bias, as pose increments.
SIM = ["model.motion=odometry", "sim.duration=120", "sim.sigma_v=0.1", "sim.sigma_omega_deg=1", "sim.omega_bias_deg=1"]
NOISE = ["odometry.alpha1=0.05", "odometry.alpha2=0.002", "odometry.alpha3=0.02", "odometry.alpha4=0.01"]


@pytest.mark.slow
@pytest.mark.parametrize("method", ["nano", "ekf_slam"])
def test_slam_with_the_odometry_model_beats_dead_reckoning(method):
    result = ns.run(overrides=[*SIM, *NOISE, f"filter.method={method}", "output.plots=false"], seed=1)
    m = result.metrics
    assert m["dr_rmse_fixed"] > 5.0  # the bias makes dead reckoning drift
    assert m["rmse_fixed"] * 5 <= m["dr_rmse_fixed"], m


@pytest.mark.slow
@pytest.mark.parametrize("method", ["fastslam1", "fastslam2", "ufastslam", "iterated", "nasrukf"])
def test_every_method_runs_with_the_odometry_model(method):
    over = ["model.motion=odometry", "sim.duration=15", "filter.n_particles=5", "output.plots=false"]
    m = ns.run(overrides=[*over, f"filter.method={method}"], seed=0).metrics
    assert np.isfinite(m["rmse_fixed"]) and m["rmse_fixed"] < 2.0, m


def test_rosbag_odometry_rows_move_the_laser_onto_its_poses(tmp_path):
    from tests.unit.data.test_rosbag import simulate, write_bag

    from nanoslam_jax.data import load_rosbag

    with pytest.warns(UserWarning):
        log = load_rosbag(write_bag(tmp_path, simulate(), "sqlite3"))
    raw, _ = laser_odom_raw(log, controls="odometry")
    t = np.unique(log.scans.time)
    assert raw.dr.shape == (t.size, 4)
    m = Odometry(sensor_x=float(log.laser_pose[0]), sensor_y=float(log.laser_pose[1]))
    laser = laser_poses(log)
    p = jnp.array([laser[0, 0], laser[0, 1], log.odom[0, 2]])
    step = jax.jit(lambda p, u, dt: m.step(p, u, dt))
    for k in range(t.size - 1):
        p = step(p, jnp.asarray(raw.dr[k, 1:]), t[k + 1] - t[k])
        np.testing.assert_allclose(np.asarray(p[:2]), laser[k + 1, :2], atol=1e-9)
        assert abs(_wrap(float(p[2]) - log.odom[k + 1, 2])) < 1e-9
