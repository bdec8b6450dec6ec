"""Shared test fixtures, the shape checks of the test session and the markers set by fixture.

Every function and pytree class of the modules in ``TYPECHECKED`` (the models and quadrature
rules of the public API) is imported through jaxtyping's import hook with beartype: a call whose
arguments or result do not match the jaxtyping annotations (dtype, shape, shape names shared
between arguments) fails the test with a ``jaxtyping.TypeCheckError``. ``NANOSLAM_TYPECHECK=0``
imports them unchecked.
"""

import os
from pathlib import Path

import pytest

TYPECHECKED = ("nanoslam_jax.models", "nanoslam_jax.quadrature")

if os.environ.get("NANOSLAM_TYPECHECK", "1") != "0":
    import warnings

    from beartype.roar import BeartypeDecorHintPep585DeprecationWarning
    from jaxtyping import install_import_hook

    # before any test module imports the package; ints pass for floats (PEP 484's numeric tower)
    install_import_hook(TYPECHECKED, "beartype.beartype(conf=beartype.BeartypeConf(is_pep484_tower=True))")
    warnings.filterwarnings("ignore", category=BeartypeDecorHintPep585DeprecationWarning)  # typing.Callable

DATA_FIXTURES = ("vp_dir", "mrclam_dir")


def pytest_collection_modifyitems(config, items):
    """A test that uses a real-dataset fixture is marked ``data``."""
    for item in items:
        if any(name in DATA_FIXTURES for name in getattr(item, "fixturenames", ())):
            item.add_marker(pytest.mark.data)


@pytest.fixture(scope="session", autouse=True)
def compile_cache_dir(tmp_path_factory) -> Path:
    """One compilation cache for the whole test session, never the user's cache directory.

    Many modules compile the same filter program (the embedded default, the small simulated logs
    the sweep and method tests share): with JAX's persistent cache enabled in every test process
    and shared by pytest-xdist's workers (the session's base directory), a program is compiled
    once per session and loaded afterwards. Commands run in fresh processes get it through
    ``NANOSLAM_CACHE_DIR`` (unless the caller set one). Tests of the cache itself use their own
    directories in fresh processes."""
    from nanoslam_jax._cache import enable_compile_cache

    base = tmp_path_factory.getbasetemp()
    session = base.parent if os.environ.get("PYTEST_XDIST_WORKER") else base  # xdist: .../pytest-N/popen-gwK
    path = Path(os.environ.setdefault("NANOSLAM_CACHE_DIR", str(session / "nanoslam_cache")))
    enable_compile_cache(path)
    return path


@pytest.fixture(scope="module", autouse=True)
def release_compiled_programs():
    """After each test module, drop the programs it compiled. XLA:CPU keeps about 1,200 memory
    regions per compiled filter program; the whole suite in one process compiles several hundred
    programs and, without this, reaches the kernel's limit (``vm.max_map_count``), where LLVM
    aborts the process (``nanoslam_jax._cache.release_programs``)."""
    yield
    from nanoslam_jax._cache import release_programs

    release_programs(0)


@pytest.fixture(scope="session")
def vp_dir() -> Path:
    """The real Victoria Park log at ../shared/data/victoria_park (skips the test when absent)."""
    path = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "victoria_park"
    if not (path / "measurements.dat").is_file():
        pytest.skip(f"Victoria Park log not found at {path}; see README.md to obtain it")
    return path
