"""The shipped model in float64 and a synthetic observation, for the inverse problems of these tests."""

from __future__ import annotations

import pytest
from inverse_cases import MODEL, SAND
from synthetic import soft_sphere_trajectory, synthetic_metadata

from gns_framework.assembly.trained import load_trained


@pytest.fixture(scope="module")
def shipped_float64(registry):
    model = load_trained(MODEL, registry, "cpu")
    return model.simulator.double()


@pytest.fixture(scope="module")
def observed():
    """A falling block of sand-typed particles with a friction column, 12 frames."""
    trajectory = soft_sphere_trajectory(3, frames=12, block=5, particle_types=(SAND,), with_property=True, key="block")
    return trajectory, synthetic_metadata([trajectory], 2)
