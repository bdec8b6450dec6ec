"""The built-in methods, particle and Gaussian (:data:`BUILTIN_METHODS`)."""

from nanoslam_jax.methods.gaussian._methods import EKF_SLAM, NASRUKF
from nanoslam_jax.methods.particle._methods import DEAD_RECKONING, FASTSLAM1, FASTSLAM2, ITERATED, NANO, UFASTSLAM

__all__ = [
    "ADAPTIVE_NOISE_METHODS",
    "AVAILABLE_METHODS",
    "BUILTIN_METHODS",
    "GAUSSIAN_METHODS",
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
#: Their names (every registered one: :func:`nanoslam_jax.app.registry.method_names`).
AVAILABLE_METHODS = tuple(m.name for m in BUILTIN_METHODS)
#: The built-in methods without particles: their state is Gaussian and a run does not depend on the seed.
GAUSSIAN_METHODS = tuple(m.name for m in BUILTIN_METHODS if m.kind == "gaussian")
#: The built-in methods with an adaptive measurement-noise estimate (``noise.adaptive``).
ADAPTIVE_NOISE_METHODS = tuple(m.name for m in BUILTIN_METHODS if m.adaptive_noise)
