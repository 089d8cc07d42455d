"""Importing the package or asking ``gns --help`` loads no heavy optional package; importing a test
module changes no process-wide setting."""

from __future__ import annotations

import ast
import json
import subprocess
import sys
from pathlib import Path

import pytest

HEAVY = ("mlflow", "meshio", "vtk", "warp", "matplotlib", "torch_geometric", "torch_cluster")

PROBE = """
import json, sys
{body}
print(json.dumps(sorted(m.split('.')[0] for m in sys.modules)))
"""

CASES = {
    "import gns_framework": "import gns_framework",
    "gns --help": ("from gns_framework.cli import main\ntry:\n    main(['--help'])\nexcept SystemExit:\n    pass"),
    "gns plugins": "from gns_framework.cli import main\nmain(['plugins'])",
}


@pytest.mark.parametrize("case", CASES)
def test_no_heavy_package_is_imported(case):
    out = subprocess.run(
        [sys.executable, "-c", PROBE.format(body=CASES[case])], capture_output=True, text=True, check=True, timeout=120
    ).stdout
    loaded = set(json.loads(out.strip().splitlines()[-1]))
    assert not loaded & set(HEAVY), f"{case} imported {sorted(loaded & set(HEAVY))}"


def test_gns_help_does_not_import_torch():
    out = subprocess.run(
        [sys.executable, "-c", PROBE.format(body=CASES["gns --help"])],
        capture_output=True,
        text=True,
        check=True,
        timeout=120,
    ).stdout
    assert "torch" not in json.loads(out.strip().splitlines()[-1])


REPO = Path(__file__).resolve().parents[1]
PROCESS_WIDE = {"set_num_threads", "set_num_interop_threads", "set_default_dtype", "manual_seed"}
"""torch settings that hold for the whole test session once made."""


class ImportTimeCalls(ast.NodeVisitor):
    """Names of the calls a module makes when imported (function bodies are not run then)."""

    def __init__(self):
        self.names: list[tuple[int, str]] = []

    def visit_Call(self, node: ast.Call) -> None:
        func = node.func
        name = func.attr if isinstance(func, ast.Attribute) else getattr(func, "id", "")
        self.names.append((node.lineno, name))
        self.generic_visit(node)

    def visit_FunctionDef(self, node) -> None:
        for decorator in node.decorator_list:  # decorators do run at import
            self.visit(decorator)

    visit_AsyncFunctionDef = visit_FunctionDef

    def visit_Lambda(self, node) -> None:
        pass


def test_no_test_module_changes_torch_settings_when_imported():
    """Set in a fixture that restores them, not at import: an import changes them for every later test."""
    found = []
    for folder in ("tests", "parity", "plugins/examples/gns-clay/tests", "plugins/examples/gns-processor/tests"):
        for path in sorted((REPO / folder).rglob("*.py")):
            visitor = ImportTimeCalls()
            visitor.visit(ast.parse(path.read_text(), str(path)))
            found += [f"{path.relative_to(REPO)}:{line} {name}" for line, name in visitor.names if name in PROCESS_WIDE]
    assert found == []
