"""The prior: the structured unscented transform equals the generic augmented one; padding is a
no-op; a rigid motion of the start pose moves the prior with it, so the shared relative prior
placed at a particle's pose equals that particle's own prior."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from nanoslam_jax.app.config import load_config
from nanoslam_jax.methods import LinearisedPrior, UnscentedPrior, compose_prior, predict, relative_prior
from nanoslam_jax.app.filters import settings_from_config
from nanoslam_jax.models import vehicle_step
from nanoslam_jax.lib.quadrature import Unscented

_, PARAMS = settings_from_config(load_config("configs/victoria_park_nano.yaml"), 14)
predict_jit = jax.jit(predict, static_argnums=6)  # compiled once per prior and shape for the tests below


def generic_ut(x, P, u, dt, params):
    """Textbook augmented UT: 11 points over (pose, control noise), each through the full model,
    heading deviations wrapped around the centre point's. The square root is the Cholesky factor
    of the augmented covariance with the state ordered (heading, x, y, control noise)."""
    Pa = jnp.zeros((5, 5)).at[:3, :3].set(P).at[3:, 3:].set(params.motion.noise_cov(dt))
    order, back = np.array([2, 0, 1, 3, 4]), np.array([1, 2, 0, 3, 4])
    xi, wm, wc = Unscented(params.ut_alpha, params.ut_beta, params.ut_kappa).unit_points(5)
    X = jnp.concatenate([x, jnp.zeros(2)]) + (xi @ jnp.linalg.cholesky(Pa[order][:, order]).T)[:, back]
    Y = jax.vmap(lambda a: vehicle_step(a[:3], u + a[3:], dt, params.motion.vehicle))(X)
    d = Y - Y[0]
    dev = d.at[:, 2].set(jnp.arctan2(jnp.sin(d[:, 2]), jnp.cos(d[:, 2])))
    delta = wm @ dev
    e = dev - delta
    return Y[0] + delta, (e.T * wc) @ e


@pytest.mark.parametrize("seed", range(6))
@pytest.mark.slow
def test_structured_unscented_prior_equals_generic_augmented_ut(seed):
    rng = np.random.default_rng(seed)
    x = jnp.asarray(rng.normal(size=3) * [10, 10, 3])
    A = rng.normal(size=(3, 3)) * 0.1
    P = jnp.asarray(A @ A.T + 1e-4 * np.eye(3))
    u = jnp.asarray([rng.uniform(0, 5), rng.uniform(-0.4, 0.4)])
    m1, P1 = predict(x, P, jnp.array([0.025]), u[None], jnp.array([True]), PARAMS, UnscentedPrior())
    m2, P2 = generic_ut(x, P, u, 0.025, PARAMS)
    d = np.array(m1 - m2)
    d[2] = np.angle(np.exp(1j * d[2]))
    np.testing.assert_allclose(d, 0.0, atol=1e-12)
    np.testing.assert_allclose(P1, P2, atol=1e-12)


@pytest.mark.parametrize("kind", [UnscentedPrior(), LinearisedPrior()], ids=["unscented", "linearized"])
@pytest.mark.slow
def test_padding_pieces_leave_the_prior_unchanged(kind):
    x, P = jnp.asarray([1.0, 2.0, 3.1]), jnp.diag(jnp.asarray([0.1, 0.2, 0.01]))
    dt = jnp.asarray([0.025, 0.0, 0.0])
    u = jnp.asarray([[3.0, 0.1], [9.0, 0.3], [9.0, 0.3]])
    one = predict(x, P, dt[:1], u[:1], jnp.array([True]), PARAMS, kind)
    padded = predict(x, P, dt, u, jnp.array([True, False, False]), PARAMS, kind)
    for a, b in zip(one, padded):
        np.testing.assert_array_equal(a, b)


@pytest.mark.slow
def test_unscented_and_linearized_priors_agree_for_small_noise():
    """With small control noise the model is nearly linear over the spread: both priors agree."""
    _, p = settings_from_config(load_config(None, ["noise.sigma_v=0.01", "noise.sigma_alpha_deg=0.05"]), 14)
    x, P = jnp.asarray([0.0, 0.0, 0.3]), 1e-6 * jnp.eye(3)
    dt = jnp.full(9, 0.025)
    u = jnp.tile(jnp.asarray([4.0, 0.2]), (9, 1))
    mu, Pu = predict(x, P, dt, u, dt > 0, p, UnscentedPrior())
    ml, Pl = predict(x, P, dt, u, dt > 0, p, LinearisedPrior())
    # They differ by the second-order (curvature) term of the mean, O(sigma^2) ~ 1e-6 here.
    np.testing.assert_allclose(mu, ml, atol=1e-5)
    np.testing.assert_allclose(Pu, Pl, rtol=1e-3, atol=1e-14)


def _rigid(x, t, theta):
    """The pose ``x`` moved by the rigid motion (rotation ``theta`` about the origin, then ``t``)."""
    c, s = np.cos(theta), np.sin(theta)
    return np.array([t[0] + c * x[0] - s * x[1], t[1] + s * x[0] + c * x[1], x[2] + theta])


@pytest.mark.parametrize("kind", [UnscentedPrior(), LinearisedPrior()], ids=["unscented", "linearized"])
@pytest.mark.parametrize("seed", range(3))
def test_prior_commutes_with_rigid_motions(kind, seed):
    """Moving the start pose by a rigid motion moves the prior mean by it and rotates the
    covariance, for any start covariance (the model is x (+) delta(u); see filter/_prior.py)."""
    rng = np.random.default_rng(seed)
    x = rng.normal(size=3) * [10, 10, 3]
    B = rng.normal(size=(3, 3)) * 0.05
    P = B @ B.T + 1e-6 * np.eye(3)
    dt = jnp.full(10, 0.025)
    u = jnp.asarray(np.c_[rng.uniform(0, 5, 10), rng.uniform(-0.4, 0.4, 10)])
    mask = jnp.asarray(rng.uniform(size=10) < 0.8)
    t, theta = rng.normal(size=2) * 100, rng.uniform(-np.pi, np.pi)
    A = np.eye(3)
    A[:2, :2] = [[np.cos(theta), -np.sin(theta)], [np.sin(theta), np.cos(theta)]]
    m1, P1 = predict_jit(jnp.asarray(x), jnp.asarray(P), dt, u, mask, PARAMS, kind)
    m2, P2 = predict_jit(jnp.asarray(_rigid(x, t, theta)), jnp.asarray(A @ P @ A.T), dt, u, mask, PARAMS, kind)
    d = np.asarray(m2) - _rigid(np.asarray(m1), t, theta)
    d[2] = np.angle(np.exp(1j * d[2]))
    np.testing.assert_allclose(d, 0.0, atol=1e-11)
    np.testing.assert_allclose(P2, A @ np.asarray(P1) @ A.T, atol=1e-15, rtol=1e-10)


@pytest.mark.parametrize("kind", [UnscentedPrior(), LinearisedPrior()], ids=["unscented", "linearized"])
@pytest.mark.slow
def test_relative_prior_placed_at_a_pose_equals_that_poses_prior(kind):
    """The shared prior of ``filter.prior_cov: reset``: one propagation from the origin, placed at
    each particle's pose, gives each particle's own propagation from ``init_cov * I``."""
    rng = np.random.default_rng(7)
    dt = jnp.asarray(np.r_[np.full(9, 0.025), 0.0, 0.0, 0.0])
    u = jnp.asarray(np.c_[rng.uniform(0, 5, 12), rng.uniform(-0.4, 0.4, 12)])
    rel = relative_prior(dt, u, dt > 0, PARAMS, kind)
    start = PARAMS.init_cov * jnp.eye(3)
    for x in rng.normal(size=(5, 3)) * [100, 100, 3]:
        m1, P1 = predict_jit(jnp.asarray(x), start, dt, u, dt > 0, PARAMS, kind)
        m2, P2 = jax.jit(compose_prior)(jnp.asarray(x), *rel)
        d = np.array(m2 - m1)
        d[2] = np.angle(np.exp(1j * d[2]))
        np.testing.assert_allclose(d, 0.0, atol=1e-12)
        np.testing.assert_allclose(P2, P1, atol=1e-15, rtol=1e-10)
        assert np.linalg.eigvalsh(np.asarray(P1)).min() > 0
