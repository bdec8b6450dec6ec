"""nanoslam-jax: landmark SLAM with Rao-Blackwellised particle filters and their Gaussian rivals, in JAX.

Importing the package changes no JAX setting. Its entry points (:func:`run`, the ``nanoslam``
command, the engine's run, compare, sweep and study functions) compute in float64 inside a
``jax.enable_x64`` context; code that drives the filter itself does so inside
``with nanoslam_jax.float64():`` (or after ``jax.config.update("jax_enable_x64", True)``), and the
builders refuse to build in float32 with a message that says this.

The public surface: :func:`run` (one run in memory, a :class:`RunResult`), :func:`load_config`
and :class:`Config`, the model interfaces in :mod:`nanoslam_jax.models`, and
:func:`enable_compile_cache`.
"""

from nanoslam_jax._version import __version__ as __version__
from nanoslam_jax.lib._cache import enable_compile_cache as enable_compile_cache
from nanoslam_jax.lib._precision import float64 as float64
from nanoslam_jax.app.config import Config as Config, ConfigError as ConfigError, load_config as load_config
from nanoslam_jax.app.experiment import RunResult as RunResult
from nanoslam_jax.app._run import run as run

__all__ = ["__version__", "float64", "run", "RunResult", "Config", "ConfigError", "load_config", "enable_compile_cache"]
