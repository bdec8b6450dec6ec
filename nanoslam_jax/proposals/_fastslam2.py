"""FastSLAM 2.0: a Gaussian proposal from an EKF update of the prior, linearised at the prior mean."""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp

from .._linalg import inv3, mm, mt, mv, sym
from ._base import AbstractProposal, Detections, ProposalResult, noise_information, range_bearing_residuals, wrap_pose


class LinearizedProposal(AbstractProposal):
    """FastSLAM 2.0 (Montemerlo et al. 2003): ``P = (P0^-1 + sum Gx' W Gx)^-1``, ``x = x0 + P sum Gx' W nu``.

    Attributes:
        landmark_noise: ``W = (R + Gm Sigma Gm')^-1`` (the published form) instead of ``R^-1``.
    """

    landmark_noise: bool = eqx.field(static=True, default=True)

    def __call__(self, x0, P0, det: Detections, R) -> ProposalResult:
        residual = range_bearing_residuals(det)
        W = noise_information(x0, det, R, self.landmark_noise) * det.mask[:, None, None]
        r = residual(x0)
        J = jax.jacfwd(residual)(x0)  # d r / d x = -Gx
        JtW = mm(mt(J), W)
        lam = sym(inv3(P0) + jnp.sum(mm(JtW, J), axis=0))
        P = sym(inv3(lam))
        x = wrap_pose(x0 - mv(P, jnp.sum(mv(JtW, r), axis=0)))
        zero = jnp.zeros((), jnp.int32)
        return ProposalResult(x, P, zero, zero)
