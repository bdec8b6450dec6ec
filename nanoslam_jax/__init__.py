"""nanoslam-jax: landmark SLAM with Rao-Blackwellised particle filters and their Gaussian rivals, in JAX.

Importing the package switches JAX to float64 (``jax_enable_x64``); set the environment
variable ``NANOSLAM_X64=0`` before importing to keep JAX's float32 default.

The public surface: :func:`run` (one run in memory, a :class:`RunResult`), :func:`load_config`
and :class:`Config`, the model interfaces in :mod:`nanoslam_jax.models`, and
:func:`enable_compile_cache`.
"""

import os as _os

import jax as _jax

if _os.environ.get("NANOSLAM_X64", "1") != "0":
    _jax.config.update("jax_enable_x64", True)

from nanoslam_jax._version import __version__ as __version__  # noqa: E402
from nanoslam_jax.app._cache import enable_compile_cache as enable_compile_cache  # noqa: E402
from nanoslam_jax.app.config import Config as Config, ConfigError as ConfigError, load_config as load_config  # noqa: E402
from nanoslam_jax.app.experiment import RunResult as RunResult  # noqa: E402
from nanoslam_jax.app._run import run as run  # noqa: E402

__all__ = ["__version__", "run", "RunResult", "Config", "ConfigError", "load_config", "enable_compile_cache"]
