"""Shared test fixtures, the shape checks of the test session and the markers set by fixture.

Every function and pytree class of the modules in ``TYPECHECKED`` (the models and quadrature
rules of the public API) is imported through jaxtyping's import hook with beartype: a call whose
arguments or result do not match the jaxtyping annotations (dtype, shape, shape names shared
between arguments) fails the test with a ``jaxtyping.TypeCheckError``. ``NANOSLAM_TYPECHECK=0``
imports them unchecked.
"""

import os
from pathlib import Path

import jax
import pytest
from tests.helpers.paths import SHARED_DATA

# The library is tested in float64, the precision its entry points compute in (importing the
# package changes no JAX setting: nanoslam_jax.float64).
jax.config.update("jax_enable_x64", True)

TYPECHECKED = ("nanoslam_jax.models", "nanoslam_jax.lib.quadrature")

if os.environ.get("NANOSLAM_TYPECHECK", "1") != "0":
    import warnings

    from beartype.roar import BeartypeDecorHintPep585DeprecationWarning
    from jaxtyping import install_import_hook

    # before any test module imports the package; ints pass for floats (PEP 484's numeric tower)
    install_import_hook(TYPECHECKED, "beartype.beartype(conf=beartype.BeartypeConf(is_pep484_tower=True))")
    warnings.filterwarnings("ignore", category=BeartypeDecorHintPep585DeprecationWarning)  # typing.Callable

DATA_FIXTURES = ("vp_dir", "mrclam_dir")


#: Modules that compile the most filter programs, in the order pytest-xdist hands them out first
#: (it gives whole modules to its workers, in collection order: ``--dist loadfile
#: --no-loadscope-reorder`` in pyproject.toml). A long module started last would run alone while
#: the other worker idles; started first, the many short modules fill in behind it. The others
#: keep pytest's order. A module missing from this list only costs balance, never a test. The
#: paths are relative to this folder.
LONG_MODULES = (
    "unit/methods/test_methods.py",
    "unit/lib/test_cache.py",
    "unit/methods/test_filter.py",
    "e2e/test_cli.py",
    "unit/models/test_motion_models.py",
    "unit/app/test_study.py",
    "unit/data/test_mrclam.py",
    "unit/app/test_sweep.py",
    "unit/methods/test_nasrukf.py",
    "unit/methods/test_landmarks.py",
    "unit/methods/test_ufastslam.py",
    "unit/methods/test_adaptive_process.py",
    "unit/smoother/test_smoother.py",
    "unit/frontend/test_frontend.py",
    "e2e/test_best_config.py",
    "unit/models/test_measurement_models.py",
    "unit/methods/test_path.py",
    "unit/methods/test_known_association.py",
    "unit/methods/test_ekf_slam.py",
    "unit/methods/test_management.py",
)


def pytest_collection_modifyitems(config, items):
    """A test that uses a real-dataset fixture is marked ``data``; the long modules go first."""
    for item in items:
        if any(name in DATA_FIXTURES for name in getattr(item, "fixturenames", ())):
            item.add_marker(pytest.mark.data)
    rank = {name: i for i, name in enumerate(LONG_MODULES)}
    here = Path(__file__).resolve().parent

    def module(item) -> str:
        path = Path(item.path).resolve()
        return path.relative_to(here).as_posix() if path.is_relative_to(here) else path.name

    items.sort(key=lambda item: rank.get(module(item), len(LONG_MODULES)))  # stable: order within kept


@pytest.fixture(scope="session", autouse=True)
def compile_cache_dir(tmp_path_factory) -> Path:
    """One compilation cache for the whole test session, never the user's cache directory.

    Many modules compile the same filter program (the embedded default, the small simulated logs
    the sweep and method tests share): with JAX's persistent cache enabled in every test process
    and shared by pytest-xdist's workers (the session's base directory), a program is compiled
    once per session and loaded afterwards. Commands run in fresh processes get it through
    ``NANOSLAM_CACHE_DIR`` (unless the caller set one). Tests of the cache itself use their own
    directories in fresh processes."""
    from nanoslam_jax.lib._cache import enable_compile_cache

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
    aborts the process (``nanoslam_jax.lib._cache.release_programs``)."""
    yield
    from nanoslam_jax.lib._cache import release_programs

    release_programs(0)


@pytest.fixture(scope="session")
def vp_dir() -> Path:
    """The real Victoria Park log at ../shared/data/victoria_park (skips the test when absent)."""
    path = SHARED_DATA / "victoria_park"
    if not (path / "measurements.dat").is_file():
        pytest.skip(f"Victoria Park log not found at {path}; see README.md to obtain it")
    return path
