"""Run the mirror tests of changed modules, or list the modules that have none.

``tests/`` mirrors the package tree down to the file: ``gns_framework/training/step.py``
is tested in ``tests/training/test_step.py``, ``plugins/gns_builtins/processors/grid_cnn.py``
in ``tests/builtins/processors/test_grid_cnn.py``. A mirror may also be split by topic
(``test_step_<topic>.py``), and a module with a common name mirrors with its folder's
(``simulators/_mpm/solver.py``: ``test_mpm_solver.py``), since test module names are unique.

Usage::

    python scripts/mirror_tests.py                 # the mirrors of the modules changed since HEAD
    python scripts/mirror_tests.py FILE...         # the mirrors of these modules
    python scripts/mirror_tests.py --missing       # modules with logic and no mirror test
"""

from __future__ import annotations

import argparse
import ast
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = {Path("gns_framework"): Path("tests"), Path("plugins/gns_builtins"): Path("tests/builtins")}


def mirrors(module: Path) -> list[Path]:
    """The test files mirroring ``module`` (relative to the project root) that exist."""
    for package, tests in PACKAGES.items():
        if module.is_relative_to(package):
            relative = module.relative_to(package)
            folder = ROOT / tests / relative.parent
            # Underscore packages (helpers, e.g. _kernels/) mirror without the underscore too.
            folders = {folder, ROOT / tests / Path(*[part.lstrip("_") for part in relative.parent.parts])}
            # Test module names are unique across tests/ (no __init__.py), so a module whose name is
            # common (_mpm/solver.py) mirrors as test_<folder>_<name>.py (test_mpm_solver.py).
            stems = {relative.stem}
            if relative.parent.parts:
                stems.add(f"{relative.parent.parts[-1].lstrip('_')}_{relative.stem}")
            found = []
            for candidate in sorted(folders):
                for stem in sorted(stems):
                    found += sorted(candidate.glob(f"test_{stem}.py")) + sorted(candidate.glob(f"test_{stem}_*.py"))
            return found
    return []


def has_logic(path: Path) -> bool:
    """Whether a module defines a function or a method (constants, re-exports and hook lists do not count)."""
    tree = ast.parse(path.read_text())
    for node in ast.walk(tree):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            if node.name == "__init__" and len(node.body) == 1:
                continue
            decorators = {getattr(d, "id", getattr(d, "attr", "")) for d in node.decorator_list}
            if "hookimpl" in decorators or "hookspec" in decorators:
                continue
            return True
    return False


def modules() -> list[Path]:
    found = []
    for package in PACKAGES:
        for path in sorted((ROOT / package).rglob("*.py")):
            if path.name != "__init__.py" and "__pycache__" not in path.parts:
                found.append(path.relative_to(ROOT))
    return found


def changed() -> list[Path]:
    out = subprocess.run(["git", "diff", "--name-only", "HEAD"], cwd=ROOT, capture_output=True, text=True, check=True)
    return [Path(line) for line in out.stdout.split() if line.endswith(".py")]


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("files", nargs="*", type=Path, help="modules (default: those changed since HEAD)")
    parser.add_argument("--missing", action="store_true", help="list the modules with logic and no mirror test")
    args = parser.parse_args()
    if args.missing:
        missing = [m for m in modules() if has_logic(ROOT / m) and not mirrors(m)]
        for module in missing:
            print(module)
        print(f"{len(missing)} of {len(modules())} modules have logic and no mirror test", file=sys.stderr)
        return 0
    files = [f.resolve().relative_to(ROOT) if f.is_absolute() else f for f in args.files] or changed()
    tests = sorted({t for f in files for t in mirrors(f)} | {ROOT / f for f in files if f.name.startswith("test_")})
    if not tests:
        print("no mirror tests for the changed modules")
        return 0
    return subprocess.call([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", *map(str, tests)], cwd=ROOT)


if __name__ == "__main__":
    sys.exit(main())
