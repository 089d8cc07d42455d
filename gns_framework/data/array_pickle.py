"""Deprecated: the pickle reader moved to ``gns_builtins.datasets._formats.array_pickle`` (a format reader,
beside the formats that use it), ``pickle_granted`` to :mod:`gns_framework.data.pickle_grant`.

Importing a moved name from here still works, with a DeprecationWarning naming its new home.
"""

from __future__ import annotations

import importlib
import warnings
from typing import Any

_NEW_HOMES = {"pickle_granted": "gns_framework.data.pickle_grant"}
READER = "gns_builtins.datasets._formats.array_pickle"


def __getattr__(name: str) -> Any:
    home = _NEW_HOMES.get(name, READER)
    module = importlib.import_module(home)
    if not hasattr(module, name):
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    warnings.warn(
        f"gns_framework.data.array_pickle.{name} moved to {home}.{name}; import it from there",
        DeprecationWarning,
        stacklevel=2,
    )
    return getattr(module, name)
