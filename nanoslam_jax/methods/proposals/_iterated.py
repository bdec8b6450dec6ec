"""The iterated proposal: the MAP of prior x likelihood by Gauss-Newton or Levenberg-Marquardt
(optimistix least squares) with its Laplace covariance (an IEKF-like proposal).

:func:`gauss_newton_map` is also NANO's optional initialisation.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import optimistix as optx

from nanoslam_jax.lib._linalg import chol3, chol_small, inv3, sym
from nanoslam_jax.models import AbstractMeasurementModel, RangeBearing
from nanoslam_jax.methods.proposals._base import (
    AbstractProposal,
    Detections,
    ProposalResult,
    measurement_residuals,
    noise_information,
    pose_difference,
    wrap_pose,
)
from nanoslam_jax.methods.proposals._natural_gradient import Gaussian, StateSpace

SOLVERS = ("gauss_newton", "levenberg_marquardt")
POSES = StateSpace(pose_difference, wrap_pose)
"""Poses ``(x, y, heading)``: differences and iterates with the heading wrapped."""


def _solver(name: str, tol: float):
    if name == "gauss_newton":
        return optx.GaussNewton(rtol=tol, atol=tol)
    if name == "levenberg_marquardt":
        return optx.LevenbergMarquardt(rtol=tol, atol=tol)
    raise ValueError(f"iterated.solver: {name!r} is not one of {', '.join(SOLVERS)}")


def map_estimate(
    prior: Gaussian,
    residual,
    weights,
    mask,
    *,
    solver: str = "gauss_newton",
    max_iter: int = 10,
    tol: float = 1e-8,
    space: StateSpace = POSES,
) -> tuple[Gaussian, jax.Array, jax.Array]:
    """MAP of ``N(x; x0, P0) prod_k N(r_k(x); 0, W_k^-1)`` and its Laplace (Gauss-Newton) precision.

    The least-squares residual stacks the whitened prior term ``U0 diff(x, x0)`` (``U0' U0 = L0``)
    and the whitened measurement residuals ``U_k r_k(x)`` (``U_k' U_k = W_k``; masked rows are zero).

    Args:
        prior: the prior Gaussian (mean, precision).
        residual: ``x -> r`` of shape ``(k, d)``.
        weights: the residuals' information matrices ``(k, d, d)``.
        mask: which residual rows count.
        solver: ``'gauss_newton'`` or ``'levenberg_marquardt'``.
        max_iter: solver step cap.
        tol: solver ``rtol`` and ``atol``.
        space: the state difference and projection (default: poses, the heading wrapped).

    Returns:
        The Laplace approximation ``N(x_map, (J'J)^-1)``, the number of steps and the optimistix
        result code (0 success, 1 step cap; 2 when the solution was non-finite and the prior mean
        was returned).
    """
    diff, project = space
    U0 = chol3(prior.precision).T
    weights = jnp.where(mask[:, None, None], weights, jnp.eye(weights.shape[-1]))  # masked rows may be non-finite
    Uk = jnp.swapaxes(chol_small(weights), -1, -2) * mask[:, None, None]

    def fn(x, args):
        rp = U0 @ diff(x, prior.mean)
        r = jnp.where(mask[:, None], residual(x), 0.0)  # masked rows may be non-finite (dummy landmarks)
        rm = jnp.einsum("kde,ke->kd", Uk, r).reshape(-1)
        return jnp.concatenate([rp, rm])

    sol: optx.Solution = optx.least_squares(fn, _solver(solver, tol), prior.mean, max_steps=max_iter, throw=False)
    ok = jnp.all(jnp.isfinite(sol.value))
    x = project(jnp.where(ok, sol.value, prior.mean))
    J = jax.jacfwd(lambda y: fn(y, None))(x)
    lam = sym(J.T @ J)
    code = jnp.where(ok, jnp.where(sol.result == optx.RESULTS.successful, 0, 1), 2).astype(jnp.int32)
    return Gaussian(x, lam, sym(inv3(lam))), sol.stats["num_steps"].astype(jnp.int32), code


def gauss_newton_map(prior: Gaussian, residual, weights, mask, *, max_iter: int = 10, tol: float = 1e-8) -> Gaussian:
    """MAP by optimistix Gauss-Newton with the Laplace precision (see :func:`map_estimate`)."""
    return map_estimate(prior, residual, weights, mask, solver="gauss_newton", max_iter=max_iter, tol=tol)[0]


class IteratedProposal(AbstractProposal):
    """Iterated proposal (docs/method/proposals.md, "Iterated proposal"): ``N(x_map, (J'J)^-1)`` at the MAP of prior x likelihood.

    With one Gauss-Newton step from the prior mean this is FastSLAM 2.0's proposal; iterated to
    convergence it is an IEKF-like proposal, between FastSLAM 2.0 and NANO.

    Attributes:
        solver: ``'gauss_newton'`` or ``'levenberg_marquardt'`` (optimistix least squares).
        max_iter: solver step cap.
        tol: solver tolerance.
        landmark_noise: weigh residuals with ``(R + Gm Sigma Gm')^-1`` (as FastSLAM 2.0) instead of ``R^-1``.
        measurement: the measurement model (default range-bearing).
    """

    solver: str = eqx.field(static=True, default="gauss_newton")
    max_iter: int = eqx.field(static=True, default=10)
    tol: float = eqx.field(static=True, default=1e-8)
    landmark_noise: bool = eqx.field(static=True, default=True)
    measurement: AbstractMeasurementModel = eqx.field(default_factory=RangeBearing)

    def __call__(self, x0, P0, det: Detections, R) -> ProposalResult:
        prior = Gaussian(x0, sym(inv3(P0)), P0)
        weights = noise_information(x0, det, R, self.landmark_noise, self.measurement)
        q, steps, code = map_estimate(
            prior,
            measurement_residuals(det, self.measurement),
            weights,
            det.mask,
            solver=self.solver,
            max_iter=self.max_iter,
            tol=self.tol,
        )
        return ProposalResult(q.mean, q.cov, steps, code)
