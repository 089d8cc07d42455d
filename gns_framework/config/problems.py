"""Turning pydantic errors into ``(location, message)`` problems with did-you-mean hints."""

from __future__ import annotations

import typing

from pydantic import BaseModel, ValidationError

from ..errors import did_you_mean


def format_location(loc: tuple) -> str:
    """``blocks[0].size[1]`` from pydantic's location; tags of discriminated unions (``@...``) are left out."""
    out = ""
    for part in loc:
        if isinstance(part, str) and part.startswith("@"):
            continue
        out += f"[{part}]" if isinstance(part, int) else (f".{part}" if out else str(part))
    return out


def _model_at(model: type[BaseModel], path: tuple) -> type[BaseModel] | None:
    """The pydantic model that owns the field at ``path`` (list indices skipped).

    A tagged union's member is named in the path by its tag (``@span``): the member
    with that tag is followed, not the union's first.
    """
    current: type[BaseModel] | None = model
    annotation = None
    for part in path:
        if isinstance(part, int):
            continue
        if part.startswith("@"):
            current = _tagged_model(annotation, part) or current
            continue
        if current is None:
            return None
        field = current.model_fields.get(part)
        if field is None:
            return None
        annotation = field.annotation
        current = _first_model(annotation)
    return current


def _first_model(annotation) -> type[BaseModel] | None:
    if isinstance(annotation, type) and issubclass(annotation, BaseModel):
        return annotation
    for arg in typing.get_args(annotation):
        found = _first_model(arg)
        if found is not None:
            return found
    return None


def _tagged_model(annotation, tag: str) -> type[BaseModel] | None:
    """The member of the (nested) tagged union in ``annotation`` whose ``Tag`` is ``tag``."""
    for arg in typing.get_args(annotation):
        if any(getattr(meta, "tag", None) == tag for meta in getattr(arg, "__metadata__", ())):
            return _first_model(arg)
        found = _tagged_model(arg, tag)
        if found is not None:
            return found
    return None


def problems_from(exc: ValidationError, model: type[BaseModel], prefix: tuple = ()) -> list[tuple[str, str]]:
    """Every error of ``exc`` as ``(location, message)``; unknown keys get a did-you-mean."""
    problems = []
    for err in exc.errors():
        loc = tuple(err["loc"])
        message = err["msg"]
        if err["type"] == "extra_forbidden":
            owner = _model_at(model, loc[:-1])
            choices = list(owner.model_fields) if owner else []
            message = f"unknown key{did_you_mean(str(loc[-1]), choices)}; allowed: {', '.join(choices)}"
        elif err["type"] == "missing":
            message = "required key missing"
        elif "input" in err and err["type"] not in ("model_type", "dict_type"):
            message = f"{message} (got {err['input']!r})"
        problems.append((format_location(prefix + loc), message))
    return problems
