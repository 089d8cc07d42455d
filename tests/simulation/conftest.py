"""A registry whose materials carry the simulator attributes, and small scenes that run in well under a second."""

from __future__ import annotations

import pytest

from gns_framework.plugins import DISABLE_ENV, load_registry
from simulation import sim_materials


@pytest.fixture(scope="session")
def sim_registry():
    with pytest.MonkeyPatch.context() as patch:
        patch.setenv(DISABLE_ENV, "builtin-materials")
        return load_registry(plugins=[("simulation-test-materials", sim_materials)])


@pytest.fixture(scope="session")
def materials(sim_registry):
    return {name: sim_registry.get("material", name) for name in sim_registry.names("material")}
