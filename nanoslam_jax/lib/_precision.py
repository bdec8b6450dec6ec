"""Float64 without a process-wide switch: the library's entry points run their JAX work under
``jax.enable_x64(True)`` (a context that ends with the call), so importing the package leaves
JAX's settings as they were."""

from __future__ import annotations

import functools
from collections.abc import Callable
from typing import Any, TypeVar

import jax

__all__ = ["float64", "in_float64", "require_float64"]

_F = TypeVar("_F", bound=Callable[..., Any])


def float64() -> Any:
    """A context in which JAX computes in float64 (``jax.enable_x64(True)``)::

    with nanoslam_jax.float64():
        f = nanoslam_jax.app.filters.build(cfg, segments)
        state = f.init(key)
    """
    return jax.enable_x64(True)


def in_float64(fn: _F) -> _F:
    """``fn`` run under :func:`float64` (an entry point: its arrays and programs are float64)."""

    @functools.wraps(fn)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        with float64():
            return fn(*args, **kwargs)

    return wrapper  # type: ignore[return-value]  # functools.wraps keeps the signature


def require_float64(what: str) -> None:
    """Raise a clear error when JAX computes in float32 here.

    Args:
        what: the call that needs float64, for the message.

    Raises:
        RuntimeError: naming ``what`` and the two ways to get float64.
    """
    if not jax.config.jax_enable_x64:  # type: ignore[attr-defined]  # jax.config's options are dynamic
        raise RuntimeError(
            f"{what} computes in float64, and JAX is in float32 here: call it inside "
            "`with nanoslam_jax.float64():`, or set jax.config.update('jax_enable_x64', True) first"
        )
