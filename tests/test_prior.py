"""The prior: the structured unscented transform equals the generic augmented one; padding is a no-op."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from nanoslam_jax.config import load_config
from nanoslam_jax.filter import predict, settings_from_config
from nanoslam_jax.models import vehicle_step
from nanoslam_jax.quadrature import Unscented

_, PARAMS = settings_from_config(load_config("configs/victoria_park_nano.yaml"), 14)


def generic_ut(x, P, u, dt, params):
    """Textbook augmented UT: 11 points over (pose, control noise), each through the full model,
    heading deviations wrapped around the centre point's."""
    Pa = jnp.zeros((5, 5)).at[:3, :3].set(P).at[3:, 3:].set(params.Q)
    xi, wm, wc = Unscented(params.ut_alpha, params.ut_beta, params.ut_kappa).unit_points(5)
    X = jnp.concatenate([x, jnp.zeros(2)]) + xi @ jnp.linalg.cholesky(Pa).T
    Y = jax.vmap(lambda a: vehicle_step(a[:3], u + a[3:], dt, params.vehicle))(X)
    d = Y - Y[0]
    dev = d.at[:, 2].set(jnp.arctan2(jnp.sin(d[:, 2]), jnp.cos(d[:, 2])))
    delta = wm @ dev
    e = dev - delta
    return Y[0] + delta, (e.T * wc) @ e


@pytest.mark.parametrize("seed", range(6))
def test_structured_unscented_prior_equals_generic_augmented_ut(seed):
    rng = np.random.default_rng(seed)
    x = jnp.asarray(rng.normal(size=3) * [10, 10, 3])
    A = rng.normal(size=(3, 3)) * 0.1
    P = jnp.asarray(A @ A.T + 1e-4 * np.eye(3))
    u = jnp.asarray([rng.uniform(0, 5), rng.uniform(-0.4, 0.4)])
    m1, P1 = predict(x, P, jnp.array([0.025]), u[None], jnp.array([True]), PARAMS, "unscented")
    m2, P2 = generic_ut(x, P, u, 0.025, PARAMS)
    d = np.array(m1 - m2)
    d[2] = np.angle(np.exp(1j * d[2]))
    np.testing.assert_allclose(d, 0.0, atol=1e-12)
    np.testing.assert_allclose(P1, P2, atol=1e-12)


@pytest.mark.parametrize("kind", ["unscented", "linearized"])
def test_padding_pieces_leave_the_prior_unchanged(kind):
    x, P = jnp.asarray([1.0, 2.0, 3.1]), jnp.diag(jnp.asarray([0.1, 0.2, 0.01]))
    dt = jnp.asarray([0.025, 0.0, 0.0])
    u = jnp.asarray([[3.0, 0.1], [9.0, 0.3], [9.0, 0.3]])
    one = predict(x, P, dt[:1], u[:1], jnp.array([True]), PARAMS, kind)
    padded = predict(x, P, dt, u, jnp.array([True, False, False]), PARAMS, kind)
    for a, b in zip(one, padded):
        np.testing.assert_array_equal(a, b)


def test_unscented_and_linearized_priors_agree_for_small_noise():
    """With small control noise the model is nearly linear over the spread: both priors agree."""
    _, p = settings_from_config(load_config(None, ["noise.sigma_v=0.01", "noise.sigma_alpha_deg=0.05"]), 14)
    x, P = jnp.asarray([0.0, 0.0, 0.3]), 1e-6 * jnp.eye(3)
    dt = jnp.full(9, 0.025)
    u = jnp.tile(jnp.asarray([4.0, 0.2]), (9, 1))
    mu, Pu = predict(x, P, dt, u, dt > 0, p, "unscented")
    ml, Pl = predict(x, P, dt, u, dt > 0, p, "linearized")
    # They differ by the second-order (curvature) term of the mean, O(sigma^2) ~ 1e-6 here.
    np.testing.assert_allclose(mu, ml, atol=1e-5)
    np.testing.assert_allclose(Pu, Pl, rtol=1e-3, atol=1e-14)
