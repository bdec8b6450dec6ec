"""The house in layers: the import graph of the package (grimp's, the graph import-linter checks)
has no cycle, and every import goes down the layers written in pyproject.toml
([tool.importlinter]); importing the package changes no JAX setting."""

import subprocess
import sys
import tomllib
from pathlib import Path

import grimp
import pytest
from tests.helpers.paths import REPO_ROOT

ROOT = REPO_ROOT


@pytest.fixture(scope="module")
def graph():
    return grimp.build_graph("nanoslam_jax", exclude_type_checking_imports=True)


def _layers() -> list[list[str]]:
    cfg = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["importlinter"]
    (contract,) = [c for c in cfg["contracts"] if c["type"] == "layers"]
    return [[f"nanoslam_jax.{p.strip()}" for p in layer.split("|")] for layer in contract["layers"]]


def _cycles(graph) -> list[list[str]]:
    """The strongly connected components of more than one module (Tarjan's algorithm)."""
    sys.setrecursionlimit(max(10_000, sys.getrecursionlimit()))
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set[str] = set()
    out: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in graph.find_modules_directly_imported_by(v):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    for m in sorted(graph.modules):
        if m not in index:
            visit(m)
    return out


def test_the_package_has_no_import_cycle(graph):
    assert _cycles(graph) == []


def test_a_cycle_is_found_where_there_is_one():
    g = grimp.ImportGraph()
    for m in ("p", "p.a", "p.b", "p.c"):
        g.add_module(m)
    g.add_import(importer="p.a", imported="p.b")
    g.add_import(importer="p.b", imported="p.c")
    assert _cycles(g) == []
    g.add_import(importer="p.c", imported="p.a")
    assert _cycles(g) == [["p.a", "p.b", "p.c"]]


def test_imports_go_down_the_layers(graph):
    layers = _layers()
    assert [p for layer in layers for p in layer][-1] == "nanoslam_jax.lib"
    rank = {p: i for i, layer in enumerate(layers) for p in layer}

    def layer_of(module: str):
        return next((p for p in rank if module == p or module.startswith(p + ".")), None)

    up = []
    for m in sorted(graph.modules):
        a = layer_of(m)
        for d in graph.find_modules_directly_imported_by(m):
            b = layer_of(d)
            if a is not None and b is not None and a != b and rank[b] <= rank[a]:
                up.append(f"{m} -> {d}")
    assert up == []


def test_every_package_declares_its_public_names():
    for init in sorted((ROOT / "nanoslam_jax").rglob("__init__.py")):
        assert "__all__" in init.read_text(), init


@pytest.mark.slow
def test_importing_the_package_changes_no_jax_setting():
    code = (
        "import jax; before = dict(jax.config.values); import nanoslam_jax, nanoslam_jax.app.cli; "
        "after = dict(jax.config.values); print(sorted(k for k in after if after[k] != before.get(k)))"
    )
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300, cwd=ROOT)
    assert res.returncode == 0, res.stderr[-2000:]
    assert res.stdout.strip() == "[]"


@pytest.mark.slow
def test_the_contract_holds_for_import_linter():
    exe = Path(sys.executable).with_name("lint-imports")
    res = subprocess.run([str(exe)], capture_output=True, text=True, timeout=300, cwd=ROOT)
    assert res.returncode == 0, res.stdout[-3000:]
    assert "1 kept, 0 broken" in res.stdout


def _diagram_layers(text: str) -> list[set[str]]:
    """The layers the Mermaid flowchart of docs/architecture.md draws, from the top: the chain of
    ``a --> b --> ...`` read as packages (a node that is a subgraph of packages stands for them)."""
    block = text.split("```mermaid", 1)[1].split("```", 1)[0]
    inner: dict[str, set[str]] = {}
    current = None
    chain: list[str] = []
    for line in (raw.strip() for raw in block.splitlines()):
        if line.startswith("subgraph "):
            current = line.split()[1].split("[")[0]
            inner[current] = set()
        elif line == "end":
            current = None
        elif "-->" in line:
            chain = [part.strip() for part in line.split("-->")]
        elif current is not None and line:
            inner[current].add(line.split("[")[0])
    packages = {p.name for p in (ROOT / "nanoslam_jax").iterdir() if (p / "__init__.py").is_file()}
    return [{node} if node in packages else inner[node] for node in chain]


def test_the_architecture_diagram_draws_the_contracts_layers():
    text = (ROOT / "docs" / "architecture.md").read_text()
    contract = [{p.removeprefix("nanoslam_jax.") for p in layer} for layer in _layers()]
    assert _diagram_layers(text) == contract
    for layer in contract:
        for package in layer:
            assert f"`nanoslam_jax.{package}`" in text, package  # a row of the layer table


def test_a_diagram_with_a_layer_out_of_order_is_caught():
    text = (ROOT / "docs" / "architecture.md").read_text()
    swapped = text.replace("methods --> data", "data --> methods")
    assert swapped != text
    contract = [{p.removeprefix("nanoslam_jax.") for p in layer} for layer in _layers()]
    assert _diagram_layers(swapped) != contract
