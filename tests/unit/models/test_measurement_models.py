"""Measurement models as plug-ins: a model written in this module (the generic, autodiff path)
against the identical built-in range-bearing model (its hand-specialised path), EKF-SLAM with a
linear-Gaussian motion and measurement model against a Kalman filter written here, a particle
method against the same Kalman filter, and the generic path's Jacobians against finite
differences."""

import dataclasses
import math
from typing import ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from nanoslam_jax.app.config import ConfigError, load_config
from nanoslam_jax.data import Segments, make_segments
from nanoslam_jax.methods import run_filter
from nanoslam_jax.app.filters import settings_from_config
from tests.helpers.internals import innovation_information
from nanoslam_jax.models import AbstractMeasurementModel, AbstractMotionModel, RangeBearing
from nanoslam_jax.sim.park import simulate


class PlainRangeBearing(AbstractMeasurementModel):
    """Range and bearing to a point written out here from its equations, as a user would write a
    model: not a RangeBearing, so the filter takes its generic (autodiff) path."""

    angles: ClassVar[tuple[int, ...]] = (1,)

    sigma_r: jax.Array = eqx.field(default=0.3, converter=jnp.asarray)
    sigma_beta: jax.Array = eqx.field(default=0.02, converter=jnp.asarray)
    min_range: jax.Array = eqx.field(default=0.0, converter=jnp.asarray)
    max_range: jax.Array = eqx.field(default=50.0, converter=jnp.asarray)
    half_fov: jax.Array = eqx.field(default=math.pi / 2, converter=jnp.asarray)
    view_margin: jax.Array = eqx.field(default=0.0, converter=jnp.asarray)
    view_margin_angle: jax.Array = eqx.field(default=0.0, converter=jnp.asarray)

    def h(self, x, m, aux=None):
        d = m - x[:2]
        r = jnp.sqrt(jnp.maximum(d[0] ** 2 + d[1] ** 2, 1e-24))
        b = jnp.arctan2(d[1], d[0]) - x[2]
        return jnp.stack([r, jnp.arctan2(jnp.sin(b), jnp.cos(b))])

    def landmark_from(self, x, z, aux=None):
        a = x[2] + z[1]
        return x[:2] + z[0] * jnp.stack([jnp.cos(a), jnp.sin(a)])

    def noise_cov(self):
        return jnp.diag(jnp.stack([self.sigma_r**2, self.sigma_beta**2]))

    def visible(self, x, m):
        r, b = self.h(x, m)
        return (
            (r > self.min_range + self.view_margin)
            & (r < self.max_range - self.view_margin)
            & (jnp.abs(b) < self.half_fov - self.view_margin_angle)
        )


class Offset(AbstractMeasurementModel):
    """A linear measurement: the landmark's offset from the sensor in the world frame, ``z = m - p``."""

    sigma: jax.Array = eqx.field(default=0.2, converter=jnp.asarray)
    radius: jax.Array = eqx.field(default=1e9, converter=jnp.asarray)

    def h(self, x, m, aux=None):
        return m - x[:2]

    def landmark_from(self, x, z, aux=None):
        return x[:2] + z

    def noise_cov(self):
        return jnp.square(self.sigma) * jnp.eye(2)

    def visible(self, x, m):
        return jnp.sum(jnp.square(m - x[:2])) < jnp.square(self.radius)


class Drift(AbstractMotionModel):
    """Linear-Gaussian motion: ``x' = x + (u dt, 0) + w``, ``w ~ N(0, dt diag(q_xy^2, q_xy^2, q_phi^2))``."""

    control_dim: ClassVar[int] = 2
    noise: ClassVar[str] = "additive"

    q_xy: jax.Array = eqx.field(default=0.3, converter=jnp.asarray)
    q_phi: jax.Array = eqx.field(default=0.01, converter=jnp.asarray)

    def step(self, x, u, dt):
        return jnp.stack([x[0] + u[0] * dt, x[1] + u[1] * dt, x[2]])

    def noise_sqrt(self, dt):
        r = jnp.sqrt(jnp.asarray(dt, dtype=float))
        return jnp.diag(jnp.stack([self.q_xy * r, self.q_xy * r, self.q_phi * r]))


# ---------------------------------------------------------------------------------------------
# (a) the generic path against the built-in range-bearing fast path


def _sim_config(method, extra=()):
    return load_config(
        None,
        [
            "data.kind=simulated",
            "sim.duration=25",
            f"filter.method={method}",
            "filter.n_particles=6",
            "map.occlusion=false",
            "output.plots=false",
            *extra,
        ],
    )


def _plain_like(rb: RangeBearing) -> PlainRangeBearing:
    return PlainRangeBearing(**{f.name: getattr(rb, f.name) for f in dataclasses.fields(RangeBearing)})


@pytest.mark.slow
@pytest.mark.parametrize("method", ["ekf_slam", "fastslam2"])
def test_model_written_in_a_test_module_equals_the_builtin_range_bearing(method):
    """The same run (to rounding) from the generic path with a model written here as from the
    built-in model's hand-specialised path: association, proposal, landmark updates, management."""
    cfg = _sim_config(method)
    raw = simulate(cfg.sim, cfg.vehicle)
    seg = make_segments(raw, max_range=cfg.data.max_range)
    static, params = settings_from_config(cfg, seg.k_max)
    assert isinstance(params.measurement, RangeBearing)
    a = run_filter(static, params, seg, 3)
    b = run_filter(static, params._replace(measurement=_plain_like(params.measurement)), seg, 3)
    assert int(np.asarray(a.outputs.n_landmarks)[-1]) > 5
    np.testing.assert_array_equal(np.asarray(b.outputs.n_landmarks), np.asarray(a.outputs.n_landmarks))
    np.testing.assert_allclose(np.asarray(b.outputs.best_pose), np.asarray(a.outputs.best_pose), atol=1e-9)
    np.testing.assert_allclose(np.asarray(b.outputs.mean_pose), np.asarray(a.outputs.mean_pose), atol=1e-9)


@pytest.mark.slow
def test_generic_innovation_information_equals_the_range_bearing_components():
    rng = np.random.default_rng(0)
    x = jnp.array([1.0, -2.0, 0.4])
    A = rng.normal(size=(3, 3))
    P = jnp.asarray(A @ A.T * 0.1 + 0.01 * np.eye(3))
    mean = jnp.asarray(rng.uniform(-20, 20, (7, 2)))
    B = rng.normal(size=(7, 2, 2))
    cov = jnp.asarray(B @ np.swapaxes(B, 1, 2) * 0.2 + 0.05 * np.eye(2))
    rb = RangeBearing(sigma_r=0.3, sigma_beta=0.02)
    (zr, zb), (a00, a01, a11) = innovation_information(x, P, mean, cov, rb.R, rb)
    z_hat, s_inv = innovation_information(x, P, mean, cov, rb.R, _plain_like(rb))
    np.testing.assert_allclose(z_hat, np.stack([zr, zb], -1), atol=1e-12)
    np.testing.assert_allclose(s_inv, np.stack([np.stack([a00, a01], -1), np.stack([a01, a11], -1)], -2), rtol=1e-9)


# ---------------------------------------------------------------------------------------------
# (b) linear-Gaussian models: EKF-SLAM against a Kalman filter, a particle method approaching it

LANDMARKS = np.array([[3.0, 4.0], [8.0, -2.0], [12.0, 6.0], [-3.0, 5.0], [15.0, -1.0]])
Q_XY, Q_PHI, SIGMA, INIT_COV = 0.3, 0.01, 0.2, 1e-6


def _linear_log(n_seg=40, dt=0.25, seed=1, per_scan=5):
    """A log of the linear models: two DR pieces per segment, then (up to ``per_scan``) landmarks
    within 9 m of the true position detected (``z = m - p + v``), with their ids."""
    rng = np.random.default_rng(seed)
    k_max, n = per_scan, len(LANDMARKS)
    u = np.stack([np.full(n_seg, 1.0), 0.6 * np.sin(np.arange(n_seg) / 6.0)], -1)
    p = np.zeros(2)
    z = np.zeros((n_seg, k_max, 2))
    z_mask = np.zeros((n_seg, k_max), bool)
    z_id = np.full((n_seg, k_max), -1, np.int32)
    for t in range(n_seg):
        for _ in range(2):
            p = p + u[t] * dt / 2 + Q_XY * math.sqrt(dt / 2) * rng.normal(size=2)
        near = [j for j in rng.permutation(n) if np.hypot(*(LANDMARKS[j] - p)) < 9.0][:k_max]
        for k, j in enumerate(near):
            z[t, k] = LANDMARKS[j] - p + SIGMA * rng.normal(size=2)
            z_mask[t, k], z_id[t, k] = True, j
    seg = Segments(
        time=np.arange(1, n_seg + 1) * dt,
        dt=np.full((n_seg, 2), dt / 2),
        u=np.repeat(u[:, None], 2, 1),
        dr_mask=np.ones((n_seg, 2), bool),
        z=z,
        z_mask=z_mask,
        diam=np.zeros((n_seg, k_max)),
        is_scan=np.ones(n_seg, bool),
        z_id=z_id,
    )
    return jax.tree.map(jnp.asarray, seg)


def _kalman_filter(seg: Segments):
    """The Kalman filter on the joint state ``(p, phi, m_j ...)``, landmarks appended at their first
    detection (``m = p + z``: the exact posterior under a flat prior on the landmark) and updated in
    the order of the detections."""
    seg = jax.tree.map(np.asarray, seg)
    mean, cov, slot = np.zeros(3), INIT_COV * np.eye(3), {}
    for t in range(seg.time.shape[0]):
        for dt, u, ok in zip(seg.dt[t], seg.u[t], seg.dr_mask[t]):
            if ok:
                mean[:2] += u * dt
                cov[:3, :3] += np.diag([Q_XY**2 * dt, Q_XY**2 * dt, Q_PHI**2 * dt])
        for k in np.flatnonzero(seg.z_mask[t]):
            j, zk, n = int(seg.z_id[t, k]), seg.z[t, k], mean.shape[0]
            H = np.zeros((2, n))
            H[:, :2] = -np.eye(2)
            if j in slot:
                H[:, slot[j] : slot[j] + 2] = np.eye(2)
                S = H @ cov @ H.T + SIGMA**2 * np.eye(2)
                K = cov @ H.T @ np.linalg.inv(S)
                mean = mean + K @ (zk - H @ mean)
                cov = (np.eye(n) - K @ H) @ cov
                cov = 0.5 * (cov + cov.T)
            else:
                slot[j] = n
                G = np.zeros((2, n))
                G[:, :2] = np.eye(2)
                mean = np.concatenate([mean, mean[:2] + zk])
                cross = G @ cov
                cov = np.block([[cov, cross.T], [cross, cross @ G.T + SIGMA**2 * np.eye(2)]])
    landmarks = {j: (mean[i : i + 2], cov[i : i + 2, i : i + 2]) for j, i in slot.items()}
    return mean[:3], cov[:3, :3], landmarks


def _linear_params(method, n_particles, seg, extra=()):
    cfg = load_config(
        None,
        [
            f"filter.method={method}",
            f"filter.n_particles={n_particles}",
            "filter.association=known",
            "map.manage=false",
            f"filter.init_cov={INIT_COV}",
            "filter.capacity=8",
            "filter.estimate=mean",
            "filter.window=8",
            *extra,
        ],
    )
    static, params = settings_from_config(cfg, seg.k_max)
    return static, params._replace(motion=Drift(Q_XY, Q_PHI), measurement=Offset(SIGMA))


@pytest.mark.slow
def test_ekf_slam_with_linear_models_equals_the_kalman_filter():
    seg = _linear_log()
    static, params = _linear_params("ekf_slam", 1, seg)
    run = run_filter(static, params, seg, 0)
    x, P, landmarks = _kalman_filter(seg)
    assert len(landmarks) == len(LANDMARKS)
    mean, cov = np.asarray(run.state.mean), np.asarray(run.state.cov)
    np.testing.assert_allclose(mean[:3], x, atol=1e-8)
    np.testing.assert_allclose(cov[:3, :3], P, atol=1e-8)
    ident = np.asarray(run.state.landmarks.ident)
    active = np.asarray(run.state.landmarks.active)
    for s in np.flatnonzero(active):
        m, C = landmarks[int(ident[s])]
        np.testing.assert_allclose(mean[3 + 2 * s : 5 + 2 * s], m, atol=1e-8)
        np.testing.assert_allclose(cov[3 + 2 * s : 5 + 2 * s, 3 + 2 * s : 5 + 2 * s], C, atol=1e-8)


@pytest.mark.slow
def test_particle_method_with_linear_models_approaches_the_kalman_filter():
    """FastSLAM 2.0 (Rao-Blackwellised, known association) with one detection per scan and the
    weight at the prior (with linear-Gaussian models: the optimal proposal and its exact weight):
    the particles' weighted mean pose approaches the Kalman filter's as the particles grow,
    within a fraction of its standard deviation at 400 particles."""
    seg = _linear_log(n_seg=60, per_scan=1)
    x, P, _ = _kalman_filter(seg)
    sd = np.sqrt(np.diag(P))[:2]
    err = {}
    for n in (4, 400):
        static, params = _linear_params("fastslam2", n, seg, ["filter.prior=linearized", "filter.weight=marginal"])
        run = run_filter(static, params, seg, 0)
        err[n] = np.abs(np.asarray(run.outputs.mean_pose)[-1, :2] - x[:2]) / sd
    assert np.all(err[400] < 0.25), err
    assert np.max(err[400]) < np.max(err[4]), err


# ---------------------------------------------------------------------------------------------
# (c) the generic path's Jacobians against finite differences


def _central_difference(f, a, eps=1e-6):
    a = np.asarray(a, float)
    cols = []
    for i in range(a.size):
        d = np.zeros_like(a)
        d[i] = eps
        cols.append((np.asarray(f(jnp.asarray(a + d))) - np.asarray(f(jnp.asarray(a - d)))) / (2 * eps))
    return np.stack(cols, -1)


@pytest.mark.parametrize("model", [PlainRangeBearing(), Offset()], ids=["range_bearing", "offset"])
@pytest.mark.slow
def test_autodiff_jacobians_match_finite_differences(model):
    rng = np.random.default_rng(3)
    for _ in range(5):
        x = jnp.asarray(rng.uniform([-5, -5, -3], [5, 5, 3]))
        m = jnp.asarray(rng.uniform(-15, 15, 2))
        z = model.h(x, m)
        Gx, Gm = model.jacobians(x, m)
        Ix, Iz = model.inverse_jacobians(x, z)
        np.testing.assert_allclose(model.landmark_from(x, z), m, atol=1e-9)
        np.testing.assert_allclose(Gx, _central_difference(lambda a, m=m: model.h(a, m), x), atol=1e-7)
        np.testing.assert_allclose(Gm, _central_difference(lambda a, x=x: model.h(x, a), m), atol=1e-7)
        np.testing.assert_allclose(Ix, _central_difference(lambda a, z=z: model.landmark_from(a, z), x), atol=1e-7)
        np.testing.assert_allclose(Iz, _central_difference(lambda a, x=x: model.landmark_from(x, a), z), atol=1e-7)


# ---------------------------------------------------------------------------------------------
# configuration


def test_model_named_by_import_path_with_its_parameters():
    cfg = load_config(
        None,
        ["model.measurement=tests.unit.models.test_measurement_models:Offset", "model.measurement_params.sigma=0.5"],
    )
    _, params = settings_from_config(cfg, 4)
    assert isinstance(params.measurement, Offset)
    np.testing.assert_allclose(params.R, 0.25 * np.eye(2))


def test_bad_measurement_models_are_config_errors():
    with pytest.raises(ConfigError, match="model.measurement"):
        load_config(None, ["model.measurement=no_such_model"])
    with pytest.raises(ConfigError, match="model.measurement"):
        load_config(None, ["model.measurement=json:loads"])  # importable, not a measurement model
    with pytest.raises(ConfigError, match="model.measurement_params"):
        load_config(None, ["model.measurement_params.sigma_r=1"])  # the built-in reads section noise
    with pytest.raises(ConfigError, match="model.measurement_params"):
        load_config(
            None,
            ["model.measurement=tests.unit.models.test_measurement_models:Offset", "model.measurement_params.nope=1"],
        )
    with pytest.raises(ConfigError, match="model.measurement.*nasrukf"):
        load_config(
            None, ["model.measurement=tests.unit.models.test_measurement_models:Offset", "filter.method=nasrukf"]
        )
