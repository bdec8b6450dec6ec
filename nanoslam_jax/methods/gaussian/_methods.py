"""The built-in Gaussian methods as :class:`~nanoslam_jax.methods.Method` objects: EKF-SLAM and
NASRUKF FastSLAM (detections or per-beam measurements), their ``init`` and ``step``."""

from __future__ import annotations

from typing import Any

from nanoslam_jax.methods._method import Method
from nanoslam_jax.methods._method_settings import NasrukfStatic, nasrukf_static
from nanoslam_jax.methods.gaussian._ekf_slam import ekf_slam_step, init_ekf_state
from nanoslam_jax.methods.gaussian._nasrukf import nasrukf_step
from nanoslam_jax.methods.gaussian._nasrukf_beams import beam_step
from nanoslam_jax.methods.gaussian._nasrukf_beams_state import init_beam_state
from nanoslam_jax.methods.gaussian._nasrukf_state import init_nasrukf_state

__all__ = ["EKF_SLAM", "NASRUKF"]


def _ekf_init(static: Any, params: Any) -> Any:
    return init_ekf_state(static, params)


def _ekf_step(static: Any, params: Any, state: Any, seg: Any, valid: Any) -> Any:
    return ekf_slam_step(static, params, state, seg, valid)


def _nasrukf_beams(static: Any) -> bool:
    return nasrukf_static(static).measurement == "beams"


def _nasrukf_init(static: Any, params: Any) -> Any:
    if _nasrukf_beams(static):
        return init_beam_state(static, params)
    return init_nasrukf_state(static, params)


def _nasrukf_step(static: Any, params: Any, state: Any, seg: Any, valid: Any) -> Any:
    if _nasrukf_beams(static):
        return beam_step(static, params, state, seg, valid)
    return nasrukf_step(static, params, state, seg, valid)


EKF_SLAM = Method("ekf_slam", kind="gaussian", init=_ekf_init, step=_ekf_step, description="EKF-SLAM")
NASRUKF = Method(
    "nasrukf",
    kind="gaussian",
    init=_nasrukf_init,
    step=_nasrukf_step,
    adaptive_noise=True,
    static_default=NasrukfStatic(),
    section="nasrukf",
    description="NASRUKF FastSLAM: adaptive square-root UKF per feature",
)
