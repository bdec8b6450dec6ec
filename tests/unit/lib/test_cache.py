"""The persistent compilation cache: a second run in a fresh process loads the filter program
instead of compiling it, gives the same outputs, and ``--no-cache`` bypasses the cache.

Hits and misses are JAX's own statistics (its monitoring events, which ``nanoslam run`` records
in ``metrics.json``), not wall-clock times. Each run is a fresh ``nanoslam`` process with
``NANOSLAM_CACHE_DIR`` pointing at a test directory.
"""

import functools
import json
import os
import pickle
import subprocess
import sys
from pathlib import Path
from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from nanoslam_jax.lib import _cache
from nanoslam_jax.lib._cache import CACHE_ENV, compile_program, default_cache_dir, program_key
from tests.helpers.paths import REPO_ROOT

# A small run that still compiles the whole filter program: FastSLAM 1.0 on 20 s of the simulated log.
SMALL = [
    "--set",
    "filter.method=fastslam1",
    "--set",
    "filter.capacity=64",
    "--set",
    "filter.window=16",
    "--set",
    "sim.duration=20",
    "--set",
    "output.plots=false",
    "--quiet",
]


def _run(out: Path, cache: Path, *extra: str) -> dict:
    env = {**os.environ, CACHE_ENV: str(cache)}
    env.pop("JAX_COMPILATION_CACHE_DIR", None)
    res = subprocess.run(
        [sys.executable, "-m", "nanoslam_jax.app.cli", "run", "--out", str(out), *SMALL, *extra],
        capture_output=True,
        text=True,
        env=env,
        timeout=600,
    )
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
    return dict(
        root=root,
        cache=cache,
        first=first,
        second=second,
        bypass=bypass,
        files=(files_after_first, files_after_second, _files(cache)),
    )


@pytest.mark.slow
def test_first_run_compiles_and_writes_the_cache(runs):
    c = runs["first"]["compilation"]
    assert c["cache_dir"] == str(runs["cache"])
    assert c["cache_hits"] == 0 and c["cache_misses"] >= 1
    files = runs["files"][0]
    assert [f for f in files if f.parts[0] == "exported"], "no traced program was kept"
    assert [f for f in files if f.parts[0] != "exported"], "no executable was kept"


@pytest.mark.slow
def test_second_run_in_a_fresh_process_loads_from_the_cache(runs):
    first, second = runs["first"]["compilation"], runs["second"]["compilation"]
    assert second["cache_hits"] >= 1
    # A program that compiles in under the cache's minimum compile time is looked up, compiled and
    # not written, in either run (a miss each time, how many depends on the machine's speed); one
    # that takes longer is written by the first run, so a second run that compiled it again would
    # write it again: the second run adds no entry.
    assert second["cache_misses"] <= first["cache_misses"]
    assert runs["files"][1] == runs["files"][0], "the second run compiled and wrote a program the first had kept"
    # JAX's own accounting (not a wall-clock target): loading is cheaper than compiling, and the
    # filter step was not traced again (its traced program came from the cache).
    assert second["backend_s"] < first["backend_s"]
    assert second["trace_s"] < 0.25 * first["trace_s"]


@pytest.mark.slow
def test_cached_run_gives_identical_outputs(runs):
    root = runs["root"]
    for name in ("trajectory.csv", "map.csv"):
        assert (root / "first" / name).read_bytes() == (root / "second" / name).read_bytes(), name
    keys = ["rmse_fixed", "rmse_aligned", "n_landmarks", "resample_count"]
    assert {k: runs["first"][k] for k in keys} == {k: runs["second"][k] for k in keys}


@pytest.mark.slow
def test_a_run_never_executes_a_pickle_planted_in_the_cache(runs, tmp_path):
    """Every traced-program entry of a warm cache replaced by a pickle that would create a file
    when unpickled: a fresh run executes none of them, traces afresh, gives the uncached run's
    outputs and puts real entries back."""
    import shutil

    cache = tmp_path / "jax"
    shutil.copytree(runs["cache"], cache)
    marker = tmp_path / "executed"
    entries = sorted((cache / "exported").glob("*.bin"))
    assert entries
    for entry in entries:
        entry.write_bytes(pickle.dumps(_Planted(marker)))
    _run(tmp_path / "planted", cache)
    assert not marker.exists(), "a file of the cache directory was unpickled"
    for name in ("trajectory.csv", "map.csv"):
        assert (tmp_path / "planted" / name).read_bytes() == (runs["root"] / "bypass" / name).read_bytes(), name
    for entry in entries:  # traced afresh and written again
        assert entry.read_bytes().startswith(_cache._MAGIC)


@pytest.mark.slow
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


@pytest.mark.slow
def test_unwritable_cache_directory_is_a_clear_error(tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("not a directory")
    env = {**os.environ, CACHE_ENV: str(blocker / "jax")}
    env.pop("JAX_COMPILATION_CACHE_DIR", None)
    res = subprocess.run(
        [sys.executable, "-m", "nanoslam_jax.app.cli", "run", "--out", str(tmp_path / "r"), *SMALL],
        capture_output=True,
        text=True,
        env=env,
        timeout=300,
    )
    assert res.returncode == 2
    assert "Traceback" not in res.stderr
    assert str(blocker / "jax") in res.stderr and CACHE_ENV in res.stderr and "--no-cache" in res.stderr


@pytest.mark.parametrize("argv", [["run"], ["compare", "x.yaml"], ["sweep", "x.yaml"], ["simulate", "--out", "d"]])
def test_every_computing_command_takes_no_cache(argv):
    from nanoslam_jax.app.cli import _parser

    assert _parser().parse_args([*argv, "--no-cache"]).no_cache is True
    assert _parser().parse_args(argv).no_cache is False


# --------------------------------------------------------------------------- traced programs, in-process


@functools.partial(jax.jit, static_argnames=("scale",))
def _toy(scale: float, x, y):
    return {"sum": jnp.sum(x) * scale, "prod": x * y[0]}


@pytest.fixture
def toy_cache(tmp_path, monkeypatch):
    """A directory for compile_program's traced programs in this process (JAX's XLA layer left as it is)."""
    monkeypatch.setattr(_cache, "_exported_dir", lambda: tmp_path)
    return tmp_path


def _entries(d: Path) -> set:
    return {p.name for p in d.glob("*.bin")}


def test_compile_program_keeps_and_reuses_the_traced_program(toy_cache, monkeypatch):
    x, y = jnp.arange(4.0), (jnp.ones(4) * 2,)
    direct = _toy.lower(3.0, x, y).compile()(x, y)
    first = compile_program(_toy, 3.0, x, y)
    assert len(_entries(toy_cache)) == 1
    assert compile_program(_toy, 3.0, x, y) is first  # in this process: the compiled program itself
    # As in a fresh process (nothing compiled yet): the entry is read, not traced again.
    monkeypatch.setattr(_cache, "_COMPILED", {})
    monkeypatch.setattr(jax.export, "export", lambda *a, **k: pytest.fail("traced again"))
    second = compile_program(_toy, 3.0, x, y)
    assert second is not first
    for out in (first(x, y), second(x, y)):
        assert jax.tree.structure(out) == jax.tree.structure(direct)
        for a, b in zip(jax.tree.leaves(out), jax.tree.leaves(direct)):
            np.testing.assert_array_equal(a, b)
    assert len(_entries(toy_cache)) == 1


def test_program_key_changes_with_static_shapes_dtypes_sources_and_versions(monkeypatch):
    _cache._environment_digest.cache_clear()  # a digest cached by an earlier test under another JAX config
    x, y = jnp.arange(4.0), (jnp.ones(4),)
    base = program_key(_toy, 3.0, (x, y))
    assert program_key(_toy, 3.0, (x, y)) == base
    assert program_key(_toy, 4.0, (x, y)) != base  # a static setting
    assert program_key(_toy, 3.0, (jnp.arange(5.0), y)) != base  # a shape
    assert program_key(_toy, 3.0, (x.astype(jnp.float32), y)) != base  # a dtype
    assert program_key(_toy, 3.0, ((x, y),)) != base  # the tree structure
    # The package's sources and the installed versions (jax, jaxlib, equinox, ...) enter the key.
    _cache._environment_digest.cache_clear()
    real = _cache.Path.read_bytes

    def edited(self):
        data = real(self)
        return data + b"# edited" if self.name == "_scan.py" else data

    monkeypatch.setattr(_cache.Path, "read_bytes", edited)
    assert program_key(_toy, 3.0, (x, y)) != base
    monkeypatch.setattr(_cache.Path, "read_bytes", real)
    _cache._environment_digest.cache_clear()
    assert program_key(_toy, 3.0, (x, y)) == base
    dists = list(_cache.importlib.metadata.distributions())

    class Upgraded:
        metadata = {"Name": "jax"}
        version = "999.0"

    monkeypatch.setattr(_cache.importlib.metadata, "distributions", lambda: dists + [Upgraded()])
    _cache._environment_digest.cache_clear()
    assert program_key(_toy, 3.0, (x, y)) != base
    _cache._environment_digest.cache_clear()


class _Planted:
    """Unpickling this creates the file ``marker`` (``open(marker, "w")``): the proof that a file
    of the cache directory was unpickled."""

    def __init__(self, marker: Path):
        self.marker = str(marker)

    def __reduce__(self):
        return open, (self.marker, "w")


def _header(entry: Path) -> dict:
    data = entry.read_bytes()
    assert data.startswith(_cache._MAGIC)
    start = len(_cache._MAGIC) + 8
    return json.loads(data[start : start + int.from_bytes(data[len(_cache._MAGIC) : start], "big")])


def _count_exports(monkeypatch) -> list:
    calls, real = [], jax.export.export

    def counting(*a, **k):
        calls.append(1)
        return real(*a, **k)

    monkeypatch.setattr(jax.export, "export", counting)
    return calls


def test_a_planted_pickle_is_never_executed(toy_cache, tmp_path_factory, monkeypatch):
    """A pickle planted under the very name the entry of this program has (and its pickle in the
    layout an older version read) is not unpickled: the run traces afresh, gives the uncached
    program's outputs and overwrites the file with a real entry."""
    marker = tmp_path_factory.mktemp("planted") / "executed"
    x, y = jnp.arange(4.0), (jnp.ones(4) * 2,)
    direct = _toy.lower(3.0, x, y).compile()(x, y)
    entry = toy_cache / f"{program_key(_toy, 3.0, (x, y))}.bin"
    for payload in (pickle.dumps(_Planted(marker)), pickle.dumps((b"\0" * 64, _Planted(marker)))):
        pickle.loads(payload)  # the payload does what it says, when it is unpickled
        assert marker.exists()
        marker.unlink()
        entry.write_bytes(payload)
        monkeypatch.setattr(_cache, "_COMPILED", {})  # as in a fresh process
        exports = _count_exports(monkeypatch)
        out = compile_program(_toy, 3.0, x, y)(x, y)
        assert not marker.exists(), "a file of the cache directory was unpickled"
        assert exports == [1]
        assert jax.tree.structure(out) == jax.tree.structure(direct)
        for a, b in zip(jax.tree.leaves(out), jax.tree.leaves(direct)):
            np.testing.assert_array_equal(a, b)
        assert _header(entry)["key"] == entry.stem


def _truncate(entry: Path, other: Path) -> None:
    entry.write_bytes(entry.read_bytes()[:-100])


def _flip_a_program_byte(entry: Path, other: Path) -> None:
    data = bytearray(entry.read_bytes())
    data[-200] ^= 0xFF
    entry.write_bytes(bytes(data))


def _another_programs_entry(entry: Path, other: Path) -> None:
    entry.write_bytes(other.read_bytes())  # a valid entry, of another program, under this one's name


def _rewrite_header(change):
    def damage(entry: Path, other: Path) -> None:
        data = entry.read_bytes()
        start = len(_cache._MAGIC) + 8
        size = int.from_bytes(data[len(_cache._MAGIC) : start], "big")
        header = json.loads(data[start : start + size])
        change(header)
        raw = json.dumps(header).encode()
        entry.write_bytes(_cache._MAGIC + len(raw).to_bytes(8, "big") + raw + data[start + size :])

    return damage


def _claim_a_function(h):  # an output node naming a callable that is no NamedTuple
    h["out_tree"]["children"][1]["class"] = "os:system"


def _claim_an_unimported_module(h):  # an output node naming a module this process has not imported
    h["out_tree"]["children"][1]["class"] = "nanoslam_test_not_a_module:Out"


def _claim_other_inputs(h):
    h["in_tree"] = h["in_tree"].replace("*", "*, *", 1)


@pytest.mark.parametrize(
    "damage",
    [
        lambda e, o: e.write_bytes(b"not a program"),
        lambda e, o: e.write_bytes(b""),
        _truncate,
        _flip_a_program_byte,
        _another_programs_entry,
        _rewrite_header(_claim_a_function),
        _rewrite_header(_claim_an_unimported_module),
        _rewrite_header(_claim_other_inputs),
    ],
    ids=["garbage", "empty", "truncated", "flipped-byte", "other-program", "function", "unimported", "inputs"],
)
def test_a_damaged_entry_is_a_miss_traced_again_and_overwritten(toy_cache, monkeypatch, damage):
    x, y = jnp.arange(3.0), (jnp.ones(3) * 2,)
    model = _Model(gain=jnp.float64(0.5), name="m")
    expected = _step_fn.lower(2, model, _State(x, y[0]), x).compile()(model, _State(x, y[0]), x)
    compile_program(_step_fn, 2, model, _State(x, y[0]), x)
    compile_program(_step_fn, 3, model, _State(x, y[0]), x)
    entry = toy_cache / f"{program_key(_step_fn, 2, (model, _State(x, y[0]), x))}.bin"
    (other,) = {p for p in toy_cache.glob("*.bin")} - {entry}
    damage(entry, other)
    monkeypatch.setattr(_cache, "_COMPILED", {})  # as in a fresh process
    exports = _count_exports(monkeypatch)
    out = compile_program(_step_fn, 2, model, _State(x, y[0]), x)(model, _State(x, y[0]), x)
    assert exports == [1], "the damaged entry was not traced again"
    assert jax.tree.structure(out) == jax.tree.structure(expected)
    for a, b in zip(jax.tree.leaves(out), jax.tree.leaves(expected)):
        np.testing.assert_array_equal(a, b)
    # Overwritten with a good entry: the next fresh process reads it without tracing.
    monkeypatch.setattr(_cache, "_COMPILED", {})
    compile_program(_step_fn, 2, model, _State(x, y[0]), x)
    assert exports == [1]


class _State(NamedTuple):
    pose: jax.Array
    weight: jax.Array


class _Record(NamedTuple):
    total: jax.Array
    parts: dict
    missing: None


class _Model(eqx.Module):
    gain: jax.Array
    name: str = eqx.field(static=True)


@functools.partial(jax.jit, static_argnames=("k",))
def _step_fn(k: int, model: _Model, state: _State, u):
    new = _State(state.pose + model.gain * u * k, state.weight * 0.5)
    return (model, state, new), _Record(jnp.sum(new.pose), {"b": new.weight, "a": [u, (u * 2,)]}, None)


def test_outputs_of_namedtuples_dicts_and_input_subtrees_are_kept(toy_cache, monkeypatch):
    """The output tree is kept as plain data: builtin containers, NamedTuples of imported modules
    and subtrees equal to the inputs' (here an equinox module with a static field), rebuilt exactly."""
    x = jnp.arange(3.0)
    args = (_Model(gain=jnp.float64(0.5), name="m"), _State(x, x + 1), x)
    expected = _step_fn.lower(2, *args).compile()(*args)
    compile_program(_step_fn, 2, *args)
    (entry,) = toy_cache.glob("*.bin")
    assert _header(entry)["out_tree"]["children"][0]["children"][0] == {"input": [0]}
    monkeypatch.setattr(_cache, "_COMPILED", {})
    monkeypatch.setattr(jax.export, "export", lambda *a, **k: pytest.fail("traced again"))
    out = compile_program(_step_fn, 2, *args)(*args)
    assert jax.tree.structure(out) == jax.tree.structure(expected)
    assert isinstance(out[1], _Record) and out[0][0].name == "m"
    for a, b in zip(jax.tree.leaves(out), jax.tree.leaves(expected)):
        np.testing.assert_array_equal(a, b)


@jax.jit
def _new_model(_, x):
    return _Model(gain=jnp.sum(x), name="made")


def test_an_output_not_described_as_data_is_compiled_but_not_kept(toy_cache, monkeypatch):
    x = jnp.arange(3.0)
    first = compile_program(_new_model, None, x)
    assert not list(toy_cache.iterdir()), "an equinox module made by the program was kept"
    assert first(x).gain == 3.0 and first(x).name == "made"
    monkeypatch.setattr(_cache, "_COMPILED", {})
    exports = _count_exports(monkeypatch)
    assert compile_program(_new_model, None, x)(x).gain == 3.0
    assert exports == [1]


def test_without_a_cache_directory_nothing_is_written(monkeypatch):
    monkeypatch.setattr(_cache, "_exported_dir", lambda: None)
    monkeypatch.setattr(jax.export, "export", lambda *a, **k: pytest.fail("exported without a cache"))
    x, y = jnp.arange(3.0), (jnp.ones(3),)
    np.testing.assert_array_equal(compile_program(_toy, 2.0, x, y)(x, y)["prod"], x)


@functools.partial(jax.jit, static_argnames=("k",))
def _qr_solve(k: int, a, b):
    import lineax as lx

    # Least squares by lineax's QR: a LAPACK custom call (ormqr) whose ABI jax.export does not
    # guarantee across versions, as the iterated proposal's solver uses.
    return lx.linear_solve(lx.MatrixLinearOperator(a), b, solver=lx.QR(), throw=False).value[:k]


def test_programs_with_lapack_custom_calls_are_kept_too(toy_cache, monkeypatch):
    a = jnp.array([[3.0, 1.0], [1.0, 2.0], [0.5, 0.0]])
    b = jnp.array([1.0, 2.0, 0.5])
    expected = np.linalg.lstsq(np.asarray(a), np.asarray(b), rcond=None)[0]
    np.testing.assert_allclose(compile_program(_qr_solve, 2, a, b)(a, b), expected, rtol=1e-12)
    assert len(_entries(toy_cache)) == 1
    monkeypatch.setattr(_cache, "_COMPILED", {})
    monkeypatch.setattr(jax.export, "export", lambda *a, **k: pytest.fail("traced again"))
    np.testing.assert_allclose(compile_program(_qr_solve, 2, a, b)(a, b), expected, rtol=1e-12)


# --------------------------------------------------------------------------- compiled code in memory


@pytest.mark.slow
@pytest.mark.skipif(_cache.memory_maps() is None, reason="needs /proc/self/maps (Linux)")
def test_release_programs_unmaps_compiled_filter_programs(monkeypatch):
    """A compiled filter program holds hundreds of memory regions (counted in /proc/self/maps,
    the kernel's own account) until it is released; ``release_programs`` frees them only above
    its threshold, and a released program compiles again to the same outputs."""
    from nanoslam_jax.app.config import load_config
    from nanoslam_jax.app.experiment import load_log
    from nanoslam_jax.methods import run_filter
    from nanoslam_jax.app.filters import settings_from_config

    _cache.release_programs(0)
    before = _cache.memory_maps()[0]
    # the FastSLAM 1.0 run of tests/unit/app/test_method_registry.py (its program compiled once a session)
    cfg = load_config(None, ["sim.duration=20", "filter.n_particles=6", "filter.method=fastslam1"])
    log = load_log(cfg)
    static, params = settings_from_config(cfg, log.segments.k_max)
    pose = np.asarray(run_filter(static, params, log.segments, 0).outputs.best_pose)
    grown = _cache.memory_maps()[0] - before
    assert grown > 100, f"a filter program added only {grown} memory regions"

    assert not _cache.release_programs(1.0)  # below the limit: nothing released
    assert _cache.memory_maps()[0] - before >= grown - 10
    assert _cache.release_programs(0)
    assert _cache.memory_maps()[0] - before < 0.2 * grown, "the compiled program's regions were not released"

    np.testing.assert_array_equal(np.asarray(run_filter(static, params, log.segments, 0).outputs.best_pose), pose)

    # The threshold is a fraction of the kernel's limit.
    monkeypatch.setattr(_cache, "memory_maps", lambda: (499, 1000))
    assert not _cache.release_programs(0.5)
    monkeypatch.setattr(_cache, "memory_maps", lambda: (500, 1000))
    assert _cache.release_programs(0.5)


_TINY_PROGRAM = """
import json, sys, warnings
import jax, jax.numpy as jnp
from nanoslam_jax.lib._cache import compile_stats, enable_compile_cache
compile_stats()
enable_compile_cache(sys.argv[1])
jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)  # keep even this tiny program
x = jnp.ones(17)
with warnings.catch_warnings(record=True) as caught:
    warnings.simplefilter("always")
    jax.jit(lambda x: jnp.sin(x) * 2.0 + jnp.cos(x)).lower(x).compile()(x).block_until_ready()
s = compile_stats()
print(json.dumps({"hits": s.cache_hits, "misses": s.cache_misses,
                  "warnings": [str(w.message) for w in caught if "persistent compilation cache" in str(w.message)]}))
"""


@pytest.mark.slow
def test_a_damaged_cache_entry_is_replaced_and_the_next_run_loads(tmp_path):
    """A truncated entry of JAX's cache costs one recompile: that run writes the entry afresh and
    the run after it loads from the cache again, without a warning."""
    script, cache = tmp_path / "tiny.py", tmp_path / "cache"
    script.write_text(_TINY_PROGRAM)
    root = str(REPO_ROOT)
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([root, os.environ.get("PYTHONPATH", "")])}
    env.pop("JAX_COMPILATION_CACHE_DIR", None)

    def run() -> dict:
        res = subprocess.run(
            [sys.executable, str(script), str(cache)], capture_output=True, text=True, env=env, timeout=300
        )
        assert res.returncode == 0, res.stderr
        return json.loads(res.stdout.strip().splitlines()[-1])

    first = run()
    assert first["misses"] >= 1 and not first["warnings"]
    (entry,) = cache.glob("jit__lambda-*-cache")
    good = entry.read_bytes()
    assert run()["misses"] == 0  # loads
    entry.write_bytes(good[:100])  # damaged: truncated
    damaged = run()
    assert damaged["misses"] == 1 and len(damaged["warnings"]) == 1  # JAX's warning, one recompile
    assert entry.stat().st_size == len(good)  # written afresh
    healed = run()
    assert healed["misses"] == 0 and healed["hits"] == first["misses"] and not healed["warnings"]
