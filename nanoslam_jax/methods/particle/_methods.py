"""The built-in particle methods as :class:`~nanoslam_jax.methods.Method` objects: each one's
proposal and its default static settings (FastSLAM 1.0 and 2.0, Unscented FastSLAM, NANO-SLAM,
the iterated proposal), and dead reckoning."""

from __future__ import annotations

from typing import Any

from nanoslam_jax.lib.quadrature import make_rule
from nanoslam_jax.methods._method import Method
from nanoslam_jax.methods._method_settings import IteratedStatic, NanoStatic, settings_of
from nanoslam_jax.methods.maps._updates import UnscentedLandmarkUpdate
from nanoslam_jax.methods.proposals import LinearizedProposal, NanoProposal, PriorProposal
from nanoslam_jax.methods.proposals._iterated import IteratedProposal
from nanoslam_jax.methods.proposals._ufastslam import UnscentedProposal

__all__ = ["DEAD_RECKONING", "FASTSLAM1", "FASTSLAM2", "ITERATED", "NANO", "UFASTSLAM"]


def _nano(static: Any, params: Any, mp: Any) -> NanoProposal:
    ns: NanoStatic = settings_of(static, NanoStatic)
    rule = make_rule(ns.quadrature, alpha=mp.alpha, beta=mp.beta, kappa=mp.kappa, order=ns.gh_order)
    return NanoProposal(
        rule,
        mp.gamma,
        mp.step,
        max_iter=ns.max_iter,
        hessian=ns.hessian,
        landmark_noise=ns.landmark_noise,
        init=ns.init,
        solver=ns.solver,
        measurement=params.measurement,
    )


# optimistix's least-squares solvers cannot run under shard_map (lineax compares the residual's
# structure with its operator's, whose sharding differs there): such runs stay on one device.
def _nano_shardable(static: Any) -> bool:
    return settings_of(static, NanoStatic).init != "gauss_newton"


def _never(static: Any) -> bool:
    return False


def _fastslam1(static: Any, params: Any, mp: Any) -> PriorProposal:
    return PriorProposal()


def _fastslam2(static: Any, params: Any, mp: Any) -> LinearizedProposal:
    return LinearizedProposal(landmark_noise=True, measurement=params.measurement)


def _ufastslam(static: Any, params: Any, mp: Any) -> UnscentedProposal:
    return UnscentedProposal(
        alpha=params.ut_alpha, beta=params.ut_beta, kappa=params.ut_kappa, measurement=params.measurement
    )


def _iterated(static: Any, params: Any, mp: Any) -> IteratedProposal:
    it: IteratedStatic = settings_of(static, IteratedStatic)
    return IteratedProposal(
        solver=it.solver,
        max_iter=it.max_iter,
        tol=it.tol,
        landmark_noise=it.landmark_noise,
        measurement=params.measurement,
    )


DEAD_RECKONING = Method("dead_reckoning", kind="dead_reckoning", description="the motion model alone")
NANO = Method(
    "nano",
    proposal=_nano,
    adaptive_noise=True,
    shardable=_nano_shardable,
    static_default=NanoStatic(),
    section="nano",
    description="NANO-SLAM: the KL-optimal Gaussian proposal by natural-gradient iteration",
)
FASTSLAM1 = Method("fastslam1", proposal=_fastslam1, description="FastSLAM 1.0: the prior as proposal")
FASTSLAM2 = Method(
    "fastslam2", proposal=_fastslam2, adaptive_noise=True, description="FastSLAM 2.0: the linearised (EKF) proposal"
)
UFASTSLAM = Method(
    "ufastslam",
    proposal=_ufastslam,
    landmark_update=UnscentedLandmarkUpdate(),
    adaptive_noise=True,
    description="Unscented FastSLAM: unscented proposal and landmark updates",
)
ITERATED = Method(
    "iterated",
    proposal=_iterated,
    shardable=_never,
    static_default=IteratedStatic(),
    section="iterated",
    description="the iterated (Gauss-Newton / Levenberg-Marquardt MAP) proposal",
)
