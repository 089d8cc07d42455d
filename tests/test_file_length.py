"""No module of the package or the built-in plugins is longer than 610 lines (issue 49): past that, a file
holds more than one job (LagrangeBench's largest file is 610 lines)."""

from __future__ import annotations

from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
LIMIT = 610


def test_no_module_is_over_the_limit():
    too_long = {
        str(path.relative_to(ROOT)): n
        for folder in ("gns_framework", "plugins")
        for path in sorted((ROOT / folder).rglob("*.py"))
        if (n := len(path.read_text().splitlines())) > LIMIT
    }
    assert not too_long, f"modules over {LIMIT} lines (split them by concern): {too_long}"
