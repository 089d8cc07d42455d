"""Every radius builder gives the brute-force radius edges (each builder's own behaviour: its mirror test)."""

from __future__ import annotations

import importlib.util

from graph_cases import RADIUS, brute_force_radius, build, edge_set, random_positions, scenes
from hypothesis import given, settings

from gns_framework.testing import small_scene

RADIUS_BUILDERS = ["radius", "radius_fixed_capacity", "periodic_radius"] + (
    ["radius_torch_cluster"] if importlib.util.find_spec("torch_cluster") else []
)


@settings(max_examples=40, deadline=None)
@given(scenes)
def test_every_radius_builder_gives_the_same_edges(case):
    dim, counts, seed, spread = case
    position, batch = random_positions(dim, counts, seed, spread)
    scene = small_scene(dim, RADIUS)
    expected = brute_force_radius(position, batch, RADIUS)
    for name in RADIUS_BUILDERS:
        assert edge_set(build(name, scene, position, batch, len(counts))) == expected, name
