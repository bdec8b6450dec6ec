"""Proposals: one module per method, all behind :class:`AbstractProposal`."""

from nanoslam_jax.methods.proposals._base import (
    RESULT_CODES as RESULT_CODES,
    AbstractProposal as AbstractProposal,
    Detections as Detections,
    ProposalResult as ProposalResult,
)
from nanoslam_jax.methods.proposals._fastslam1 import PriorProposal as PriorProposal
from nanoslam_jax.methods.proposals._fastslam2 import LinearizedProposal as LinearizedProposal
from nanoslam_jax.methods.proposals._iterated import (
    IteratedProposal as IteratedProposal,
    gauss_newton_map as gauss_newton_map,
    map_estimate as map_estimate,
)
from nanoslam_jax.methods.proposals._nano import NanoProposal as NanoProposal
from nanoslam_jax.methods.proposals._natural_gradient import (
    Gaussian as Gaussian,
    NaturalGradientKL as NaturalGradientKL,
    NaturalGradientSettings as NaturalGradientSettings,
    StateSpace as StateSpace,
    expected_grad_hess as expected_grad_hess,
    kl_gaussian as kl_gaussian,
    natural_gradient_gaussian as natural_gradient_gaussian,
)
from nanoslam_jax.methods.proposals._ufastslam import UnscentedProposal as UnscentedProposal

__all__ = [
    "RESULT_CODES",
    "AbstractProposal",
    "Detections",
    "ProposalResult",
    "PriorProposal",
    "LinearizedProposal",
    "IteratedProposal",
    "gauss_newton_map",
    "map_estimate",
    "NanoProposal",
    "Gaussian",
    "NaturalGradientKL",
    "NaturalGradientSettings",
    "StateSpace",
    "expected_grad_hess",
    "kl_gaussian",
    "natural_gradient_gaussian",
    "UnscentedProposal",
]
