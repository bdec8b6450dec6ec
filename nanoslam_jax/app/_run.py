"""The public entry point for one run: :func:`run`."""

from __future__ import annotations

import dataclasses
import os
from collections.abc import Mapping, Sequence
from typing import Any, Optional, Union

from nanoslam_jax.app.config import Config, config_from_dict, load_config
from nanoslam_jax.app.experiment import RunResult, execute
from nanoslam_jax.lib._precision import in_float64

__all__ = ["run"]


@in_float64
def run(
    config: Union[Config, str, os.PathLike, Mapping[str, Any], None] = None,
    *,
    data: Union[str, os.PathLike, None] = None,
    seed: Optional[int] = None,
    overrides: Sequence[str] = (),
    progress: bool = False,
) -> RunResult:
    """Run a configuration in memory and return its :class:`~nanoslam_jax.RunResult`.

    Args:
        config: a :class:`~nanoslam_jax.Config`, the path of a YAML config, a mapping in the
            YAML layout, or None for the embedded default (a simulated log with ground truth).
        data: the log directory (overrides ``data.path``, as ``--data`` does on the command line).
        seed: the filter's PRNG seed (overrides ``seed``).
        overrides: ``key=value`` strings, as ``--set`` takes them.
        progress: print a progress indicator to stderr.

    Returns:
        The trajectory, map, per-segment outputs, final state and metrics of the run. Write the
        result directory the ``run`` command writes with :meth:`RunResult.write`.

    Raises:
        ConfigError: naming the key, for a configuration that does not validate.
        LogFormatError: naming the file and line, for a log that cannot be read.
    """
    if isinstance(config, Config):
        cfg = config
        if overrides:
            from nanoslam_jax.app.config import apply_overrides, config_to_dict

            cfg = config_from_dict(apply_overrides(config_to_dict(cfg), list(overrides)), source="overrides")
    elif isinstance(config, Mapping):
        from nanoslam_jax.app.config import apply_overrides

        cfg = config_from_dict(apply_overrides(dict(config), list(overrides)), source="config mapping")
    else:
        cfg = load_config(config, list(overrides))
    if seed is not None:
        cfg = dataclasses.replace(cfg, seed=int(seed))
    return execute(cfg, None if data is None else str(data), progress)
