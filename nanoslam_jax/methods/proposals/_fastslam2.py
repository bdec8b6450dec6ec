"""FastSLAM 2.0: a Gaussian proposal from an EKF update of the prior, linearised at the prior mean."""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float

from nanoslam_jax.lib._linalg import inv3, mm, mt, mv, sym, tsum
from nanoslam_jax.models import AbstractMeasurementModel, RangeBearing
from nanoslam_jax.methods.proposals._base import (
    AbstractProposal,
    Detections,
    ProposalResult,
    measurement_residuals,
    noise_information,
    wrap_pose,
)
from nanoslam_jax.methods.proposals._natural_gradient import Gaussian


def linearized_gaussian(
    prior: Gaussian,
    residual,
    weights: Float[Array, "k d d"],
    mask: Bool[Array, " k"],
    project=wrap_pose,
) -> Gaussian:
    """One EKF (Gauss-Newton) update of the prior with residuals linearised at the prior mean.

    ``P = (P0^-1 + sum J' W J)^-1``, ``x = x0 - P sum J' W r(x0)`` with ``J = dr/dx`` at ``x0``.

    Args:
        prior: the prior Gaussian (mean, precision).
        residual: ``x -> r`` of shape ``(k, d)`` (measurement minus prediction, angles wrapped).
        weights: the residuals' information matrices.
        mask: which residual rows count.
        project: applied to the updated mean (heading wrap for poses).
    """
    W = jnp.where(mask[:, None, None], weights, 0.0)  # masked rows may be non-finite (dummy landmarks)
    r = jnp.where(mask[:, None], residual(prior.mean), 0.0)
    J = jnp.where(mask[:, None, None], jax.jacfwd(residual)(prior.mean), 0.0)
    JtW = mm(mt(J), W)
    lam = sym(prior.precision + tsum(mm(JtW, J)))
    P = sym(inv3(lam)) if lam.shape[-1] == 3 else sym(jnp.linalg.inv(lam))
    return Gaussian(project(prior.mean - mv(P, tsum(mv(JtW, r)))), lam, P)


class LinearizedProposal(AbstractProposal):
    """FastSLAM 2.0 (Montemerlo et al. 2003): ``P = (P0^-1 + sum Gx' W Gx)^-1``, ``x = x0 + P sum Gx' W nu``.

    Attributes:
        landmark_noise: ``W = (R + Gm Sigma Gm')^-1`` (the published form) instead of ``R^-1``.
        measurement: the measurement model (default range-bearing).
    """

    landmark_noise: bool = eqx.field(static=True, default=True)
    measurement: AbstractMeasurementModel = eqx.field(default_factory=RangeBearing)

    def __call__(self, x0, P0, det: Detections, R) -> ProposalResult:
        W = noise_information(x0, det, R, self.landmark_noise, self.measurement)
        q = linearized_gaussian(
            Gaussian(x0, sym(inv3(P0)), P0), measurement_residuals(det, self.measurement), W, det.mask
        )
        zero = jnp.zeros((), jnp.int32)
        return ProposalResult(q.mean, q.cov, zero, zero)
