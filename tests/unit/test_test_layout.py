"""The layout of the tests: they mirror the packages, and reach private modules only where they may.

``tests/unit/<package>`` holds the unit tests of ``nanoslam_jax.<package>`` (the fast tier is
``pytest tests/unit -m "not slow"``), ``tests/unit`` itself the tests of the package as a whole,
``tests/e2e`` the end-to-end runs of the commands and shipped files, and ``tests/helpers`` the
documented testing helpers. A unit test of ``<package>`` may import that package's private
modules (``nanoslam_jax.<package>._name`` and those of its subpackages) but no other package's;
the package-wide and end-to-end tests import none. A helper that reaches a private module names it
in its docstring, saying why (``tests/helpers/internals.py``).
"""

import ast
from pathlib import Path

import pytest

from tests.helpers.paths import REPO_ROOT

TESTS = REPO_ROOT / "tests"
PACKAGE = REPO_ROOT / "nanoslam_jax"


def _is_module(name: str) -> bool:
    """Whether the dotted name is a module or package of the source tree (not a name in one)."""
    path = REPO_ROOT.joinpath(*name.split("."))
    return path.with_suffix(".py").is_file() or (path / "__init__.py").is_file()


def imported_modules(path: Path) -> set[str]:
    """The modules of nanoslam_jax a file imports, anywhere in it: ``import a.b``, ``from a.b import
    c`` (``a.b``, and ``a.b.c`` where that is a module)."""
    found: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
        if isinstance(node, ast.Import):
            names = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names = [node.module] + [
                f"{node.module}.{a.name}" for a in node.names if _is_module(f"{node.module}.{a.name}")
            ]
        else:
            continue
        found.update(n for n in names if n == "nanoslam_jax" or n.startswith("nanoslam_jax."))
    return found


def private_part(module: str) -> str | None:
    """The package a private module belongs to (``nanoslam_jax.<package>``, or ``nanoslam_jax``
    for a private module of the root), or None for a public module."""
    parts = module.split(".")
    if not any(p.startswith("_") for p in parts[1:]):
        return None
    return ".".join(parts[:2]) if len(parts) > 2 and not parts[1].startswith("_") else "nanoslam_jax"


def violations(path: Path, tests: Path = TESTS) -> list[str]:
    """The private imports a test module under ``tests`` may not make, given where it lies."""
    rel = path.relative_to(tests).parts
    if rel[0] == "unit" and len(rel) > 2:
        allowed = f"nanoslam_jax.{rel[1]}"
    elif rel[0] in ("unit", "e2e"):
        allowed = None  # the package as a whole, end to end: no private module at all
    else:
        return []
    bad = []
    for module in sorted(imported_modules(path)):
        owner = private_part(module)
        if owner is not None and owner != allowed:
            bad.append(f"{path.relative_to(tests.parent)} imports {module}")
    return bad


def _test_files() -> list[Path]:
    return sorted(p for p in TESTS.rglob("*.py") if p.relative_to(TESTS).parts[0] in ("unit", "e2e"))


def test_no_test_imports_a_private_module_of_another_package():
    bad = [v for path in _test_files() for v in violations(path)]
    assert not bad, "import the public name (the package's __all__) or go through tests/helpers:\n" + "\n".join(bad)


def test_helpers_say_which_private_modules_they_use():
    """A helper names every private module it imports in its docstring (where it says why)."""
    undocumented = []
    for path in sorted((TESTS / "helpers").glob("*.py")):
        documented = ast.get_docstring(ast.parse(path.read_text())) or ""
        undocumented += [
            f"{path.name}: {m}" for m in sorted(imported_modules(path)) if private_part(m) and m not in documented
        ]
    assert not undocumented, undocumented


def test_unit_folders_mirror_the_packages():
    folders = sorted(p for p in (TESTS / "unit").rglob("*") if p.is_dir() and p.name != "__pycache__")
    assert folders, "no tests/unit/<package> folder"
    for folder in folders:
        package = PACKAGE.joinpath(*folder.relative_to(TESTS / "unit").parts)
        assert (package / "__init__.py").is_file(), f"{folder} names no subpackage of nanoslam_jax"


def test_every_test_module_is_in_a_tier_and_every_folder_a_package():
    """Test modules live under tests/unit or tests/e2e; every folder is a package, so that modules
    of the same name in different folders (tests/unit/app/test_cli.py, tests/e2e/test_cli.py) do
    not clash."""
    stray = [p for p in TESTS.rglob("test_*.py") if p.relative_to(TESTS).parts[0] not in ("unit", "e2e")]
    assert not stray, stray
    for folder in [TESTS, *(p for p in TESTS.rglob("*") if p.is_dir() and p.name != "__pycache__")]:
        assert (folder / "__init__.py").is_file(), folder


@pytest.mark.parametrize(
    "where, source, bad",
    [
        ("unit/methods/test_x.py", "from nanoslam_jax.methods.maps._landmarks import init_landmark", False),
        ("unit/methods/test_x.py", "from nanoslam_jax.methods import _scan", False),
        ("unit/methods/test_x.py", "from nanoslam_jax.lib._cache import release_programs", True),
        ("unit/methods/test_x.py", "from nanoslam_jax.lib import _trig", True),
        ("unit/methods/test_x.py", "import nanoslam_jax.data._carmen", True),
        ("unit/methods/test_x.py", "def f():\n    from nanoslam_jax.app.sweep import _batch", True),
        ("unit/methods/test_x.py", "from nanoslam_jax.app.cli import _parser", False),  # a private name, not a module
        ("unit/app/test_x.py", "from nanoslam_jax.app.sweep._batch import log_key", False),
        ("unit/test_x.py", "from nanoslam_jax.lib._precision import in_float64", True),
        ("e2e/test_x.py", "from nanoslam_jax.app import _devices", True),
        ("e2e/test_x.py", "from nanoslam_jax.app.cli import main", False),
        ("helpers/x.py", "from nanoslam_jax.methods import _scan", False),
    ],
)
def test_the_rule_on_imports_written_here(tmp_path, where, source, bad):
    path = tmp_path / "tests" / where
    path.parent.mkdir(parents=True)
    path.write_text(source + "\n")
    assert bool(violations(path, tests=tmp_path / "tests")) == bad
