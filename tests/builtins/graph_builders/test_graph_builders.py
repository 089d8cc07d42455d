"""Graph builders against brute force; every radius builder gives the same edge set."""

from __future__ import annotations

import importlib.util

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from gns_framework.errors import PluginError, RecipeError
from gns_framework.plugins import load_registry
from gns_framework.testing import small_scene

REGISTRY = load_registry()
RADIUS = 0.1
RADIUS_BUILDERS = ["radius", "periodic_radius"] + (
    ["radius_torch_cluster"] if importlib.util.find_spec("torch_cluster") else []
)


def build(name, scene, position, batch, num_examples, **params):
    cls = REGISTRY.get("graph_builder", name)
    return cls(cls.Params.model_validate(params), scene).build(position, batch, num_examples)


def edge_set(graph):
    return set(zip(graph.senders.tolist(), graph.receivers.tolist()))


def brute_force_radius(position, batch, radius, box_length=None):
    """Pairs (sender, receiver) of one example at squared distance < R^2 (minimum image where given)."""
    p = position.double().numpy()
    diff = p[:, None] - p[None]
    if box_length is not None:
        diff = diff - box_length * np.floor(diff / box_length + 0.5)
    close = (diff**2).sum(-1) < radius**2
    close &= batch.numpy()[:, None] == batch.numpy()[None]
    receivers, senders = np.nonzero(close)
    return set(zip(senders.tolist(), receivers.tolist()))


scenes = st.tuples(
    st.integers(2, 3),
    st.lists(st.integers(1, 40), min_size=1, max_size=3),
    st.integers(0, 2**31 - 1),
    st.sampled_from([0.5, 1.0, 3.0]),
)


def random_positions(dim, counts, seed, spread):
    generator = torch.Generator().manual_seed(seed)
    position = torch.rand(sum(counts), dim, generator=generator, dtype=torch.float64) * spread
    batch = torch.repeat_interleave(torch.arange(len(counts)), torch.tensor(counts))
    return position, batch


@settings(max_examples=40, deadline=None)
@given(scenes)
def test_every_radius_builder_gives_the_same_edges(case):
    dim, counts, seed, spread = case
    position, batch = random_positions(dim, counts, seed, spread)
    scene = small_scene(dim, RADIUS)
    expected = brute_force_radius(position, batch, RADIUS)
    for name in RADIUS_BUILDERS:
        assert edge_set(build(name, scene, position, batch, len(counts))) == expected, name


@settings(max_examples=40, deadline=None)
@given(scenes)
def test_periodic_radius_is_the_minimum_image_radius_graph(case):
    dim, counts, seed, _ = case
    position, batch = random_positions(dim, counts, seed, 1.0)
    scene = small_scene(dim, RADIUS, periodic=(True,) * dim)
    graph = build("periodic_radius", scene, position, batch, len(counts))
    assert edge_set(graph) == brute_force_radius(position, batch, RADIUS, box_length=1.0)
    assert float(torch.linalg.vector_norm(graph.displacement, dim=-1).max()) < RADIUS


def test_periodic_radius_connects_across_the_face_only_along_periodic_dimensions():
    position = torch.tensor([[0.01, 0.5], [0.99, 0.5], [0.5, 0.01], [0.5, 0.99]], dtype=torch.float64)
    batch = torch.zeros(4, dtype=torch.long)
    graph = build("periodic_radius", small_scene(2, RADIUS, periodic=(True, False)), position, batch, 1)
    assert edge_set(graph) - {(i, i) for i in range(4)} == {(0, 1), (1, 0)}
    across = (graph.senders == 1) & (graph.receivers == 0)
    assert torch.allclose(graph.displacement[across], torch.tensor([[-0.02, 0.0]], dtype=torch.float64))


def test_periodic_radius_refuses_a_box_shorter_than_two_radii():
    with pytest.raises(RecipeError, match="2R"):
        REGISTRY.get("graph_builder", "periodic_radius")(
            REGISTRY.get("graph_builder", "periodic_radius").Params(), small_scene(2, 0.6, periodic=(True, True))
        )


@settings(max_examples=40, deadline=None)
@given(scenes, st.integers(1, 12), st.booleans())
def test_knn_matches_brute_force(case, k, self_edges):
    dim, counts, seed, spread = case
    position, batch = random_positions(dim, counts, seed, spread)
    graph = build("knn", small_scene(dim, RADIUS), position, batch, len(counts), k=k, self_edges=self_edges)
    expected = set()
    start = 0
    for count in counts:
        p = position[start : start + count]
        d2 = ((p[:, None] - p[None]) ** 2).sum(-1)
        if not self_edges:
            d2.fill_diagonal_(float("inf"))
        take = min(k, count if self_edges else count - 1)
        nearest = torch.argsort(d2, dim=1, stable=True)[:, :take]
        expected |= {(int(s) + start, r + start) for r in range(count) for s in nearest[r]}
        start += count
    assert edge_set(graph) == expected
    in_degree = torch.bincount(graph.receivers, minlength=position.shape[0])
    assert int(in_degree.max()) <= k


def test_knn_max_radius_drops_far_neighbours():
    position = torch.tensor([[0.0, 0.0], [0.05, 0.0], [0.5, 0.0]], dtype=torch.float64)
    graph = build("knn", small_scene(2), position, torch.zeros(3, dtype=torch.long), 1, k=3, max_radius=0.1)
    assert edge_set(graph) == {(0, 0), (1, 0), (0, 1), (1, 1), (2, 2)}


@pytest.mark.skipif(importlib.util.find_spec("torch_cluster") is not None, reason="torch-cluster is installed")
def test_torch_cluster_builder_without_torch_cluster_says_what_to_install():
    cls = REGISTRY.get("graph_builder", "radius_torch_cluster")
    with pytest.raises(PluginError, match="pip install torch-cluster"):
        cls(cls.Params(), small_scene())
