"""README's layout table names every package and root module of gns_framework, so a newcomer finds each there."""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
PACKAGE = ROOT / "gns_framework"


def first_cells(readme: str) -> str:
    """The first cell of every row of the README's tables whose first cell names a path."""
    return "\n".join(line.split(" | ")[0] for line in readme.splitlines() if line.startswith("| `"))


def unnamed(table: str) -> list[str]:
    """The packages and root modules of gns_framework that ``table`` does not name."""
    named = set(re.findall(r"`(?:gns_framework/)?([a-z_]+)(?:/|\.py)`", table))
    parts = {p.name for p in PACKAGE.iterdir() if p.is_dir() and (p / "__init__.py").exists()}
    parts |= {p.stem for p in PACKAGE.glob("*.py") if p.stem != "__init__"}
    return sorted(parts - named)


def test_every_package_and_root_module_has_a_row():
    assert unnamed(first_cells((ROOT / "README.md").read_text())) == []


def test_a_package_without_a_row_is_found():
    readme = (ROOT / "README.md").read_text()
    without = "\n".join(line for line in readme.splitlines() if not line.startswith("| `gns_framework/decomposition/`"))
    assert unnamed(first_cells(without)) == ["decomposition"]
