"""Fixtures of the dataset-layout tests: two small trajectories with every optional field a layout may store."""

from __future__ import annotations

import pytest
from synthetic import soft_sphere_trajectory


@pytest.fixture(scope="module")
def trajectories():
    return [
        soft_sphere_trajectory(0, frames=12, key="a", particle_types=(5, 6), kinematic_floor=True, with_property=True),
        soft_sphere_trajectory(1, frames=12, key="b", particle_types=(5, 6), kinematic_floor=True, with_property=True),
    ]
