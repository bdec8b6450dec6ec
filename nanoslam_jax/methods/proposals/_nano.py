"""The NANO proposal: natural-gradient Gaussian approximation of the pose posterior."""

from __future__ import annotations

import equinox as eqx
from jaxtyping import Array, Float

from nanoslam_jax.lib._linalg import inv3, sym
from nanoslam_jax.models import AbstractMeasurementModel, RangeBearing
from nanoslam_jax.lib.quadrature import QuadratureRule
from nanoslam_jax.methods.proposals._base import (
    AbstractProposal,
    Detections,
    ProposalResult,
    measurement_residuals,
    noise_information,
)
from nanoslam_jax.methods.proposals._iterated import POSES, gauss_newton_map
from nanoslam_jax.methods.proposals._natural_gradient import (
    Gaussian,
    NaturalGradientSettings,
    natural_gradient_gaussian,
)


class NanoProposal(AbstractProposal):
    """NANO-SLAM's proposal (docs/method/proposals.md, "NANO").

    Attributes:
        rule: quadrature rule for the expectations (cubature by default).
        gamma: KL stopping threshold (traced).
        step: natural-gradient step, 1 undamped (traced).
        max_iter: iteration cap.
        hessian: ``'gauss_newton'`` or ``'exact'``.
        landmark_noise: use ``R + Gm Sigma Gm'`` instead of ``R`` in the likelihood.
        init: ``'prior'`` or ``'gauss_newton'`` (start from the Gauss-Newton MAP and its
            Laplace precision).
        solver: ``'optimistix'`` or ``'while_loop'``.
        measurement: the measurement model (default range-bearing).
    """

    rule: QuadratureRule
    gamma: Float[Array, ""]
    step: Float[Array, ""]
    max_iter: int = eqx.field(static=True, default=10)
    hessian: str = eqx.field(static=True, default="gauss_newton")
    landmark_noise: bool = eqx.field(static=True, default=False)
    init: str = eqx.field(static=True, default="prior")
    solver: str = eqx.field(static=True, default="while_loop")
    measurement: AbstractMeasurementModel = eqx.field(default_factory=RangeBearing)

    def __call__(self, x0, P0, det: Detections, R) -> ProposalResult:
        prior = Gaussian(x0, sym(inv3(P0)), P0)
        residual = measurement_residuals(det, self.measurement)
        weights = noise_information(x0, det, R, self.landmark_noise, self.measurement)
        start = None
        if self.init == "gauss_newton":
            start = gauss_newton_map(prior, residual, weights, det.mask, max_iter=self.max_iter)
        settings = NaturalGradientSettings(self.gamma, self.step, self.max_iter, self.hessian, self.solver)
        out = natural_gradient_gaussian(
            prior, residual, weights, det.mask, self.rule, settings=settings, start=start, space=POSES
        )
        return ProposalResult(out.q.mean, out.q.cov, out.iterations, out.result)
