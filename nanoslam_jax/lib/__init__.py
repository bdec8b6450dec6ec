"""Small numerical helpers below everything else: closed-form algebra of tiny matrices,
vectorisable trigonometry and angle wrapping, Gaussian quadrature rules, resampling schemes,
batched-form helpers and the field metadata (default, range, meaning) that settings classes use."""

from nanoslam_jax.lib._angles import circular_mean, wrap_angle, wrap_angle_np
from nanoslam_jax.lib._fields import _f as setting

__all__ = ["wrap_angle", "wrap_angle_np", "circular_mean", "setting"]
