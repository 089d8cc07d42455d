"""``gns check``: validate recipes, reporting every problem of each with its location."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from ..config.recipe import load_recipe
from ..errors import RecipeError
from ..plugins import load_registry


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("recipes", nargs="+", type=Path, metavar="RECIPE", help="recipe files or folders (searched recursively)")


def run(args: argparse.Namespace) -> int:
    registry = load_registry()
    files: list[Path] = []
    for path in args.recipes:
        files += sorted(path.rglob("*.yaml")) + sorted(path.rglob("*.yml")) if path.is_dir() else [path]
    failed = 0
    for file in files:
        try:
            load_recipe(file, registry)
            print(f"{file}: ok")
        except RecipeError as exc:
            failed += 1
            print(exc, file=sys.stderr)
    return 1 if failed else 0
