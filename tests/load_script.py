"""Import a project script (benchmarks/, scripts/, fixtures) that is not a package module, by its path."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path
from types import ModuleType

ROOT = Path(__file__).resolve().parents[1]


def load_script(path: str | Path, name: str | None = None) -> ModuleType:
    """The module of ``path`` (relative to the project root, or absolute), run once per call.

    It is registered in ``sys.modules`` under ``name`` (default: ``script_<stem>``)
    while and after it runs, as dataclasses and pickling look their module up there.
    """
    file = Path(path) if Path(path).is_absolute() else ROOT / path
    name = name or f"script_{file.stem}"
    spec = importlib.util.spec_from_file_location(name, file)
    assert spec is not None and spec.loader is not None, f"{file}: not a Python file"
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    spec.loader.exec_module(module)
    return module
