"""The command line's compile messages: what is compiling, how long it should take, how long it took.

A command's first call of a filter program compiles it (tens of seconds on a CPU) or loads it from
the persistent compilation cache (about a second). :class:`CompileReporter` is the watcher the
commands install (:func:`nanoslam_jax.lib._cache.watch_compiles`); the core tells it of each
compilation (:func:`~nanoslam_jax.lib._cache.watched_compile`) and it writes on stderr:

* a start line naming the program (method, particles, runs side by side, segments per call) and
  the time expected: the last measured compile (or load) of the same program shape, kept in
  :data:`STORE_NAME` in the cache directory (:class:`TimingStore`), else an estimate from the
  method and the particle count (:func:`estimate_compile_s`);
* on a terminal, that line rewritten about once a second with the time elapsed (``[12 s elapsed]``);
* a done line: compiled in, or loaded from the compilation cache in, so many seconds.

Each measured time is written back to the store, keyed by the program's shape
(:func:`program_signature`). Nothing here changes a program.
"""

from __future__ import annotations

import contextlib
import datetime
import hashlib
import json
import math
import os
import shutil
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any, Callable, Iterator, Optional, TextIO

from nanoslam_jax.lib._cache import ProgramInfo, watch_compiles

__all__ = [
    "STORE_NAME",
    "CompileReporter",
    "TimingStore",
    "compile_messages",
    "estimate_compile_s",
    "program_signature",
]

#: The file of measured compile and load times, in the compilation cache directory.
STORE_NAME = "compile_times.json"
_STORE_FORMAT = 1

#: The estimate of a program's compile time with no measurement of its shape: seconds for a
#: method's filter program of one run at :data:`ESTIMATE_PARTICLES` particles or fewer on a 2-core
#: CPU, by method (others take :data:`ESTIMATE_DEFAULT_S`), ...
ESTIMATE_BASE_S = {
    "nano": 11.0,
    "fastslam1": 9.0,
    "fastslam2": 10.0,
    "ufastslam": 10.0,
    "ekf_slam": 3.5,
}
ESTIMATE_DEFAULT_S = 12.0
ESTIMATE_PARTICLES = 10
#: ... times ``1 + ESTIMATE_LOG_SLOPE * ln(n / ESTIMATE_PARTICLES)`` for ``n`` particles above
#: that (the particles are vectorised: the program grows slowly with them) ...
ESTIMATE_LOG_SLOPE = 0.83
#: ... times this factor for a program of several runs side by side (a sweep batch, a comparison's
#: seeds).
ESTIMATE_BATCH_FACTOR = 1.3


def estimate_compile_s(method: str, n_particles: int, batch: int = 1) -> float:
    """A rough compile time of a filter program in seconds, from the method, the particle count
    and whether it computes several runs (the constants above, fitted to measured compiles; the
    expected time when no compile of the program's shape is recorded)."""
    s = ESTIMATE_BASE_S.get(method, ESTIMATE_DEFAULT_S)
    if n_particles > ESTIMATE_PARTICLES:
        s *= 1.0 + ESTIMATE_LOG_SLOPE * math.log(n_particles / ESTIMATE_PARTICLES)
    return s * (ESTIMATE_BATCH_FACTOR if batch > 1 else 1.0)


def _method_name(static: Any) -> str:
    method = getattr(static, "method", None)
    return str(getattr(method, "name", method or "program"))


def _has_particles(static: Any) -> bool:
    return getattr(getattr(static, "method", None), "kind", "particle") == "particle"


def program_signature(info: ProgramInfo) -> str:
    """The key of a program's shape in the timing store: the method, particles, landmark
    capacity, ``k_max``, segments per call, row buckets, devices and runs side by side, readable,
    then a digest of the whole static settings, the label and every argument's shape (two programs
    with the same key compile the same shapes)."""
    s = info.static
    buckets = ",".join(str(b) for b in getattr(s, "row_buckets", ()) or ())
    digest = hashlib.sha256("\0".join([info.label, repr(s), *info.shapes]).encode()).hexdigest()[:12]
    return (
        f"{_method_name(s)} particles={getattr(s, 'n_particles', 0)} capacity={getattr(s, 'capacity', 0)} "
        f"k_max={getattr(s, 'k_max', 0)} segments={info.segments} rows=[{buckets}] "
        f"devices={getattr(s, 'devices', 1)} batch={info.batch} {digest}"
    )


def describe(info: ProgramInfo) -> str:
    """``filter program (nano, 4 particles, 120 segments per call)``."""
    s = info.static
    parts = [_method_name(s)]
    n = getattr(s, "n_particles", None)
    if n is not None and _has_particles(s):
        parts.append(f"{n} particle{'s' if n != 1 else ''}")
    if info.batch > 1:
        parts.append(f"{info.batch} runs side by side")
    parts.append(f"{info.segments} segments per call")
    return f"{info.label} ({', '.join(parts)})"


class TimingStore:
    """Measured compile and load times by :func:`program_signature`, in a JSON file.

    The file holds ``{"format": 1, "programs": {key: {"compile_s", "load_s", "last", "program",
    "updated"}}}``: the last compile's and the last load's seconds, which of them came last, the
    program's description and when. It is read afresh and replaced atomically at each record, so
    processes sharing a cache directory keep each other's entries (the last writer wins a race).
    A file that does not read is treated as empty.
    """

    def __init__(self, path: str | os.PathLike):
        self.path = Path(path)

    def read(self) -> dict[str, dict]:
        try:
            data = json.loads(self.path.read_text())
        except (OSError, ValueError):
            return {}
        programs = data.get("programs") if isinstance(data, dict) and data.get("format") == _STORE_FORMAT else None
        return {k: v for k, v in programs.items() if isinstance(v, dict)} if isinstance(programs, dict) else {}

    def get(self, key: str) -> Optional[dict]:
        return self.read().get(key)

    def record(self, key: str, loaded: bool, seconds: float, program: str) -> None:
        """Keep ``seconds`` as the last load (``loaded``) or compile of ``key``; a file that cannot
        be written is left as it is."""
        programs = self.read()
        entry = dict(programs.get(key, {}))
        entry["load_s" if loaded else "compile_s"] = round(float(seconds), 3)
        entry.update(
            last="load" if loaded else "compile",
            program=program,
            updated=datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
        )
        programs[key] = entry
        text = json.dumps({"format": _STORE_FORMAT, "programs": programs}, indent=1, sort_keys=True) + "\n"
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            fd, tmp = tempfile.mkstemp(dir=self.path.parent, prefix=self.path.name, suffix=".tmp")
            try:
                with os.fdopen(fd, "w") as f:
                    f.write(text)
                os.chmod(tmp, 0o644)
                os.replace(tmp, self.path)
            except BaseException:
                Path(tmp).unlink(missing_ok=True)
                raise
        except OSError:
            pass


def _seconds(s: float) -> str:
    return f"{s:.1f} s" if s < 10 else f"{s:.0f} s"


class _Compile:
    """One compilation followed by a :class:`CompileReporter` (its :class:`CompileHandle`)."""

    def __init__(self, reporter: "CompileReporter", info: ProgramInfo):
        self.reporter, self.info = reporter, info
        self.what = describe(info)
        self.key = program_signature(info)
        self.store = TimingStore(Path(info.cache_dir) / STORE_NAME) if info.cache_dir else None
        entry = self.store.get(self.key) if self.store is not None else None
        self.loading, self.expected = self._expectation(entry or {})
        self.t0 = reporter.clock()
        self._stop = threading.Event()
        self._thread: Optional[threading.Thread] = None
        if self.reporter.tty:
            self._write("\r\033[K" + self._fit(self.start_line()))
            if reporter.interval > 0:
                self._thread = threading.Thread(target=self._tick_loop, name="nanoslam-compile-clock", daemon=True)
                self._thread.start()
        else:
            self._write(self.start_line() + "\n")

    def _expectation(self, entry: dict) -> tuple[bool, str]:
        """Whether the program should load from the cache, and the expected time as words."""
        info = self.info
        if info.cache_dir is None:
            est = estimate_compile_s(_method_name(info.static), getattr(info.static, "n_particles", 1), info.batch)
            return False, f"about {est:.0f} s (estimate; the compilation cache is off)"
        compile_s, load_s = entry.get("compile_s"), entry.get("load_s")
        # In the cache when its traced program is there, or (nothing tells) when it was measured before.
        loading = info.expect_load if info.expect_load is not None else bool(entry)
        if loading and isinstance(load_s, (int, float)):
            return True, f"expected {_seconds(load_s)} (last load)"
        if isinstance(compile_s, (int, float)):
            if loading:
                return True, f"expected well under its last compile's {_seconds(compile_s)}"
            return False, f"expected {_seconds(compile_s)} (last compile)"
        est = estimate_compile_s(_method_name(info.static), getattr(info.static, "n_particles", 1), info.batch)
        if loading:
            return True, "expected a few seconds (estimate)"
        return False, f"about {est:.0f} s (estimate)"

    def start_line(self) -> str:
        if self.loading:
            return f"nanoslam: loading the {self.what} from the compilation cache: {self.expected}"
        return f"nanoslam: compiling the {self.what}: {self.expected}"

    def tick(self) -> None:
        """Write the start line with the time elapsed (a terminal only: the line is rewritten)."""
        if self.reporter.tty and not self._stop.is_set():
            elapsed = self.reporter.clock() - self.t0
            self._write("\r\033[K" + self._fit(f"{self.start_line()} [{elapsed:.0f} s elapsed]"))

    def _tick_loop(self) -> None:
        while not self._stop.wait(self.reporter.interval):
            try:
                self.tick()
            except Exception:  # a closed stream: stop ticking, never raise in this thread
                return

    def _end(self, line: str) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=5)
        self._write(("\r\033[K" if self.reporter.tty else "") + line + "\n")

    def finished(self, loaded: bool) -> None:
        seconds = self.reporter.clock() - self.t0
        if loaded:
            self._end(f"nanoslam: loaded the {self.what} from the compilation cache in {seconds:.1f} s")
        else:
            self._end(f"nanoslam: compiled the {self.what} in {seconds:.1f} s")
        if self.store is not None:
            self.store.record(self.key, loaded, seconds, self.what)

    def failed(self, error: BaseException) -> None:
        seconds = self.reporter.clock() - self.t0
        how = "interrupted" if isinstance(error, KeyboardInterrupt) else "failed"
        self._end(f"nanoslam: compiling the {self.what} {how} after {seconds:.1f} s")

    def _fit(self, line: str) -> str:
        width = (self.reporter.width or shutil.get_terminal_size((120, 24)).columns) - 1
        return line if len(line) <= width else line[: max(width - 3, 0)] + "..."

    def _write(self, text: str) -> None:
        stream = self.reporter.stream
        if stream is None:
            return
        with self.reporter.lock:
            stream.write(text)
            stream.flush()


class CompileReporter:
    """The watcher of compilations the commands install: writes the compile messages on
    ``stream`` and records the measured times in the cache directory's :class:`TimingStore`.

    Args:
        stream: where the messages go (None: write nothing, record the times only).
        clock: seconds, monotonic (``time.monotonic``; a fake one in tests).
        tty: whether ``stream`` is a terminal (None: ask it). On a terminal the start line is
            rewritten with the time elapsed; elsewhere a start and a done line are written.
        interval: seconds between the rewrites (0: none, :meth:`_Compile.tick` by hand).
        width: the terminal's width the rewritten line is cut to (None: ask the terminal).
    """

    def __init__(
        self,
        stream: Optional[TextIO] = sys.stderr,
        *,
        clock: Callable[[], float] = time.monotonic,
        tty: Optional[bool] = None,
        interval: float = 1.0,
        width: Optional[int] = None,
    ):
        self.stream, self.clock, self.interval, self.width = stream, clock, interval, width
        isatty = getattr(stream, "isatty", None)
        self.tty = bool(isatty()) if tty is None and callable(isatty) else bool(tty)
        self.lock = threading.Lock()

    def start(self, info: ProgramInfo) -> _Compile:
        return _Compile(self, info)


@contextlib.contextmanager
def compile_messages(enabled: bool = True, stream: Optional[TextIO] = None) -> Iterator[CompileReporter]:
    """Install a :class:`CompileReporter` for the block: messages on ``stream`` (stderr) when
    ``enabled``; the measured times are recorded either way."""
    reporter = CompileReporter((stream or sys.stderr) if enabled else None)
    with watch_compiles(reporter):
        yield reporter
