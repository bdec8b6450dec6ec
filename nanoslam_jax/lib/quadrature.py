"""Gaussian quadrature rules: expectations under N(mean, cov) from weighted points.

Every rule is an :class:`equinox.Module` deriving from :class:`QuadratureRule`. A rule first
builds points ``xi`` for the standard normal ``N(0, I_n)`` with mean weights ``wm`` and
covariance weights ``wc`` (:meth:`QuadratureRule.unit_points`), then maps them to
``N(mean, cov)`` with the lower Cholesky factor: ``X = mean + xi @ chol(cov).T``
(:meth:`QuadratureRule.points`). :meth:`QuadratureRule.expect` evaluates ``E[f(x)]``.

Rules (polynomial degree integrated exactly under any Gaussian):

- :class:`Cubature`: third-degree spherical-radial cubature, ``2n`` points (degree 3).
- :class:`Unscented`: ``2n + 1`` sigma points with ``alpha, beta, kappa`` (degree 3; with
  ``alpha = 1`` and ``n + kappa = 3`` also the fourth moments along each Cholesky axis).
- :class:`GaussHermite`: tensor product of ``p``-point probabilists' Gauss-Hermite rules,
  ``p**n`` points (degree ``2p - 1``).

:func:`sigma_point_stats` and :func:`sigma_point_cross_cov` turn transformed points back into
a mean and (cross-)covariance, with optional angle components (circular mean, wrapped
deviations), as unscented filters need.

The dimension ``n`` is always static (a Python int); everything else may be traced, so all of
this works under ``jit`` and ``vmap``.
"""

from __future__ import annotations

import abc
from collections.abc import Callable

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float, PyTree

from nanoslam_jax.lib._angles import wrap_angle

__all__ = [
    "CHOL_REL_JITTER",
    "RULE_NAMES",
    "QuadratureRule",
    "Cubature",
    "Unscented",
    "GaussHermite",
    "make_rule",
    "robust_cholesky",
    "sigma_point_stats",
    "sigma_point_cross_cov",
]

RULE_NAMES = ("cubature", "unscented", "gauss_hermite")

#: Jitter added to the diagonal before the Cholesky factorisation, relative to ``trace(cov)/n``.
CHOL_REL_JITTER = 1e-12


def robust_cholesky(cov: Float[ArrayLike, "n n"], rel_jitter: float = CHOL_REL_JITTER) -> Float[Array, "n n"]:
    """Lower Cholesky factor of a (near-singular) covariance.

    The matrix is symmetrised, ``(cov + cov.T) / 2``, and ``eps * I`` is added with
    ``eps = rel_jitter * trace(cov) / n + tiny`` (``tiny`` the smallest normal float of the
    dtype, so that an all-zero covariance gives an all-zero-ish factor, not NaN). The default
    relative jitter (1e-12) is far below any statistically meaningful variance yet above the
    rounding errors (about ``n * 2e-16 * trace``) that make a rank-deficient float64 covariance
    indefinite. A covariance with clearly negative eigenvalues still gives NaN.

    Args:
        cov: covariance matrix (n, n).
        rel_jitter: diagonal jitter relative to the mean variance ``trace(cov) / n``.
    """
    cov = jnp.asarray(cov)
    cov = 0.5 * (cov + cov.T)
    n = cov.shape[-1]
    eps = rel_jitter * jnp.trace(cov) / n + jnp.finfo(cov.dtype).tiny
    return jnp.linalg.cholesky(cov + eps * jnp.eye(n, dtype=cov.dtype))


class QuadratureRule(eqx.Module):
    """Abstract Gaussian quadrature rule: ``E[f(x)] ~ sum_i wm_i f(X_i)`` for ``x ~ N(mean, cov)``."""

    @abc.abstractmethod
    def unit_points(self, n: int) -> tuple[Float[Array, "m n"], Float[Array, " m"], Float[Array, " m"]]:
        """Points and weights for the standard normal ``N(0, I_n)``.

        Args:
            n: state dimension (static Python int).

        Returns:
            ``(xi, wm, wc)``: points (m, n), mean weights (m,) summing to 1, covariance weights (m,).
        """

    @abc.abstractmethod
    def num_points(self, n: int) -> int:
        """Number of points ``m`` the rule uses in dimension ``n`` (static Python int)."""

    def points(
        self, mean: Float[ArrayLike, " n"], cov: Float[ArrayLike, "n n"]
    ) -> tuple[Float[Array, "m n"], Float[Array, " m"], Float[Array, " m"]]:
        """Points and weights for ``N(mean, cov)``: ``X = mean + xi @ chol(cov).T``.

        The Cholesky factor comes from :func:`robust_cholesky` (symmetrised, tiny jitter
        relative to the trace), so near-singular covariances are fine.

        Args:
            mean: Gaussian mean (n,).
            cov: Gaussian covariance (n, n), symmetric positive semi-definite.

        Returns:
            ``(X, wm, wc)``: points (m, n), mean weights (m,), covariance weights (m,).
        """
        mean = jnp.asarray(mean)
        chol = robust_cholesky(cov)
        xi, wm, wc = self.unit_points(mean.shape[-1])
        return mean + xi @ chol.T, wm, wc

    def expect(
        self,
        f: Callable[[Float[Array, " n"]], PyTree[Array]],
        mean: Float[ArrayLike, " n"],
        cov: Float[ArrayLike, "n n"],
    ) -> PyTree[Array]:
        """Approximate ``E[f(x)]`` for ``x ~ N(mean, cov)`` as ``sum_i wm_i f(X_i)``.

        Args:
            f: function of one point (n,) returning a pytree of arrays; it is vmapped over points.
            mean: Gaussian mean (n,).
            cov: Gaussian covariance (n, n).

        Returns:
            The weighted sum, with the structure and leaf shapes of ``f``'s output.
        """
        x, wm, _ = self.points(mean, cov)
        fx = jax.vmap(f)(x)
        return jax.tree_util.tree_map(lambda y: jnp.tensordot(wm, y, axes=1), fx)


class Cubature(QuadratureRule):
    """Third-degree spherical-radial cubature: ``2n`` points ``+-sqrt(n) e_i``, weights ``1/(2n)``."""

    def unit_points(self, n: int) -> tuple[Float[Array, "m n"], Float[Array, " m"], Float[Array, " m"]]:
        """See :meth:`QuadratureRule.unit_points`; here ``wc = wm``.

        Args:
            n: state dimension (static Python int).
        """
        eye = jnp.sqrt(float(n)) * jnp.eye(n)
        xi = jnp.concatenate([eye, -eye])
        w = jnp.full((2 * n,), 1.0 / (2 * n))
        return xi, w, w

    def num_points(self, n: int) -> int:
        """``2n``.

        Args:
            n: state dimension (static Python int).
        """
        return 2 * n


class Unscented(QuadratureRule):
    """Scaled unscented transform: ``2n + 1`` sigma points.

    With ``lambda = alpha^2 (n + kappa) - n`` and ``c = n + lambda``: points ``0`` and
    ``+-sqrt(c) e_i``; ``wm_0 = lambda / c``, ``wc_0 = wm_0 + 1 - alpha^2 + beta``, all other
    weights ``1 / (2c)``. Requires ``alpha^2 (n + kappa) > 0`` (not checked: the fields may be
    traced, so one compiled program serves any values).

    Attributes:
        alpha: spread of the points (scalar, may be traced).
        beta: prior-knowledge term of the centre covariance weight (2 is optimal for Gaussians).
        kappa: secondary scaling (``n + kappa = 3`` matches the fourth moments along each axis).
    """

    alpha: Float[ArrayLike, ""] = 1.0
    beta: Float[ArrayLike, ""] = 2.0
    kappa: Float[ArrayLike, ""] = 0.0

    def unit_points(self, n: int) -> tuple[Float[Array, "m n"], Float[Array, " m"], Float[Array, " m"]]:
        """See :meth:`QuadratureRule.unit_points`; the first point is the centre.

        Args:
            n: state dimension (static Python int).
        """
        alpha2 = jnp.square(jnp.asarray(self.alpha, dtype=float))
        c = alpha2 * (n + jnp.asarray(self.kappa, dtype=float))  # c = n + lambda
        lam = c - n
        eye = jnp.sqrt(c) * jnp.eye(n)
        xi = jnp.concatenate([jnp.zeros((1, n)), eye, -eye])
        w_i = jnp.full((2 * n,), 1.0) / (2.0 * c)
        wm0 = lam / c
        wm = jnp.concatenate([wm0[None], w_i])
        wc = jnp.concatenate([(wm0 + 1.0 - alpha2 + jnp.asarray(self.beta, dtype=float))[None], w_i])
        return xi, wm, wc

    def num_points(self, n: int) -> int:
        """``2n + 1``.

        Args:
            n: state dimension (static Python int).
        """
        return 2 * n + 1


class GaussHermite(QuadratureRule):
    """Tensor-product Gauss-Hermite rule of order ``p``: ``p**n`` points, exact to degree ``2p - 1``.

    One-dimensional nodes and weights are those of the probabilists' Hermite polynomials
    (:func:`numpy.polynomial.hermite_e.hermegauss`), weights normalised to sum to 1; ``wc = wm``.

    Attributes:
        order: number of nodes per dimension ``p >= 1`` (static).
    """

    order: int = eqx.field(default=3, static=True)

    def __check_init__(self) -> None:
        if not (isinstance(self.order, (int, np.integer)) and self.order >= 1):
            raise ValueError(f"GaussHermite order must be an int >= 1, got {self.order!r}")

    def unit_points(self, n: int) -> tuple[Float[Array, "m n"], Float[Array, " m"], Float[Array, " m"]]:
        """See :meth:`QuadratureRule.unit_points` (computed in NumPy at trace time).

        Args:
            n: state dimension (static Python int).
        """
        nodes, weights = np.polynomial.hermite_e.hermegauss(self.order)
        weights = weights / weights.sum()
        grids = np.meshgrid(*([np.arange(self.order)] * n), indexing="ij")
        idx = np.stack([g.ravel() for g in grids], axis=1)  # (p**n, n) node indices
        w = jnp.asarray(np.prod(weights[idx], axis=1), dtype=float)
        return jnp.asarray(nodes[idx], dtype=float), w, w

    def num_points(self, n: int) -> int:
        """``order ** n``.

        Args:
            n: state dimension (static Python int).
        """
        return self.order**n


def make_rule(
    name: str,
    *,
    alpha: Float[ArrayLike, ""] = 1.0,
    beta: Float[ArrayLike, ""] = 2.0,
    kappa: Float[ArrayLike, ""] = 0.0,
    order: int = 3,
) -> QuadratureRule:
    """Build a rule by name.

    Args:
        name: ``"cubature"``, ``"unscented"`` or ``"gauss_hermite"``.
        alpha: unscented alpha (ignored by the other rules).
        beta: unscented beta (ignored by the other rules).
        kappa: unscented kappa (ignored by the other rules).
        order: Gauss-Hermite order p (ignored by the other rules).

    Raises:
        ValueError: for an unknown name (the message lists the allowed names).
    """
    if name == "cubature":
        return Cubature()
    if name == "unscented":
        return Unscented(alpha=alpha, beta=beta, kappa=kappa)
    if name == "gauss_hermite":
        return GaussHermite(order=order)
    raise ValueError(f"unknown quadrature rule {name!r}; expected one of {', '.join(map(repr, RULE_NAMES))}")


def _deviations(y: Float[Array, "m d"], mean: Float[Array, " d"], angle_index: int | None) -> Float[Array, "m d"]:
    """``y - mean`` with the ``angle_index`` column (if any) wrapped to (-pi, pi]."""
    d = y - mean
    if angle_index is not None:
        d = d.at[:, angle_index].set(wrap_angle(d[:, angle_index]))
    return d


def sigma_point_stats(
    y: Float[ArrayLike, "m d"],
    wm: Float[ArrayLike, " m"],
    wc: Float[ArrayLike, " m"],
    angle_index: int | None = None,
) -> tuple[Float[Array, " d"], Float[Array, "d d"]]:
    """Weighted mean and covariance of transformed points.

    Args:
        y: transformed points (m, d).
        wm: mean weights (m,).
        wc: covariance weights (m,).
        angle_index: static index of a component that is an angle, or None. Its mean is the
            circular mean ``atan2(sum wm sin, sum wm cos)`` and its deviations are wrapped to
            (-pi, pi].

    Returns:
        ``(mean (d,), cov (d, d))``, cov symmetric.
    """
    y, wm, wc = jnp.asarray(y), jnp.asarray(wm), jnp.asarray(wc)
    mean = wm @ y
    if angle_index is not None:
        a = y[:, angle_index]
        mean = mean.at[angle_index].set(jnp.arctan2(wm @ jnp.sin(a), wm @ jnp.cos(a)))
    d = _deviations(y, mean, angle_index)
    cov = (wc[:, None] * d).T @ d
    return mean, 0.5 * (cov + cov.T)


def sigma_point_cross_cov(
    x: Float[ArrayLike, "m n"],
    x_mean: Float[ArrayLike, " n"],
    y: Float[ArrayLike, "m d"],
    y_mean: Float[ArrayLike, " d"],
    wc: Float[ArrayLike, " m"],
    x_angle_index: int | None = None,
    y_angle_index: int | None = None,
) -> Float[Array, "n d"]:
    """Weighted cross-covariance ``sum_i wc_i (x_i - x_mean)(y_i - y_mean)'``.

    Args:
        x: points (m, n).
        x_mean: mean of ``x`` (n,) (e.g. the Gaussian mean the points were drawn from).
        y: transformed points (m, d).
        y_mean: mean of ``y`` (d,) (e.g. from :func:`sigma_point_stats`).
        wc: covariance weights (m,).
        x_angle_index: static index of an angle component of ``x`` (deviations wrapped), or None.
        y_angle_index: static index of an angle component of ``y`` (deviations wrapped), or None.

    Returns:
        Cross-covariance (n, d).
    """
    dx = _deviations(jnp.asarray(x), jnp.asarray(x_mean), x_angle_index)
    dy = _deviations(jnp.asarray(y), jnp.asarray(y_mean), y_angle_index)
    return (jnp.asarray(wc)[:, None] * dx).T @ dy
