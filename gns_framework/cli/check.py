"""``gns check``: validate recipes as training would, reporting every problem of each with its location.

For each recipe, all at once:

- the schema and the installed components (``gns_framework.config.recipe``);
- the optional modules each named component declares (``optional_modules`` on its
  class, e.g. ``radius_torch_cluster`` needs ``torch_cluster``): not installed, the
  component could not be built;
- the data, as the trainer opens it: the folder exists (``dataset.path``, relative to
  the recipe, see ``gns_framework.config.paths``), it has the layout's files (metadata
  and a train split that reads), its particle type ids all belong to materials
  (``model.materials`` when given, else installed materials), its property columns have
  names, and its trajectories are long enough for the model's history and push-forward;
- the model the trainer would build from recipe and data (sizes, periodic dimensions
  the graph builder must connect).

Nothing is trained and nothing is written.
"""

from __future__ import annotations

import argparse
import importlib
import sys
from pathlib import Path

from ..assembly.learned import size_problems, training_problems
from ..config.recipe import COMPONENT_SECTIONS, Recipe, load_recipe
from ..errors import GnsError, RecipeError
from ..plugins import Registry, load_registry


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "recipes", nargs="+", type=Path, metavar="RECIPE", help="recipe files or folders (searched recursively)"
    )
    parser.add_argument(
        "--no-data",
        action="store_true",
        help="check only the recipe and the installed components, not its dataset (data not made yet)",
    )


def missing_module(name: str) -> str | None:
    """Why module ``name`` cannot be imported; None when it can."""
    try:
        importlib.import_module(name)
    except ImportError as exc:
        return str(exc) or f"No module named {name!r}"
    except Exception as exc:  # a module that fails to import is as unusable as a missing one
        return f"{type(exc).__name__}: {exc}"
    return None


def component_problems(recipe: Recipe, registry: Registry) -> list[tuple[str, str]]:
    """Optional modules of the recipe's components (and dataset layout) that are not importable."""
    problems = []
    named = [(f"model.{kind}", kind, getattr(recipe.model, kind)) for kind in COMPONENT_SECTIONS]
    named.append(("dataset", "dataset", recipe.dataset))
    for location, kind, spec in named:
        try:
            cls = registry.get(kind, spec.name)
        except GnsError:
            continue  # reported by the schema pass
        for module in getattr(cls, "optional_modules", ()):
            why = missing_module(module)
            if why is not None:
                problems.append(
                    (
                        f"{location}.name",
                        f"{kind} {spec.name!r} needs the optional module {module!r}, "
                        f"which is not importable ({why}); install it or choose another {kind}",
                    )
                )
    return problems


def _data_location(message: str) -> str:
    if "model.materials" in message:
        return "model.materials"
    if "material_property" in message:
        return "model.material_properties"
    return "dataset.path"


def data_problems(recipe: Recipe, registry: Registry) -> list[tuple[str, str]]:
    """What the trainer would refuse in the data and the model built from it, before its first step."""
    from ..assembly.data import prepare_data
    from ..assembly.learned import build_learned_simulator
    from ..data.windows import WindowIndex
    from ..training.parts import rolled_window_problems

    try:
        data = prepare_data(recipe, registry)
    except RecipeError as exc:
        return [(loc or "dataset.path", message) for loc, message in exc.problems]
    except (GnsError, OSError, ValueError) as exc:
        return [(_data_location(str(exc)), str(exc))]
    spec = recipe.training
    problems = rolled_window_problems(spec.pushforward_steps, spec.unrolled_loss_steps, data.setup.context_size)
    try:
        WindowIndex(data.train, recipe.model.history, spec.pushforward_steps + spec.unrolled_loss_steps)
    except ValueError as exc:
        problems.append(("model.history", f"{recipe.dataset.path}: train split: {exc}"))
    try:
        build_learned_simulator(data.setup, data.metadata, recipe.model, registry)
    except RecipeError as exc:
        problems += [(loc or "model", message) for loc, message in exc.problems]
    except (GnsError, ValueError, RuntimeError) as exc:
        problems.append(("model", str(exc)))
    return problems


def check_recipe(file: Path, registry: Registry, with_data: bool = True) -> None:
    """RecipeError listing every problem of ``file`` that stops training; returns when there is none."""
    recipe = load_recipe(file, registry)  # schema problems first: nothing else can be read without a valid recipe
    problems = component_problems(recipe, registry) + training_problems(recipe, registry)
    # The data checks build the model: never one too large to build.
    if with_data and not size_problems(recipe, registry):
        problems += data_problems(recipe, registry)
    if problems:
        raise RecipeError(file, problems)


def run(args: argparse.Namespace) -> int:
    registry = load_registry()
    files: list[Path] = []
    for path in args.recipes:
        files += sorted(path.rglob("*.yaml")) + sorted(path.rglob("*.yml")) if path.is_dir() else [path]
    failed = 0
    for file in files:
        try:
            check_recipe(file, registry, with_data=not args.no_data)
            print(f"{file}: ok")
        except RecipeError as exc:
            failed += 1
            print(exc, file=sys.stderr)
    return 1 if failed else 0
