"""Square-root UKF primitives and the adaptive noise estimator (nanoslam_jax/methods/gaussian/_srukf.py).

Independent truths: re-factorisation with numpy (Cholesky update/downdate, QR factor); a standard
(non-square-root) unscented Kalman filter written here in numpy with dense covariances; the Kalman
filter for linear models; the closed form of the forgetting-factor recursion (an exponentially
weighted mean); the paper's eq. 11 evaluated densely.
"""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from nanoslam_jax.methods.gaussian import _srukf
from nanoslam_jax.lib.quadrature import Unscented
from tests.helpers.ukf_reference import ALPHA, BETA, KAPPA, dense_transform, dense_update, random_spd, ut_weights

RULE = Unscented(ALPHA, BETA, KAPPA)

chol_rank_one = jax.jit(_srukf.chol_rank_one)
qr_factor = jax.jit(_srukf.qr_factor)


def sr_update(x, P, h, z, R, z_angles=()):
    L = np.linalg.cholesky(P)
    pred = _srukf.predict_measurement(jnp.asarray(x), jnp.asarray(L), h, RULE, z_angles)
    xn, Ln, _, Sz = _srukf.measurement_update(
        jnp.asarray(x), jnp.asarray(L), pred, jnp.asarray(z), jnp.asarray(np.linalg.cholesky(R)), (), z_angles
    )
    return np.asarray(xn), np.asarray(Ln), np.asarray(Sz)


# --------------------------------------------------------------------------- Cholesky and QR


@pytest.mark.parametrize("n", [1, 2, 3, 5, 8])
@pytest.mark.parametrize("weight", [0.8, 2.5, -0.05, -0.4])
def test_rank_one_update_and_downdate_equal_refactorisation(n, weight):
    rng = np.random.default_rng(n * 10 + int(10 * abs(weight)))
    P = random_spd(rng, n)
    v = rng.normal(size=n)
    if weight < 0:  # a downdate that keeps P positive definite: |w| v'P^-1 v < 1
        v = v * 0.9 / math.sqrt(-weight * v @ np.linalg.solve(P, v))
    ref = np.linalg.cholesky(P + weight * np.outer(v, v))
    out = np.asarray(chol_rank_one(jnp.asarray(np.linalg.cholesky(P)), jnp.asarray(v), weight))
    np.testing.assert_allclose(out, ref, rtol=0, atol=1e-12)
    assert np.array_equal(np.triu(out, 1), np.zeros((n, n)))


def test_rank_update_of_a_singular_factor_and_zero_weight():
    """An update of a singular factor (the pose-start template starts singular) is still exact;
    weight 0 changes nothing."""
    rng = np.random.default_rng(5)
    B = rng.normal(size=(4, 2))
    P = B @ B.T  # rank 2
    Rb = np.linalg.qr(B.T, mode="r")
    L = np.zeros((4, 4))
    L[:, :2] = (Rb * np.sign(np.diag(Rb))[:, None]).T
    assert np.allclose(L @ L.T, P)
    V = rng.normal(size=(4, 3))
    out = np.asarray(jax.jit(_srukf.chol_rank_update)(jnp.asarray(L), jnp.asarray(V), 1.0))
    np.testing.assert_allclose(out @ out.T, P + V @ V.T, rtol=0, atol=1e-12)
    np.testing.assert_allclose(out, np.linalg.cholesky(P + V @ V.T), atol=1e-12)
    np.testing.assert_array_equal(np.asarray(chol_rank_one(jnp.asarray(L), jnp.asarray(V[:, 0]), 0.0)), L)


def test_downdate_that_would_be_indefinite_stays_finite():
    """Removing more than the matrix holds cannot give a Cholesky factor: the result stays finite
    and lower triangular with a non-negative diagonal (the offending column is left unrotated)."""
    L = np.linalg.cholesky(np.diag([1.0, 2.0, 3.0]))
    out = np.asarray(chol_rank_one(jnp.asarray(L), jnp.array([2.0, 0.1, 0.1]), -1.0))
    assert np.all(np.isfinite(out)) and np.all(np.diag(out) >= 0)
    assert np.array_equal(np.triu(out, 1), np.zeros((3, 3)))


@pytest.mark.parametrize("shape", [(2, 12), (5, 10), (6, 16), (3, 3)])
def test_qr_factor_is_the_cholesky_factor_of_m_mt(shape):
    rng = np.random.default_rng(shape[0] * shape[1])
    M = rng.normal(size=shape)
    np.testing.assert_allclose(np.asarray(qr_factor(jnp.asarray(M))), np.linalg.cholesky(M @ M.T), atol=1e-12)


def test_qr_factor_rejects_too_few_columns():
    with pytest.raises(ValueError, match="columns"):
        _srukf.qr_factor(jnp.ones((3, 2)))


# --------------------------------------------------------------------------- SR-UKF = UKF = KF


def f_nonlinear(x, w):
    """A strongly nonlinear 4-D map with 2-D non-additive noise (component 2 an angle)."""
    return jnp.stack(
        [
            x[0] + jnp.cos(x[2] + w[1]) * (1.0 + x[3] + w[0]),
            x[1] + jnp.sin(x[2]) * x[3] ** 2,
            x[2] + 0.3 * jnp.sin(x[0]) + w[1],
            x[3] * jnp.exp(-0.2 * x[1]) + 0.5 * w[0] * w[1],
        ]
    )


def h_nonlinear(x):
    """Range and bearing of (x0, x1) seen from (x3, 0) with heading x2 (angle output 1)."""
    dx, dy = x[0] - x[3], x[1]
    return jnp.stack([jnp.sqrt(dx * dx + dy * dy), jnp.arctan2(dy, dx) - x[2]])


@pytest.mark.parametrize("seed", range(4))
@pytest.mark.slow
def test_srukf_transform_equals_the_standard_ukf(seed):
    rng = np.random.default_rng(seed)
    x = rng.normal(size=4) + np.array([0, 0, 2.5, 1.0])
    P = random_spd(rng, 4, 0.4)
    Q = random_spd(rng, 2, 0.3)
    mean_ref, cov_ref = dense_transform(x, P, f_nonlinear, Q, angles=(2,))
    mean, L = jax.jit(_srukf.srukf_transform, static_argnums=(2, 5))(
        jnp.asarray(x), jnp.asarray(np.linalg.cholesky(P)), f_nonlinear, jnp.asarray(np.linalg.cholesky(Q)), RULE, (2,)
    )
    np.testing.assert_allclose(np.asarray(mean), mean_ref, rtol=0, atol=1e-9)
    np.testing.assert_allclose(np.asarray(L) @ np.asarray(L).T, cov_ref, rtol=0, atol=1e-9)


@pytest.mark.parametrize("seed", range(4))
@pytest.mark.slow
def test_srukf_measurement_update_equals_the_standard_ukf(seed):
    rng = np.random.default_rng(100 + seed)
    x = np.array([6.0, 3.0, 0.2, -1.0]) + rng.normal(size=4) * 0.5
    P = random_spd(rng, 4, 0.5)
    R = np.diag([0.2, 0.01])
    z = np.asarray(h_nonlinear(jnp.asarray(x))) + rng.normal(size=2) * [0.5, 0.1]
    mean_ref, cov_ref = dense_update(x, P, h_nonlinear, z, R, (1,))
    mean, L, _ = sr_update(x, P, h_nonlinear, z, R, (1,))
    np.testing.assert_allclose(mean, mean_ref, rtol=0, atol=1e-9)
    np.testing.assert_allclose(L @ L.T, cov_ref, rtol=0, atol=1e-9)
    # The update really moved the state and shrank the covariance (the check is not vacuous).
    assert np.abs(mean - x).max() > 1e-2 and np.trace(cov_ref) < np.trace(P) - 1e-2


@pytest.mark.slow
def test_linear_model_square_root_ukf_equals_kalman_filter():
    """x' = F x + G w and z = H x: the SR transform is the Kalman prediction and the SR update the
    Kalman update, exactly (the unscented transform is exact for linear maps)."""
    rng = np.random.default_rng(7)
    n = 5
    F, G, H = rng.normal(size=(n, n)), rng.normal(size=(n, 2)), rng.normal(size=(2, n))
    x, P, Q, R = rng.normal(size=n), random_spd(rng, n), random_spd(rng, 2), random_spd(rng, 2, 0.5)
    z = rng.normal(size=2)
    xp_ref, Pp_ref = F @ x, F @ P @ F.T + G @ Q @ G.T
    S = H @ Pp_ref @ H.T + R
    K = Pp_ref @ H.T @ np.linalg.inv(S)
    xu_ref, Pu_ref = xp_ref + K @ (z - H @ xp_ref), Pp_ref - K @ S @ K.T

    xp, Lp = _srukf.srukf_transform(
        jnp.asarray(x),
        jnp.asarray(np.linalg.cholesky(P)),
        lambda a, w: jnp.asarray(F) @ a + jnp.asarray(G) @ w,
        jnp.asarray(np.linalg.cholesky(Q)),
        RULE,
    )
    np.testing.assert_allclose(np.asarray(xp), xp_ref, atol=1e-10)
    np.testing.assert_allclose(np.asarray(Lp @ Lp.T), Pp_ref, atol=1e-10)
    xu_d, Pu_d = dense_update(np.asarray(xp), np.asarray(Lp @ Lp.T), lambda a: jnp.asarray(H) @ a, z, R)
    xu, Lu, Sz = sr_update(np.asarray(xp), np.asarray(Lp @ Lp.T), lambda a: jnp.asarray(H) @ a, z, R)
    for mean, cov in ((xu, Lu @ Lu.T), (xu_d, Pu_d)):
        np.testing.assert_allclose(mean, xu_ref, atol=1e-10)
        np.testing.assert_allclose(cov, Pu_ref, atol=1e-10)
    np.testing.assert_allclose(Sz @ Sz.T, S, atol=1e-10)


# --------------------------------------------------------------------------- adaptive noise (eq. 11)


def test_forgetting_weights():
    b = 0.9
    assert float(_srukf.forgetting_weight(b, 0)) == pytest.approx(1.0)
    assert float(_srukf.forgetting_weight(b, 1)) == pytest.approx(0.1 / 0.19)
    assert float(_srukf.forgetting_weight(b, 10_000)) == pytest.approx(1 - b)


def test_noise_estimate_is_the_exponentially_weighted_mean():
    """With d_k = (1 - b) / (1 - b^(k+1)) the recursion is the normalised exponentially weighted
    mean of the samples nu^2 - predicted (d_0 = 1: the starting value drops out)."""
    rng = np.random.default_rng(3)
    b, k0 = 0.95, 40
    nu, pred = rng.normal(size=(k0, 2)) * [0.7, 0.05], np.abs(rng.normal(size=(k0, 2))) * [0.1, 1e-4]
    use = rng.random(k0) < 0.7
    rows, last, count = jax.jit(_srukf.adaptive_noise_rows)(
        jnp.array([5.0, 1.0]), jnp.asarray(0), jnp.asarray(nu), jnp.asarray(pred), jnp.asarray(use), b, jnp.zeros(2)
    )
    samples = (nu**2 - pred)[use]
    w = b ** np.arange(len(samples))[::-1]
    ref = w @ samples / w.sum()
    assert int(count) == use.sum()
    np.testing.assert_allclose(np.asarray(last), np.maximum(ref, 0.0), rtol=1e-12)
    np.testing.assert_array_equal(np.asarray(rows)[-1], np.asarray(last) if use[-1] else np.asarray(rows)[-1])
    # Rows not used leave the estimate as the row before had it.
    i = int(np.flatnonzero(~use)[1])
    np.testing.assert_array_equal(np.asarray(rows)[i], np.asarray(rows)[i - 1])


def test_noise_estimate_equals_the_papers_cholupdates_diagonal():
    """Eq. 11 literally: R** = (1 - d) R + d |nu||nu|', R* = R** - d sum wc_i dz_i dz_i' (the two
    cholupdate calls, evaluated densely), R = diag(R*)."""
    rng = np.random.default_rng(11)
    R = np.diag([0.5, 0.02])
    wm, wc, _ = ut_weights(5)
    dz = rng.normal(size=(11, 2)) * [0.2, 0.01]
    dz -= wm @ dz
    nu = np.array([0.9, -0.2])
    for k in (5, 50):  # at k = 0 (d = 1) R** is rank one and the paper's downdate always fails
        d = (1 - 0.97) / (1 - 0.97 ** (k + 1))
        Rss = (1 - d) * R + d * np.outer(np.abs(nu), np.abs(nu))
        Rs = Rss - d * (wc[:, None] * dz).T @ dz
        assert np.all(np.linalg.eigvalsh(Rs) > 0)  # the paper's downdates succeed here
        out = _srukf.adaptive_noise_update(
            jnp.diag(jnp.asarray(R)), k, jnp.asarray(nu), jnp.asarray(wc @ dz**2), 0.97, jnp.zeros(2)
        )
        np.testing.assert_allclose(np.asarray(out), np.diag(Rs), rtol=1e-12)


def test_noise_estimate_floor():
    out = _srukf.adaptive_noise_update(
        jnp.array([1.0, 1.0]), 0, jnp.array([0.1, 0.1]), jnp.array([0.5, 0.0]), 0.9, jnp.array([0.05, 0.001])
    )
    np.testing.assert_allclose(np.asarray(out), [0.05, 0.01])  # d_0 = 1: 0.1^2 - 0.5 floored, 0.1^2
