"""Deprecated: the pickle reader moved to ``gns_builtins.datasets._formats.array_pickle`` (a format reader,
beside the formats that use it), ``pickle_granted`` to :mod:`gns_framework.data.pickle_grant`.

Importing a moved name from here still works, with a DeprecationWarning naming its new home.
"""

from __future__ import annotations

from ..moved import old_home

__getattr__ = old_home(
    __name__, "gns_builtins.datasets._formats.array_pickle", {"pickle_granted": "gns_framework.data.pickle_grant"}
)
