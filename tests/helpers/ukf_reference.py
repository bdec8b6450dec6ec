"""A dense (non-square-root) unscented Kalman filter in numpy: the reference the square-root
filter is tested against (tests/unit/methods/test_srukf.py, tests/unit/methods/test_nasrukf.py)."""

import math

import jax.numpy as jnp
import numpy as np

ALPHA, BETA, KAPPA = 0.9, 2.0, 0.0


def random_spd(rng, n, scale=1.0):
    A = rng.normal(size=(n, n)) * scale
    return A @ A.T / n + 0.1 * scale**2 * np.eye(n)


def wrap(a):
    return (a + np.pi) % (2 * np.pi) - np.pi


def ut_weights(n):
    lam = ALPHA**2 * (n + KAPPA) - n
    wm = np.full(2 * n + 1, 1.0 / (2 * (n + lam)))
    wc = wm.copy()
    wm[0] = lam / (n + lam)
    wc[0] = wm[0] + 1 - ALPHA**2 + BETA
    return wm, wc, math.sqrt(n + lam)


def dense_sigma_points(x, P, C=None):
    """Sigma points along the columns of the lower Cholesky factor ``C`` of ``P`` (given for a
    singular ``P``)."""
    n = x.shape[0]
    wm, wc, gamma = ut_weights(n)
    C = np.linalg.cholesky(P) if C is None else C
    return np.concatenate([x[None], x + gamma * C.T, x - gamma * C.T]), wm, wc


def dense_transform(x, P, f, Q, angles=(), C=None):
    """Standard UKF time update with the noise augmented (dense covariances; ``C``: the lower
    Cholesky factor of a singular ``P``)."""
    n, q = x.shape[0], Q.shape[0]
    Pa = np.zeros((n + q, n + q))
    Pa[:n, :n], Pa[n:, n:] = P, Q
    Ca = None
    if C is not None:
        Ca = np.zeros((n + q, n + q))
        Ca[:n, :n], Ca[n:, n:] = C, np.linalg.cholesky(Q)
    X, wm, wc = dense_sigma_points(np.concatenate([x, np.zeros(q)]), Pa, Ca)
    Y = np.stack([np.asarray(f(jnp.asarray(p[:n]), jnp.asarray(p[n:]))) for p in X])
    dev = Y - Y[0]
    for i in angles:
        dev[:, i] = wrap(dev[:, i])
    mean = Y[0] + wm @ dev
    for i in angles:
        mean[i] = wrap(mean[i])
    D = dev - wm @ dev
    return mean, (wc[:, None] * D).T @ D


def dense_update(x, P, h, z, R, z_angles=()):
    """Standard UKF measurement update (dense): K = Pxz Pzz^-1, P - K Pzz K'."""
    X, wm, wc = dense_sigma_points(x, P)
    Z = np.stack([np.asarray(h(jnp.asarray(p))) for p in X])
    dev = Z - Z[0]
    for i in z_angles:
        dev[:, i] = wrap(dev[:, i])
    z_hat = Z[0] + wm @ dev
    dz = dev - wm @ dev
    Pzz = (wc[:, None] * dz).T @ dz + R
    Pxz = (wc[:, None] * (X - x)).T @ dz
    K = Pxz @ np.linalg.inv(Pzz)
    nu = z - z_hat
    for i in z_angles:
        nu[i] = wrap(nu[i])
    return x + K @ nu, P - K @ Pzz @ K.T
