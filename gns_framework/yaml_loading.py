"""YAML reading for recipes and scene specs: duplicate keys are errors, and errors carry line numbers."""

from __future__ import annotations

from pathlib import Path

import yaml

from .errors import RecipeError


class _StrictLoader(yaml.SafeLoader):
    pass


def _mapping_without_duplicates(loader: _StrictLoader, node: yaml.MappingNode, deep: bool = False) -> dict:
    seen: dict = {}
    for key_node, _ in node.value:
        key = loader.construct_object(key_node, deep=deep)
        if key in seen:
            raise yaml.constructor.ConstructorError(
                None, None, f"duplicate key {key!r} (first at line {seen[key] + 1})", key_node.start_mark
            )
        seen[key] = key_node.start_mark.line
    return loader.construct_mapping(node, deep=deep)


_StrictLoader.add_constructor(yaml.resolver.BaseResolver.DEFAULT_MAPPING_TAG, _mapping_without_duplicates)


def load_yaml_mapping(path: str | Path) -> dict:
    """Read a YAML file that must hold a mapping; raise RecipeError naming the file and line."""
    path = Path(path)
    try:
        text = path.read_text()
    except FileNotFoundError:
        raise RecipeError(path, [("", "file not found")]) from None
    except OSError as exc:
        raise RecipeError(path, [("", f"cannot read: {exc}")]) from None
    try:
        raw = yaml.load(text, Loader=_StrictLoader)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f"line {mark.line + 1}, column {mark.column + 1}" if mark else ""
        problem = getattr(exc, "problem", None) or str(exc)
        raise RecipeError(path, [(where, f"invalid YAML: {problem}")]) from None
    if not isinstance(raw, dict):
        raise RecipeError(path, [("", f"expected a mapping at the top level, got {type(raw).__name__}")])
    return raw
