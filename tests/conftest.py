"""Shared test fixtures."""

from pathlib import Path

import pytest


@pytest.fixture(scope="session")
def vp_dir() -> Path:
    """The real Victoria Park log at ../shared/data/victoria_park (skips the test when absent)."""
    path = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "victoria_park"
    if not (path / "measurements.dat").is_file():
        pytest.skip(f"Victoria Park log not found at {path}; see README.md to obtain it")
    return path
