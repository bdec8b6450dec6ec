"""JAX's own count of compile time, and the watcher a command installs to hear of each compilation.

:class:`CompileStats` counts, with JAX's monitoring events (not wall clock around our calls), the
time spent tracing, lowering and compiling or loading programs and the persistent cache's hits
and misses, for ``metrics.json`` and the benchmark. :func:`watch_compiles` installs a
:class:`CompileWatcher` (the application's compile messages) that :func:`watched_compile` tells of
every program the core compiles; the core itself prints nothing.
"""

from __future__ import annotations

import contextlib
import dataclasses
from typing import Any, Iterator, Optional, Protocol

import jax

__all__ = [
    "CompileHandle",
    "CompileStats",
    "CompileWatcher",
    "ProgramInfo",
    "compile_stats",
    "watch_compiles",
    "watched_compile",
]


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
        return CompileStats(
            **{f.name: getattr(self, f.name) - getattr(earlier, f.name) for f in dataclasses.fields(self)}
        )

    def as_dict(self) -> dict:
        return {**dataclasses.asdict(self), "total_s": self.total_s}


_STATS: Optional[CompileStats] = None


def _on_duration(event: str, duration_secs: float, **_) -> None:
    name = _DURATIONS.get(event)
    if name is not None and _STATS is not None:
        setattr(_STATS, name, getattr(_STATS, name) + duration_secs)


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


# --------------------------------------------------------------------------- compile watchers


@dataclasses.dataclass(frozen=True)
class ProgramInfo:
    """What a compilation is about, as :func:`watched_compile` tells a :class:`CompileWatcher`.

    Attributes:
        label: what the program is (``"filter program"``, ``"sweep batch program"``).
        static: the program's static settings (the filter's ``Static``: its ``method``,
            ``n_particles``, ``capacity``, ``k_max``, ``row_buckets`` and ``devices``).
        shapes: each argument leaf's type and shape (``"float64[10,3]"``), in tree order.
        segments: log segments per call of the program.
        batch: runs the program computes side by side (1: one run).
        cache_dir: the persistent compilation cache directory in use (None: the cache is off).
        expect_load: whether the program is expected to load from the cache: True when its traced
            program is in ``exported/``, False when it is not (or the cache is off), None when
            nothing tells.
    """

    label: str
    static: Any
    shapes: tuple[str, ...]
    segments: int
    batch: int = 1
    cache_dir: Optional[str] = None
    expect_load: Optional[bool] = None


class CompileHandle(Protocol):
    """One compilation in progress, as a :class:`CompileWatcher` follows it."""

    def finished(self, loaded: bool) -> None:
        """The program is ready; ``loaded``: its executable came from the persistent cache."""

    def failed(self, error: BaseException) -> None:
        """Compiling raised ``error`` (a ``KeyboardInterrupt`` too); it is raised on after this."""


class CompileWatcher(Protocol):
    """What :func:`watch_compiles` installs: told of each compilation :func:`watched_compile` wraps."""

    def start(self, info: ProgramInfo) -> CompileHandle: ...


_WATCHERS: list[CompileWatcher] = []


@contextlib.contextmanager
def watch_compiles(watcher: CompileWatcher) -> Iterator[CompileWatcher]:
    """Tell ``watcher`` of every compilation :func:`watched_compile` wraps while the block runs
    (the innermost watcher only). The core only calls the watcher; what it prints or records is
    the caller's (the command line's compile messages)."""
    _WATCHERS.append(watcher)
    try:
        yield watcher
    finally:
        _WATCHERS.remove(watcher)


def _shapes(args: tuple) -> tuple[str, ...]:
    return tuple(str(jax.typeof(x)) if hasattr(x, "shape") else type(x).__name__ for x in jax.tree.leaves(args))


@contextlib.contextmanager
def watched_compile(
    label: str,
    static: Any,
    args: tuple,
    *,
    segments: int,
    batch: int = 1,
    expect_load: Optional[bool] = None,
) -> Iterator[None]:
    """Wrap the compilation (or loading) of one program for the watcher of :func:`watch_compiles`.

    Without a watcher this does nothing. With one, the watcher's :meth:`~CompileWatcher.start` is
    called before the block and the handle's ``finished`` or ``failed`` after it. Whether the
    program was loaded from the persistent cache is JAX's own count (its monitoring events: a
    cache hit during the block), not a guess from the time. A watcher that raises is ignored: what
    it reports never changes a program.

    Args:
        label: what the program is, for the message.
        static: the program's static settings.
        args: its example arguments (their shapes enter :attr:`ProgramInfo.shapes`).
        segments: log segments per call.
        batch: runs side by side in the program.
        expect_load: see :attr:`ProgramInfo.expect_load`.
    """
    if not _WATCHERS:
        yield
        return
    watcher = _WATCHERS[-1]
    cache = jax.config.jax_compilation_cache_dir or None  # type: ignore[attr-defined]  # jax.config's options are dynamic
    handle: Optional[CompileHandle] = None
    try:
        info = ProgramInfo(
            label, static, _shapes(args), int(segments), int(batch), cache, expect_load if cache else False
        )
        before = compile_stats()
        handle = watcher.start(info)
    except Exception:  # a watcher's failure must not stop the compilation
        handle = None
    try:
        yield
    except BaseException as e:
        if handle is not None:
            with contextlib.suppress(Exception):
                handle.failed(e)
        raise
    if handle is not None:
        with contextlib.suppress(Exception):
            handle.finished(compile_stats().since(before).cache_hits > 0)
