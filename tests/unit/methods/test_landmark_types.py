"""Landmarks of any dimension: the map and every update sized by the measurement model's
``landmark_dim``, checked against closed forms (a linear 3-D model: the Kalman filter), against the
2-D point map (a circle of fixed radius is a point with a constant third value) and against the
simulator's true pillars (circle landmarks from the front end's arcs)."""

import dataclasses
from typing import ClassVar

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from nanoslam_jax.app.config import load_config
from nanoslam_jax.data import make_segments
from nanoslam_jax.app.experiment import execute, load_log, map_columns
from nanoslam_jax.methods import reported_map, run_filter
from nanoslam_jax.app.filters import settings_from_config
from nanoslam_jax.methods.maps._landmarks import ekf_update_loglik, init_landmark, ukf_init_landmark, ukf_update_loglik
from nanoslam_jax.lib.quadrature import Unscented
from nanoslam_jax.models import AbstractMeasurementModel, Circle

# the functions under test, compiled (run eagerly, JAX compiles each operation)
ekf_update_loglik, init_landmark, ukf_init_landmark = map(
    jax.jit, (ekf_update_loglik, init_landmark, ukf_init_landmark)
)
ukf_update_loglik = jax.jit(ukf_update_loglik)


class Shifted3(AbstractMeasurementModel):
    """A linear 3-D model: ``z = m - (px, py, 0)`` (no angles), noise ``diag(r)``."""

    landmark_dim: ClassVar[int] = 3
    measurement_dim: ClassVar[int] = 3
    r: jax.Array

    def h(self, x, m, aux=None):
        return m - jnp.stack([x[0], x[1], 0.0])

    def landmark_from(self, x, z, aux=None):
        return z + jnp.stack([x[0], x[1], 0.0])

    def noise_cov(self):
        return jnp.diag(self.r)

    def visible(self, x, m):
        return jnp.asarray(True)


def _kalman(m, P, z_minus_pred, R):
    """The Kalman update of ``N(m, P)`` by ``z = m + noise(R)`` (identity observation) and the
    log-likelihood of the innovation."""
    S = P + R
    K = P @ np.linalg.inv(S)
    ll = -0.5 * (z_minus_pred @ np.linalg.solve(S, z_minus_pred) + np.linalg.slogdet(2 * np.pi * S)[1])
    return m + K @ z_minus_pred, (np.eye(3) - K) @ P, ll


@pytest.mark.slow  # four programs compiled
def test_three_dimensional_landmark_updates_equal_the_kalman_filter():
    model = Shifted3(jnp.array([0.04, 0.09, 0.01]))
    R = np.diag([0.04, 0.09, 0.01])
    x = jnp.array([1.0, -2.0, 0.3])
    z = jnp.array([2.5, 1.0, 0.7])
    m0, c0 = init_landmark(x, z, jnp.asarray(R), model)
    np.testing.assert_allclose(m0, [3.5, -1.0, 0.7], atol=1e-12)
    np.testing.assert_allclose(c0, R, atol=1e-12)
    um, uc = ukf_init_landmark(x, z, jnp.asarray(R), Unscented(1.0, 2.0, 0.0), model)
    np.testing.assert_allclose(um, m0, atol=1e-12)
    np.testing.assert_allclose(uc, R, atol=1e-12)

    mean = np.array([3.4, -0.8, 0.75])
    cov = np.array([[0.3, 0.05, 0.01], [0.05, 0.2, -0.02], [0.01, -0.02, 0.1]])
    z2 = jnp.array([2.45, 1.15, 0.72])
    want_m, want_c, want_ll = _kalman(mean, cov, np.asarray(z2) - (mean - [1.0, -2.0, 0.0]), R)
    for update in (ekf_update_loglik, lambda *a: ukf_update_loglik(*a[:-1], Unscented(1.0, 2.0, 0.0), model=a[-1])):
        got_m, got_c, got_ll = update(x, z2, jnp.asarray(mean), jnp.asarray(cov), jnp.asarray(R), model)
        np.testing.assert_allclose(got_m, want_m, atol=1e-12)
        np.testing.assert_allclose(got_c, want_c, atol=1e-12)
        np.testing.assert_allclose(got_ll, want_ll, atol=1e-10)


@pytest.mark.slow
def test_circles_of_fixed_radius_give_the_point_map_in_ekf_slam():
    """A circle's centre is detected by its range and bearing as a point is; with every radius the
    same its third value is constant and decoupled, so EKF-SLAM over (xc, yc, R) gives the path and
    the centres of EKF-SLAM over points."""
    # Occlusion is a test of points (a circle counts a miss wherever its centre is in view).
    cfg = load_config(None, ["filter.method=ekf_slam", "sim.duration=120", "data.k_max=16", "map.occlusion=false"])
    log = load_log(cfg)
    static, params = settings_from_config(cfg, log.segments.k_max)
    point = run_filter(static, params, log.segments, 0)

    raw = log.raw
    det = raw.detections
    circles = dataclasses.replace(raw, detections=np.c_[det[:, :3], np.full(len(det), 0.25), det[:, 3]])
    d = cfg.data
    seg = make_segments(circles, min_range=d.min_range, max_range=d.max_range, k_max=d.k_max, measurement_dim=3)
    rb = params.measurement
    circle = Circle(
        sigma_r=rb.sigma_r,
        sigma_beta=rb.sigma_beta,
        sigma_radius=0.05,
        min_range=rb.min_range,
        max_range=rb.max_range,
        half_fov=rb.half_fov,
        view_margin=rb.view_margin,
        view_margin_angle=rb.view_margin_angle,
    )
    run = run_filter(static, params._replace(measurement=circle), seg, 0)

    np.testing.assert_array_equal(run.outputs.n_new, point.outputs.n_new)
    np.testing.assert_allclose(run.outputs.best_pose, point.outputs.best_pose, atol=1e-7)
    lm_c, lm_p = reported_map(run.state), reported_map(point.state)
    np.testing.assert_array_equal(lm_c.active, lm_p.active)
    act = np.asarray(lm_p.active)
    assert act.sum() > 20
    np.testing.assert_allclose(np.asarray(lm_c.mean)[act, :2], np.asarray(lm_p.mean)[act], atol=1e-7)
    np.testing.assert_allclose(np.asarray(lm_c.mean)[act, 2], 0.25, atol=1e-12)
    np.testing.assert_allclose(np.asarray(lm_c.cov)[act, :2, :2], np.asarray(lm_p.cov)[act], atol=1e-9)


@pytest.mark.slow
@pytest.mark.parametrize("method", ["ekf_slam", "fastslam2"])
def test_circle_landmarks_map_the_simulated_pillars(method):
    """The front end's arcs of a simulated room with four round pillars, as circle landmarks: every
    true pillar is mapped by a confirmed circle, centre within 12 cm and radius within 1 cm of the
    simulator's truth (the path drifts by about 2 deg in heading without them)."""
    overrides = [
        "data.detections=laser_circles",
        "model.measurement=circle",
        "model.measurement_params={sigma_r: 0.02, sigma_beta: 0.01, sigma_radius: 0.02, min_range: 0.2, "
        "max_range: 9.5, half_fov: 1.4835}",
        "detector.circle_max_radius=0.5",
        "data.k_max=8",
        "indoor.pillars=4",
        "indoor.duration=60",
        "indoor.seed=1",
        f"filter.method={method}",
        "filter.n_particles=20",
        "output.plots=false",
        "output.progress=false",
    ]
    res = execute(load_config("configs/indoor_lines.yaml", overrides))
    m = res.metrics
    assert m["n_arcs"] == 4 and m["n_arcs_matched"] == 4, m
    assert m["arc_centre_worst"] < 0.12 and m["arc_radius_worst"] < 0.01, m
    assert m["rmse_heading_deg"] < m["dr_rmse_heading_deg"], m
    cols = map_columns(3)
    assert res.landmarks.shape[1] == len(cols) and cols[:3] == ["x", "y", "m2"]
    confirmed = res.landmarks[res.landmarks[:, cols.index("confirmed")] > 0]
    truth = res.log.feature_truth.arcs
    d = np.hypot(*(confirmed[:, None, :2] - truth[None, :, :2]).transpose(2, 0, 1))
    nearest = np.argmin(d, axis=1)
    np.testing.assert_allclose(confirmed[:, 2], truth[nearest, 2], atol=0.01)
