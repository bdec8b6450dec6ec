"""The built-in methods, particle and Gaussian (:data:`BUILTIN_METHODS`)."""

from nanoslam_jax.methods.gaussian._methods import EKF_SLAM, NASRUKF
from nanoslam_jax.methods.particle._methods import DEAD_RECKONING, FASTSLAM1, FASTSLAM2, ITERATED, NANO, UFASTSLAM

__all__ = [
    "BUILTIN_METHODS",
    "DEAD_RECKONING",
    "EKF_SLAM",
    "FASTSLAM1",
    "FASTSLAM2",
    "ITERATED",
    "NANO",
    "NASRUKF",
    "UFASTSLAM",
]

#: The built-in methods, in the order the configuration lists them.
BUILTIN_METHODS = (DEAD_RECKONING, NANO, FASTSLAM1, FASTSLAM2, UFASTSLAM, ITERATED, EKF_SLAM, NASRUKF)
