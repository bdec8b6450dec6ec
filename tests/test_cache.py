"""The persistent compilation cache: a second run in a fresh process loads the filter program
instead of compiling it, gives the same outputs, and ``--no-cache`` bypasses the cache.

Hits and misses are JAX's own statistics (its monitoring events, which ``nanoslam run`` records
in ``metrics.json``), not wall-clock times. Each run is a fresh ``nanoslam`` process with
``NANOSLAM_CACHE_DIR`` pointing at a test directory.
"""

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from nanoslam_jax._cache import CACHE_ENV, default_cache_dir

# A small run that still compiles the whole filter program: FastSLAM 1.0 on 20 s of the simulated log.
SMALL = ["--set", "filter.method=fastslam1", "--set", "filter.capacity=64", "--set", "filter.window=16",
         "--set", "sim.duration=20", "--set", "output.plots=false", "--quiet"]


def _run(out: Path, cache: Path, *extra: str) -> dict:
    env = {**os.environ, CACHE_ENV: str(cache)}
    env.pop("JAX_COMPILATION_CACHE_DIR", None)
    res = subprocess.run([sys.executable, "-m", "nanoslam_jax.cli", "run", "--out", str(out), *SMALL, *extra],
                         capture_output=True, text=True, env=env, timeout=600)
    assert res.returncode == 0, res.stderr
    return json.loads((out / "metrics.json").read_text())


def _files(d: Path) -> set:
    return {p.relative_to(d) for p in d.rglob("*") if p.is_file()}


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """The same run three times in fresh processes: cold cache, warm cache, warm cache with --no-cache."""
    root = tmp_path_factory.mktemp("cache")
    cache = root / "jax"
    first = _run(root / "first", cache)
    files_after_first = _files(cache)
    second = _run(root / "second", cache)
    files_after_second = _files(cache)
    bypass = _run(root / "bypass", cache, "--no-cache")
    return dict(root=root, cache=cache, first=first, second=second, bypass=bypass,
                files=(files_after_first, files_after_second, _files(cache)))


def test_first_run_compiles_and_writes_the_cache(runs):
    c = runs["first"]["compilation"]
    assert c["cache_dir"] == str(runs["cache"])
    assert c["cache_hits"] == 0 and c["cache_misses"] >= 1
    assert runs["files"][0], "the first run wrote nothing to the cache directory"


def test_second_run_in_a_fresh_process_loads_from_the_cache(runs):
    first, second = runs["first"]["compilation"], runs["second"]["compilation"]
    assert second["cache_hits"] >= 1
    assert second["cache_misses"] == 0, "a program was compiled again in the second run"
    assert runs["files"][1] == runs["files"][0], "the second run wrote new cache entries"
    # JAX's own accounting: loading is cheaper than compiling (not a wall-clock target).
    assert second["backend_s"] < first["backend_s"]


def test_cached_run_gives_identical_outputs(runs):
    root = runs["root"]
    for name in ("trajectory.csv", "map.csv"):
        assert (root / "first" / name).read_bytes() == (root / "second" / name).read_bytes(), name
    keys = ["rmse_fixed", "rmse_aligned", "n_landmarks", "resample_count"]
    assert {k: runs["first"][k] for k in keys} == {k: runs["second"][k] for k in keys}


def test_no_cache_bypasses_the_cache(runs):
    c = runs["bypass"]["compilation"]
    assert c["cache_dir"] is None
    assert c["cache_hits"] == 0 and c["cache_misses"] == 0  # the cache was never consulted
    assert runs["files"][2] == runs["files"][1]
    root = runs["root"]
    assert (root / "bypass" / "trajectory.csv").read_bytes() == (root / "first" / "trajectory.csv").read_bytes()


def test_cache_directory_default_and_override(monkeypatch, tmp_path):
    monkeypatch.delenv(CACHE_ENV, raising=False)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    assert default_cache_dir() == tmp_path / "xdg" / "nanoslam-jax" / "jax"
    monkeypatch.delenv("XDG_CACHE_HOME")
    assert default_cache_dir() == Path.home() / ".cache" / "nanoslam-jax" / "jax"
    monkeypatch.setenv(CACHE_ENV, str(tmp_path / "elsewhere"))
    assert default_cache_dir() == tmp_path / "elsewhere"


def test_unwritable_cache_directory_is_a_clear_error(tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("not a directory")
    env = {**os.environ, CACHE_ENV: str(blocker / "jax")}
    env.pop("JAX_COMPILATION_CACHE_DIR", None)
    res = subprocess.run([sys.executable, "-m", "nanoslam_jax.cli", "run", "--out", str(tmp_path / "r"), *SMALL],
                         capture_output=True, text=True, env=env, timeout=300)
    assert res.returncode == 2
    assert "Traceback" not in res.stderr
    assert str(blocker / "jax") in res.stderr and CACHE_ENV in res.stderr and "--no-cache" in res.stderr
