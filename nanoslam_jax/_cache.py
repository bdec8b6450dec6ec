"""The persistent compilation cache every command uses, and JAX's own count of compile time.

A run's filter program takes 12-15 s to compile on a 2-core CPU; the program depends only on the
static settings and the log's segment shapes, so a second run loads it from disk instead.
:func:`enable_compile_cache` points JAX's persistent compilation cache at one directory:
``$NANOSLAM_CACHE_DIR`` when set, else ``$XDG_CACHE_HOME/nanoslam-jax/jax`` (``~/.cache/...``).

Why the cache is safe across versions: JAX's cache key is a hash of the compiled module (every
static shape, constant and branch, so every static config setting and the segment shapes), the
compile options and XLA flags, the device kind and count, and the versions of jax, jaxlib and XLA.
Any change of this project's code that changes the program changes the module, hence the key; a
change that does not change the module gives the same executable. So the project's version is
not added to the directory: it would add no safety and would only make every upgrade (and every
editable install, whose version does not move with the commits) recompile from scratch.

:class:`CompileStats` counts, with JAX's monitoring events (not wall clock around our calls), the
time spent tracing, lowering and compiling or loading programs and the persistent cache's hits
and misses, for ``metrics.json`` and the benchmark.
"""

from __future__ import annotations

import dataclasses
import os
from pathlib import Path
from typing import Optional

import jax

__all__ = ["CACHE_ENV", "CompileStats", "compile_stats", "default_cache_dir", "enable_compile_cache"]

#: Environment variable that moves the cache directory.
CACHE_ENV = "NANOSLAM_CACHE_DIR"

#: Programs that compile faster than this are not written to the cache (JAX's default is 1 s). The
#: filter's programs all take longer; the many small eager operations of loading and scoring a
#: run would only fill the directory with entries that cost more to read than to compile.
MIN_COMPILE_TIME_S = 0.5


def default_cache_dir() -> Path:
    """``$NANOSLAM_CACHE_DIR``, else ``$XDG_CACHE_HOME/nanoslam-jax/jax`` (``~/.cache`` by default)."""
    env = os.environ.get(CACHE_ENV)
    if env:
        return Path(env).expanduser()
    base = os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache"
    return Path(base).expanduser() / "nanoslam-jax" / "jax"


def enable_compile_cache(path: str | os.PathLike | None = None) -> str:
    """Keep compiled programs in JAX's persistent compilation cache.

    Args:
        path: the cache directory (default: :func:`default_cache_dir`). When this process already
            uses a cache directory (set earlier, or by ``JAX_COMPILATION_CACHE_DIR``), that one is kept.

    Returns:
        The cache directory in use.

    Raises:
        ValueError: naming the directory and ``NANOSLAM_CACHE_DIR`` when it cannot be created.
    """
    current = jax.config.jax_compilation_cache_dir
    if current:
        return str(current)
    p = Path(path) if path is not None else default_cache_dir()
    try:
        p.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise ValueError(f"{p}: cannot create the compilation cache directory ({e.strerror}); "
                         f"set {CACHE_ENV} to a writable directory or pass --no-cache") from None
    jax.config.update("jax_persistent_cache_min_compile_time_secs", MIN_COMPILE_TIME_S)
    jax.config.update("jax_compilation_cache_dir", str(p))
    return str(p)


_DURATIONS = {
    "/jax/core/compile/jaxpr_trace_duration": "trace_s",
    "/jax/core/compile/jaxpr_to_mlir_module_duration": "lower_s",
    "/jax/core/compile/backend_compile_duration": "backend_s",
}
_COUNTS = {
    "/jax/compilation_cache/cache_hits": "cache_hits",
    "/jax/compilation_cache/cache_misses": "cache_misses",
}


@dataclasses.dataclass
class CompileStats:
    """Compile time of this process as JAX's monitoring events report it.

    Attributes:
        trace_s: tracing Python functions to jaxprs.
        lower_s: lowering jaxprs to MLIR modules.
        backend_s: XLA compilation, or loading from the persistent cache on a hit.
        cache_hits: programs loaded from the persistent cache.
        cache_misses: programs looked up in the persistent cache and compiled (a program under
            the cache's minimum compile time is looked up, compiled, and not written).
    """

    trace_s: float = 0.0
    lower_s: float = 0.0
    backend_s: float = 0.0
    cache_hits: int = 0
    cache_misses: int = 0

    @property
    def total_s(self) -> float:
        """Tracing, lowering and compiling (or loading) together."""
        return self.trace_s + self.lower_s + self.backend_s

    def since(self, earlier: "CompileStats") -> "CompileStats":
        """What was added after the snapshot ``earlier``."""
        return CompileStats(**{f.name: getattr(self, f.name) - getattr(earlier, f.name)
                               for f in dataclasses.fields(self)})

    def as_dict(self) -> dict:
        return {**dataclasses.asdict(self), "total_s": self.total_s}


_STATS: Optional[CompileStats] = None


def _on_duration(event: str, duration: float, **_) -> None:
    name = _DURATIONS.get(event)
    if name is not None and _STATS is not None:
        setattr(_STATS, name, getattr(_STATS, name) + duration)


def _on_event(event: str, **_) -> None:
    name = _COUNTS.get(event)
    if name is not None and _STATS is not None:
        setattr(_STATS, name, getattr(_STATS, name) + 1)


def compile_stats() -> CompileStats:
    """A snapshot of this process's compile statistics since the first call of this function.

    The first call registers the listeners; call it early (commands do so at start) and take
    differences with :meth:`CompileStats.since` to measure a stretch of work.
    """
    global _STATS
    if _STATS is None:
        _STATS = CompileStats()
        jax.monitoring.register_event_duration_secs_listener(_on_duration)
        jax.monitoring.register_event_listener(_on_event)
    return dataclasses.replace(_STATS)
