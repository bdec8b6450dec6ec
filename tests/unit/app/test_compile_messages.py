"""The compile messages of the commands (``nanoslam_jax.app._compile_report``): what compiles, the
time expected, the time elapsed, and a load from the persistent cache said as such.

The reporter's unit tests use a fake clock and an in-memory stream (no program is compiled); the
end-to-end test runs ``nanoslam run`` in fresh processes on one temporary cache directory.
"""

import io
import json
import os
import subprocess
import sys
import threading
import time

import pytest

from nanoslam_jax.app._compile_report import (
    STORE_NAME,
    CompileReporter,
    TimingStore,
    estimate_compile_s,
    program_signature,
)
from tests.helpers.internals import CACHE_ENV, ProgramInfo, watch_compiles, watched_compile
from nanoslam_jax.methods import FASTSLAM1, Static
from tests.helpers.paths import REPO_ROOT


class FakeClock:
    def __init__(self):
        self.now = 100.0

    def __call__(self) -> float:
        return self.now


class FakeTTY(io.StringIO):
    def isatty(self) -> bool:
        return True


def _info(cache_dir=None, expect_load=False, **static) -> ProgramInfo:
    s = Static(method=FASTSLAM1, n_particles=4, capacity=64, k_max=8, **static)
    return ProgramInfo("filter program", s, ("float64[47,8]", "bool[47]"), 47, 1, cache_dir, expect_load)


def test_non_tty_writes_a_start_and_a_done_line_and_records_the_time(tmp_path):
    clock, out = FakeClock(), io.StringIO()
    reporter = CompileReporter(out, clock=clock, tty=False)
    info = _info(str(tmp_path))
    h = reporter.start(info)
    clock.now += 31.24
    h.finished(loaded=False)
    lines = out.getvalue().splitlines()
    assert lines == [
        "nanoslam: compiling the filter program (fastslam1, 4 particles, 47 segments per call): "
        f"about {estimate_compile_s('fastslam1', 4):.0f} s (estimate)",
        "nanoslam: compiled the filter program (fastslam1, 4 particles, 47 segments per call) in 31.2 s",
    ]
    entry = TimingStore(tmp_path / STORE_NAME).get(program_signature(info))
    assert entry is not None and entry["compile_s"] == pytest.approx(31.24) and entry["last"] == "compile"

    # The same shape again: the last compile is the expected time; a load is said as such.
    out2 = io.StringIO()
    h = CompileReporter(out2, clock=clock, tty=False).start(_info(str(tmp_path)))
    clock.now += 0.8
    h.finished(loaded=True)
    first, done = out2.getvalue().splitlines()
    assert first.endswith(": expected 31 s (last compile)")
    assert done.endswith(" from the compilation cache in 0.8 s") and "loaded the filter program" in done
    out3 = io.StringIO()
    CompileReporter(out3, clock=clock, tty=False).start(_info(str(tmp_path), expect_load=True))
    assert out3.getvalue().rstrip().endswith("from the compilation cache: expected 0.8 s (last load)")
    # Another shape (more particles) has no record of its own.
    s8 = ProgramInfo("filter program", Static(method=FASTSLAM1, n_particles=8, capacity=64, k_max=8), (), 47)
    assert program_signature(s8) != program_signature(info)


def test_tty_rewrites_one_line_with_the_time_elapsed():
    clock, out = FakeClock(), FakeTTY()
    reporter = CompileReporter(out, clock=clock, interval=0, width=200)  # ticks by hand
    h = reporter.start(_info(None))
    for _ in range(3):
        clock.now += 1.0
        h.tick()
    clock.now += 0.5
    h.finished(loaded=False)
    text = out.getvalue()
    assert text.count("\n") == 1 and text.endswith(" in 3.5 s\n")
    frames = text.split("\r\033[K")[1:]
    assert len(frames) == 5  # the start line, three ticks, the done line
    assert "the compilation cache is off" in frames[0] and frames[0].startswith("nanoslam: compiling")
    assert [f.removeprefix(frames[0]) for f in frames[1:4]] == [f" [{i} s elapsed]" for i in (1, 2, 3)]


def test_the_clock_thread_stops_on_an_error_and_on_an_interrupt():
    for error in (RuntimeError("boom"), KeyboardInterrupt()):
        out = FakeTTY()
        reporter = CompileReporter(out, interval=0.01)
        before = set(threading.enumerate())
        with pytest.raises(type(error)), watch_compiles(reporter):
            with watched_compile("filter program", Static(method=FASTSLAM1), (), segments=10):
                time.sleep(0.05)
                raise error
        assert not [t for t in set(threading.enumerate()) - before if t.name == "nanoslam-compile-clock"]
        last = out.getvalue().rsplit("\r\033[K", 1)[-1]
        assert ("interrupted after" if isinstance(error, KeyboardInterrupt) else "failed after") in last
        assert last.endswith(" s\n")


def test_a_failing_watcher_never_stops_a_compilation():
    class Broken:
        def start(self, info):
            raise OSError("stream closed")

    with watch_compiles(Broken()):
        with watched_compile("filter program", Static(), (), segments=1):
            ran = True
    assert ran


def test_an_unreadable_store_is_empty(tmp_path):
    (tmp_path / STORE_NAME).write_text("{not json")
    store = TimingStore(tmp_path / STORE_NAME)
    assert store.read() == {}
    store.record("k", False, 2.0, "p")
    assert store.get("k")["compile_s"] == 2.0


# --------------------------------------------------------------------------- end to end

TINY = [
    "--set",
    "filter.method=fastslam1",
    "--set",
    "filter.n_particles=2",
    "--set",
    "filter.capacity=64",
    "--set",
    "filter.window=16",
    "--set",
    "sim.duration=10",
    "--set",
    "output.plots=false",
]


@pytest.mark.slow
def test_run_says_it_compiles_then_that_it_loads_from_the_cache(tmp_path):
    cache = tmp_path / "jax"
    root = str(REPO_ROOT)
    env = {**os.environ, CACHE_ENV: str(cache), "PYTHONPATH": os.pathsep.join([root, os.environ.get("PYTHONPATH", "")])}
    env.pop("JAX_COMPILATION_CACHE_DIR", None)

    def run(name, *extra):
        res = subprocess.run(
            [sys.executable, "-m", "nanoslam_jax.app.cli", "run", "--out", str(tmp_path / name), *TINY, *extra],
            capture_output=True,
            text=True,
            env=env,
            timeout=600,
        )
        assert res.returncode == 0, res.stderr[-3000:]
        return [line for line in res.stderr.splitlines() if "filter program" in line]

    first = run("first")
    assert len(first) == 2, first
    assert first[0].startswith("nanoslam: compiling the filter program (fastslam1, 2 particles, ")
    assert "about " in first[0] and "estimate" in first[0]
    assert first[1].startswith("nanoslam: compiled the filter program") and first[1].endswith(" s")
    (entry,) = json.loads((cache / STORE_NAME).read_text())["programs"].values()
    assert entry["last"] == "compile" and entry["compile_s"] > 0

    second = run("second")
    assert len(second) == 2, second
    assert second[0].startswith("nanoslam: loading the filter program") and "from the compilation cache" in second[0]
    assert f"{entry['compile_s']:.0f} s" in second[0] or f"{entry['compile_s']:.1f} s" in second[0]
    assert "loaded the filter program" in second[1] and "from the compilation cache in " in second[1]
    (after,) = json.loads((cache / STORE_NAME).read_text())["programs"].values()
    assert after["compile_s"] == entry["compile_s"] and after["last"] == "load" and after["load_s"] > 0

    assert run("quiet", "--quiet") == []
