"""The built-in plugins use the framework as any plugin would: through gns_framework.api and gns_framework.contracts."""

from __future__ import annotations

import ast
from pathlib import Path

import gns_framework.api as api

PLUGINS = Path(__file__).resolve().parents[2] / "plugins" / "gns_builtins"
ALLOWED = {"gns_framework.api", "gns_framework.contracts"}


def framework_imports(path: Path) -> list[tuple[int, str]]:
    found = []
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom) and node.module and node.module.split(".")[0] == "gns_framework":
            found.append((node.lineno, node.module))
        elif isinstance(node, ast.Import):
            found += [(node.lineno, a.name) for a in node.names if a.name.split(".")[0] == "gns_framework"]
    return found


def test_built_ins_import_the_framework_only_through_its_public_face():
    outside = {
        f"{path.relative_to(PLUGINS)}:{line}": module
        for path in sorted(PLUGINS.rglob("*.py"))
        for line, module in framework_imports(path)
        if module not in ALLOWED
    }
    assert not outside, f"import these from gns_framework.api (add them there if missing): {outside}"


def test_every_name_of_the_public_face_is_there():
    assert sorted(api.__all__) == sorted(set(api.__all__))
    missing = [name for name in api.__all__ if not hasattr(api, name)]
    assert not missing
