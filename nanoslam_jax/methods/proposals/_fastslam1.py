"""FastSLAM 1.0: the proposal is the motion prior."""

from __future__ import annotations

import jax.numpy as jnp

from nanoslam_jax.methods.proposals._base import AbstractProposal, Detections, ProposalResult


class PriorProposal(AbstractProposal):
    """Sample from the prior ``N(x0, P0)`` (FastSLAM 1.0); the detections only weight."""

    def __call__(self, x0, P0, det: Detections, R) -> ProposalResult:
        zero = jnp.zeros((), jnp.int32)
        return ProposalResult(x0, P0, zero, zero)
