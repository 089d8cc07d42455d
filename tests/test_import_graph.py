"""No import circles inside gns_framework, between modules or between its packages.

Every ``import`` of a module under ``gns_framework/`` counts, also those inside
functions (an import deferred into a function is still a dependency, only a hidden
one). Between modules, those under ``if TYPE_CHECKING:`` count too: a circle of
type names is still a circle a reader has to untangle. Between packages (each
subpackage, and each module at the package root, is one unit), only the imports
that run count.
"""

from __future__ import annotations

import ast
from pathlib import Path

import networkx as nx
import pytest

PACKAGE = Path(__file__).resolve().parents[1] / "gns_framework"


def module_name(path: Path, root: Path) -> str:
    parts = list(path.relative_to(root.parent).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def is_type_checking(test: ast.expr) -> bool:
    return (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING") or (
        isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING"
    )


def imports_of(path: Path, name: str, modules: set[str]) -> list[tuple[str, bool]]:
    """``(imported module, only under TYPE_CHECKING)`` for every project import of the file."""
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    found: list[tuple[str, bool]] = []

    def visit(node: ast.AST, typing_only: bool) -> None:
        if isinstance(node, ast.If) and is_type_checking(node.test):
            for child in node.body:
                visit(child, True)
            for child in node.orelse:
                visit(child, typing_only)
            return
        if isinstance(node, ast.Import):
            found.extend((alias.name, typing_only) for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")[: len(package.split(".")) - node.level + 1]
                target = ".".join(base + ([node.module] if node.module else []))
            else:
                target = node.module or ""
            for alias in node.names:  # ``from . import x`` imports the module x
                submodule = f"{target}.{alias.name}"
                found.append((submodule if submodule in modules else target, typing_only))
        for child in ast.iter_child_nodes(node):
            visit(child, typing_only)

    visit(ast.parse(path.read_text(), str(path)), False)
    return [(target, typing_only) for target, typing_only in found if target in modules and target != name]


def import_graphs(root: Path) -> tuple[nx.DiGraph, nx.DiGraph]:
    """The graph between modules (every import) and between packages (imports that run)."""
    files = {module_name(path, root): path for path in sorted(root.rglob("*.py"))}
    modules, packages = nx.DiGraph(), nx.DiGraph()
    top = root.name

    def unit(module: str) -> str:
        return ".".join(module.split(".")[:2]) if module != top else top

    for name, path in files.items():
        modules.add_node(name)
        packages.add_node(unit(name))
        for target, typing_only in imports_of(path, name, set(files)):
            modules.add_edge(name, target)
            if not typing_only and unit(target) != unit(name):
                packages.add_edge(unit(name), unit(target))
    return modules, packages


def circles(graph: nx.DiGraph) -> list[list[str]]:
    return [sorted(component) for component in nx.strongly_connected_components(graph) if len(component) > 1]


@pytest.fixture(scope="module")
def graphs():
    return import_graphs(PACKAGE)


def test_no_import_circle_between_modules(graphs):
    modules, _ = graphs
    assert modules.number_of_edges() > 100, "the graph was not built"
    assert circles(modules) == []


def test_no_import_circle_between_packages(graphs):
    _, packages = graphs
    assert circles(packages) == []


def test_a_circle_through_a_function_level_import_is_found(tmp_path):
    """The graph sees an import made inside a function, the kind that hid a circle before."""
    root = tmp_path / "pkg"
    (root / "sub").mkdir(parents=True)
    (root / "__init__.py").write_text("")
    (root / "sub" / "__init__.py").write_text("")
    (root / "core.py").write_text("def save():\n    from .sub.files import write\n")
    (root / "sub" / "files.py").write_text("def write():\n    pass\n")
    (root / "sub" / "use.py").write_text("from ..core import save\n")
    modules, packages = import_graphs(root)
    assert circles(modules) == []
    assert circles(packages) == [["pkg.core", "pkg.sub"]]


def test_a_circle_of_type_names_is_found_between_modules_only(tmp_path):
    root = tmp_path / "pkg"
    root.mkdir()
    (root / "__init__.py").write_text("")
    (root / "a.py").write_text("from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from .b import B\n")
    (root / "b.py").write_text("from .a import A\n")
    modules, packages = import_graphs(root)
    assert circles(modules) == [["pkg.a", "pkg.b"]]
    assert circles(packages) == []
