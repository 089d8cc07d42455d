"""The registry of installed components, and small scenes that run in well under a second."""

from __future__ import annotations

import pytest

from gns_framework.plugins import load_registry


@pytest.fixture(scope="session")
def sim_registry():
    return load_registry()


@pytest.fixture(scope="session")
def materials(sim_registry):
    return {name: sim_registry.get("material", name) for name in sim_registry.names("material")}
