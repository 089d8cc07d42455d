"""YAML reading for recipes and scene specs: duplicate keys are errors, and errors carry line numbers.

Numbers are read as a user writes them: PyYAML follows YAML 1.1, where
``3.537e5`` and ``1e-3`` (no sign or no dot in the exponent form) are strings;
here every YAML 1.2 float is a float. A float keeps the text it was written
as, so a field that expects a string (a name, a path) gets ``1e5`` back, not
``100000.0`` (the schemas set ``coerce_numbers_to_str``).
"""

from __future__ import annotations

import re
from pathlib import Path

import yaml

from ..errors import RecipeError


class YamlFloat(float):
    """A float read from YAML that remembers its text; ``str()`` gives the text back."""

    text: str

    def __new__(cls, value: float, text: str) -> YamlFloat:
        number = super().__new__(cls, value)
        number.text = text
        return number

    def __str__(self) -> str:
        return self.text


class _StrictLoader(yaml.SafeLoader):
    pass


# YAML 1.2 core-schema floats with an exponent (1e5, 3.537e5, .5E-3, 2.E+4); dotted
# numbers without one are floats in YAML 1.1 already.
_EXPONENT_FLOAT = re.compile(r"^[-+]?(?:[0-9][0-9_]*(?:\.[0-9_]*)?|\.[0-9_]+)[eE][-+]?[0-9]+$")
_StrictLoader.add_implicit_resolver("tag:yaml.org,2002:float", _EXPONENT_FLOAT, list("-+0123456789."))


def _float_with_text(loader: _StrictLoader, node: yaml.ScalarNode) -> float:
    value = loader.construct_yaml_float(node)
    return YamlFloat(value, node.value) if node.style is None else value


_StrictLoader.add_constructor("tag:yaml.org,2002:float", _float_with_text)


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


MAX_YAML_BYTES = 16 * 2**20
"""Largest recipe or scene file read."""
MAX_YAML_DEPTH = 64
"""Deepest nesting of mappings and lists read (recipes and scenes nest 4-6 deep): the YAML loader builds nested
values recursively, and 100,000 brackets would end it in a RecursionError."""


def _nesting_problem(text: str) -> tuple[str, str] | None:
    """(where, why) when ``text`` nests deeper than MAX_YAML_DEPTH; read from the parser's events, without recursion."""
    depth = 0
    for event in yaml.parse(text, Loader=_StrictLoader):
        if isinstance(event, (yaml.MappingStartEvent, yaml.SequenceStartEvent)):
            depth += 1
            if depth > MAX_YAML_DEPTH:
                mark = event.start_mark
                return (
                    f"line {mark.line + 1}, column {mark.column + 1}",
                    f"nested more than {MAX_YAML_DEPTH} levels deep; recipes and scenes nest a few levels",
                )
        elif isinstance(event, (yaml.MappingEndEvent, yaml.SequenceEndEvent)):
            depth -= 1
    return None


def _one_line(path: Path, where: str, message: str) -> RecipeError:
    """A RecipeError of one problem whose message is one line (``problems`` still lists it for gns check)."""
    error = RecipeError(path, [(where, message)])
    error.args = (f"{path}: {where}: {message}" if where else f"{path}: {message}",)
    return error


def load_yaml_mapping(path: str | Path) -> dict:
    """Read a YAML file that must hold a mapping; raise RecipeError naming the file and line."""
    path = Path(path)
    try:
        with open(path, "rb") as handle:
            data = handle.read(MAX_YAML_BYTES + 1)
    except FileNotFoundError:
        raise RecipeError(path, [("", "file not found")]) from None
    except OSError as exc:
        raise RecipeError(path, [("", f"cannot read: {exc}")]) from None
    if len(data) > MAX_YAML_BYTES:
        raise _one_line(path, "", f"more than {MAX_YAML_BYTES // 2**20} MiB, too large for a recipe or scene")
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise _one_line(
            path, f"byte {exc.start}", f"not UTF-8 text (0x{data[exc.start]:02x}); save the file as UTF-8"
        ) from None
    try:
        nested = _nesting_problem(text)
        if nested is not None:
            raise _one_line(path, *nested)
        raw = yaml.load(text, Loader=_StrictLoader)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f"line {mark.line + 1}, column {mark.column + 1}" if mark else ""
        problem = getattr(exc, "problem", None) or str(exc)
        raise RecipeError(path, [(where, f"invalid YAML: {problem}")]) from None
    if not isinstance(raw, dict):
        raise RecipeError(path, [("", f"expected a mapping at the top level, got {type(raw).__name__}")])
    return raw
