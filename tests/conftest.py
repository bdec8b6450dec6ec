"""Shared test fixtures."""

import os
from pathlib import Path

import pytest


@pytest.fixture(scope="session", autouse=True)
def compile_cache_dir(tmp_path_factory) -> Path:
    """Commands run in-process keep their compiled programs in a test directory, never in the
    user's cache directory (``NANOSLAM_CACHE_DIR`` unless the caller set it)."""
    path = Path(os.environ.setdefault("NANOSLAM_CACHE_DIR", str(tmp_path_factory.mktemp("nanoslam_cache"))))
    return path


@pytest.fixture(scope="session")
def vp_dir() -> Path:
    """The real Victoria Park log at ../shared/data/victoria_park (skips the test when absent)."""
    path = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "victoria_park"
    if not (path / "measurements.dat").is_file():
        pytest.skip(f"Victoria Park log not found at {path}; see README.md to obtain it")
    return path
