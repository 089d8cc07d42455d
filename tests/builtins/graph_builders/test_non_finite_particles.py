"""The graph-builder contract's promise that a particle at a non-finite position joins no edge, for every built-in
builder: a batch padded to a capacity class (model/capacity_classes.py) relies on it."""

from __future__ import annotations

import pytest
import torch
from graph_cases import RADIUS, build, edge_set, random_positions

from gns_framework.testing import small_scene


@pytest.mark.parametrize(
    "name, periodic", [("radius", False), ("radius_fixed_capacity", False), ("knn", False), ("periodic_radius", True)]
)
def test_a_non_finite_particle_joins_no_edge_and_leaves_the_others_theirs(name, periodic):
    position, batch = random_positions(2, [40, 30], seed=3, spread=1.0)
    scene = small_scene(2, RADIUS, periodic=(periodic, periodic))
    alone = edge_set(build(name, scene, position, batch, 2))
    padding = torch.tensor([[float("nan"), 0.5], [float("nan")] * 2, [float("inf"), 0.2], [0.3, float("nan")]])
    padded = torch.cat([position, padding.to(position.dtype)])
    with_padding = edge_set(build(name, scene, padded, torch.cat([batch, torch.full((4,), 1)]), 2))  # with the 30
    assert alone and with_padding == alone
