"""Gauss-Newton MAP of prior x likelihood (used as NANO's optional initialisation)."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import optimistix as optx

from .._linalg import chol2, chol3, inv3, sym
from ._base import pose_difference, wrap_pose
from ._natural_gradient import Gaussian


def gauss_newton_map(prior: Gaussian, residual, weights, mask, *, max_iter: int = 10, tol: float = 1e-8) -> Gaussian:
    """MAP of ``N(x; x0, P0) prod_k N(r_k(x); 0, W_k^-1)`` by optimistix Gauss-Newton, with the Laplace precision.

    The least-squares residual stacks the whitened prior term ``U0 (x - x0)`` (``U0' U0 = L0``)
    and the whitened measurement residuals ``U_k r_k(x)``.
    """
    U0 = chol3(prior.precision).T
    Uk = jnp.swapaxes(chol2(weights), -1, -2) * mask[:, None, None]

    def fn(x, args):
        rp = U0 @ pose_difference(x, prior.mean)
        rm = jnp.einsum("kde,ke->kd", Uk, residual(x)).reshape(-1)
        return jnp.concatenate([rp, rm])

    sol = optx.least_squares(fn, optx.GaussNewton(rtol=tol, atol=tol), prior.mean, max_steps=max_iter, throw=False)
    x = wrap_pose(jnp.where(jnp.all(jnp.isfinite(sol.value)), sol.value, prior.mean))
    J = jax.jacfwd(lambda y: fn(y, None))(x)
    lam = sym(J.T @ J)
    return Gaussian(x, lam, sym(inv3(lam)))
