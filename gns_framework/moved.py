"""Old homes of moved names: importing from one still works, with a DeprecationWarning naming the new home.

A module that moved leaves a stub whose module-level ``__getattr__`` is
``old_home(__name__, default_home, {name: home, ...})``.
"""

from __future__ import annotations

import importlib
import warnings
from collections.abc import Callable
from typing import Any


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
