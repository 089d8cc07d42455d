"""Old homes of moved names: importing from one still works, with a DeprecationWarning naming the new home.

A module that moved leaves a stub whose module-level ``__getattr__`` is
``old_home(__name__, default_home, {name: home, ...})``. A renamed attribute leaves
``old = renamed_attribute("old", "new")`` in its class, a renamed keyword a
``@renamed_keywords(old="new")`` on its function, and a class whose attribute and constructor
keyword were renamed together a ``@renamed("old", "new")``; parameters that became keyword-only a
``@formerly_positional(...)`` on their function.
"""

from __future__ import annotations

import functools
import importlib
import inspect
import warnings
from collections.abc import Callable
from typing import Any, ParamSpec, TypeVar

P = ParamSpec("P")
R = TypeVar("R")
C = TypeVar("C", bound=type)


def old_home(old: str, default_home: str, homes: dict[str, str] | None = None) -> Callable[[str], Any]:
    """A module ``__getattr__`` for ``old``: each name from ``homes`` (default: ``default_home``), with a warning."""

    def __getattr__(name: str) -> Any:
        home = (homes or {}).get(name, default_home)
        module = importlib.import_module(home)
        if name.startswith("__") or not hasattr(module, name):
            raise AttributeError(f"module {old!r} has no attribute {name!r}")
        warnings.warn(f"{old}.{name} moved to {home}.{name}; import it from there", DeprecationWarning, stacklevel=2)
        return getattr(module, name)

    return __getattr__


def renamed_attribute(old: str, new: str) -> property:
    """A read-only property ``old`` for an attribute renamed ``new``: ``self.<new>``, with a warning."""

    def get(self: Any) -> Any:
        warnings.warn(
            f"{type(self).__name__}.{old} is now .{new}; the old name goes in 0.3", DeprecationWarning, stacklevel=2
        )
        return getattr(self, new)

    return property(get, doc=f"Deprecated: the old name of ``{new}``.")


def renamed_keywords(**renames: str) -> Callable[[Callable[P, R]], Callable[P, R]]:
    """A decorator: the function also takes each renamed keyword under its old name (``old="new"``), with a warning.

    A function that still has a parameter of an old name is returned as it is (a subclass's own ``__init__``).
    """

    def decorate(function: Callable[P, R]) -> Callable[P, R]:
        taken = inspect.signature(function).parameters
        old_names = {old: new for old, new in renames.items() if old not in taken}
        if not old_names:
            return function
        name = function.__qualname__.removesuffix(".__init__")

        @functools.wraps(function)
        def renamed(*args: P.args, **kwargs: P.kwargs) -> R:
            for old in old_names.keys() & kwargs.keys():
                new = old_names[old]
                warnings.warn(
                    f"{name}({old}=...) is now {name}({new}=...); the old keyword goes in 0.3",
                    DeprecationWarning,
                    stacklevel=2,
                )
                if new in kwargs:
                    raise TypeError(f"{name}() got both {old}= and its new name {new}=")
                kwargs[new] = kwargs.pop(old)
            return function(*args, **kwargs)

        return renamed

    return decorate


def renamed(old: str, new: str) -> Callable[[C], C]:
    """A class decorator for an attribute renamed together with its constructor keyword: ``old`` still reads
    (:func:`renamed_attribute`) and the class's ``__init__`` still takes ``old=`` (:func:`renamed_keywords`)."""

    def decorate(cls: C) -> C:
        setattr(cls, old, renamed_attribute(old, new))
        cls.__init__ = renamed_keywords(**{old: new})(cls.__init__)  # type: ignore[misc]
        return cls

    return decorate


def formerly_positional(*names: str, after: int) -> Callable[[Callable[P, R]], Callable[P, R]]:
    """A decorator: parameters ``names`` that stood, in that order, after the first ``after`` arguments (``self``
    counted) and are keyword-only now still take arguments by position, with a warning."""

    def decorate(function: Callable[P, R]) -> Callable[P, R]:
        name = function.__qualname__.removesuffix(".__init__")

        @functools.wraps(function)
        def by_keyword(*args: P.args, **kwargs: P.kwargs) -> R:
            late = args[after:]
            if not late:
                return function(*args, **kwargs)
            if len(late) > len(names):
                raise TypeError(f"{name}() takes at most {after + len(names)} positional arguments, got {len(args)}")
            moved = names[: len(late)]
            by_position = f"{name}(): pass {', '.join(moved)} by keyword; by position goes in 0.3"
            warnings.warn(by_position, DeprecationWarning, stacklevel=2)
            for key, value in zip(moved, late, strict=True):
                if key in kwargs:
                    raise TypeError(f"{name}() got {key} by position and by keyword")
                kwargs[key] = value
            positional: Callable[..., R] = function  # P.args cut short is no longer P.args to a checker
            return positional(*args[:after], **kwargs)

        return by_keyword

    return decorate
