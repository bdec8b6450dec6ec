"""Paths the tests read: the repository's root, its configs and docs, and the shared datasets.

The shared datasets live next to the repository, in ``../shared/data`` (README.md); tests that
need one skip, saying so, when it is absent.
"""

from pathlib import Path

#: The repository's root (the folder holding pyproject.toml).
REPO_ROOT = Path(__file__).resolve().parents[2]
#: The shipped configuration files.
CONFIGS = REPO_ROOT / "configs"
#: The documentation's sources.
DOCS = REPO_ROOT / "docs"
#: The shared datasets: ``../shared/data`` relative to the repository's root.
SHARED_DATA = REPO_ROOT.parent / "shared" / "data"

assert (REPO_ROOT / "pyproject.toml").is_file(), REPO_ROOT

__all__ = ["CONFIGS", "DOCS", "REPO_ROOT", "SHARED_DATA"]
