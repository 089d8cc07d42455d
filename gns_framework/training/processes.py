"""Deprecated: ``Processes`` moved to :mod:`gns_framework.runtime.processes` (rollouts, the decomposition and
training all run on it). Importing it from here still works, with a DeprecationWarning."""

from __future__ import annotations

from ..moved import old_home

__getattr__ = old_home(__name__, "gns_framework.runtime.processes")
