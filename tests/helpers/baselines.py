"""The dead-reckoning baseline every end-to-end accuracy test measures itself against.

A SLAM result means something only next to what the vehicle model alone achieves on the same log:
an accuracy bound that dead reckoning also meets cannot fail when SLAM stops working. These
helpers compute the baseline in the test, on the test's own log, with the same protocol.
"""

from __future__ import annotations

import jax
import numpy as np

from nanoslam_jax.methods import dead_reckoning
from nanoslam_jax.app.filters import settings_from_config
from nanoslam_jax.eval.metrics import evaluate


def dead_reckoning_metrics(cfg, log) -> dict:
    """The evaluation protocol's figures of noise-free dead reckoning on ``log`` (the vehicle model
    driven by the logged controls from the origin), scored as the filter is."""
    _, params = settings_from_config(cfg, log.segments.k_max)
    poses = np.asarray(dead_reckoning(params, jax.tree.map(np.asarray, log.segments)))
    return evaluate(
        np.asarray(log.segments.time),
        poses[:, :2],
        log.raw.gps,
        frame=log.frame,
        rotation_deg=cfg.metrics.gps_rotation_deg,
        jump_speed=cfg.metrics.jump_speed,
    )


def assert_beats_dead_reckoning(rmse: float, dr_rmse: float, factor: float, what: str = "") -> None:
    """``rmse`` must be at most ``dr_rmse / factor``."""
    assert rmse * factor <= dr_rmse, (
        f"{what}: RMSE {rmse:.3f} m is not {factor}x better than dead reckoning's {dr_rmse:.3f} m on the same log"
    )


def reported_map_quality(cfg, log, landmarks, metrics: dict) -> dict:
    """:func:`nanoslam_jax.eval.metrics.map_summary` of a reported map (one particle's or the Gaussian
    filter's ``LandmarkMap``) against the simulated log's observable trees, in the SLAM frame and
    after the trajectory's rigid alignment in ``metrics`` (what :func:`evaluate` returned)."""
    from nanoslam_jax.eval.metrics import map_summary

    act = np.asarray(landmarks.active)
    return map_summary(
        np.asarray(landmarks.mean)[act],
        np.asarray(landmarks.confirmed)[act],
        log.map_truth,
        cfg.metrics.map_radius,
        metrics,
    )
