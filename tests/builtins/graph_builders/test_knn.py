"""The k-nearest-neighbour graph: brute force, ties, constant in-degree, chunks, and degenerate examples."""

from __future__ import annotations

import torch
from graph_cases import RADIUS, build, edge_set, random_positions, scenes
from hypothesis import given, settings
from hypothesis import strategies as st

from gns_builtins.graph_builders import knn
from gns_framework.testing import small_scene


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


def test_a_tie_goes_to_the_lower_sender_index():
    # Particles 1 and 2 are both 0.25 from particle 0 (exactly, by symmetry): with k = 1 particle 0 takes 1.
    position = torch.tensor([[0.0, 0.0], [0.25, 0.0], [-0.25, 0.0], [0.5, 0.5]], dtype=torch.float64)
    batch = torch.zeros(4, dtype=torch.long)
    graph = build("knn", small_scene(2), position, batch, 1, k=1, self_edges=False)
    assert (graph.senders[graph.receivers == 0]).tolist() == [1]
    # Swapping the two particles' indices swaps the winner: the tie is decided by index, not by place.
    swapped = position[[0, 2, 1, 3]]
    graph = build("knn", small_scene(2), swapped, batch, 1, k=1, self_edges=False)
    assert (graph.senders[graph.receivers == 0]).tolist() == [1]
    torch.testing.assert_close(graph.displacement[graph.receivers == 0], swapped[[1]] - swapped[[0]])


def test_every_particle_receives_exactly_k_edges_whatever_the_density():
    # A dense clump and a sparse cloud: unlike the radius graph, each receiver gets k senders (itself among them).
    generator = torch.Generator().manual_seed(3)
    position = torch.cat([torch.rand(30, 2, generator=generator) * 0.01, torch.rand(10, 2, generator=generator)])
    graph = build("knn", small_scene(2), position, torch.zeros(40, dtype=torch.long), 1, k=5)
    assert torch.bincount(graph.receivers, minlength=40).tolist() == [5] * 40
    assert set(graph.senders[graph.receivers == graph.senders].tolist()) == set(range(40)), "self-edges counted"


def test_edges_are_sorted_by_receiver_then_sender_with_their_displacements():
    position, batch = random_positions(2, [12, 9], seed=5, spread=1.0)
    graph = build("knn", small_scene(2), position, batch, 2, k=4)
    keys = (graph.receivers * position.shape[0] + graph.senders).tolist()
    assert keys == sorted(keys)
    torch.testing.assert_close(graph.displacement, position[graph.senders] - position[graph.receivers])
    assert bool((batch[graph.senders] == batch[graph.receivers]).all()), "no edge between examples"


def test_chunks_of_a_few_receivers_give_the_same_graph(monkeypatch):
    position, batch = random_positions(3, [25, 14], seed=11, spread=1.0)
    whole = build("knn", small_scene(3), position, batch, 2, k=6, self_edges=False)
    # 30 pairs per chunk: one receiver of the 25-particle example per chunk, two of the 14-particle one.
    monkeypatch.setattr(knn, "_PAIRS_PER_CHUNK", 30)
    chunked = build("knn", small_scene(3), position, batch, 2, k=6, self_edges=False)
    assert torch.equal(chunked.senders, whole.senders) and torch.equal(chunked.receivers, whole.receivers)


def test_examples_without_candidates_give_no_edges():
    # Example 0 has one particle and no self-edges; example 1 is empty; example 2 has two particles.
    position = torch.tensor([[0.1, 0.1], [0.5, 0.5], [0.6, 0.5]], dtype=torch.float64)
    batch = torch.tensor([0, 2, 2])
    graph = build("knn", small_scene(2), position, batch, 3, k=3, self_edges=False)
    assert edge_set(graph) == {(1, 2), (2, 1)} and graph.num_nodes == 3
    lonely = build("knn", small_scene(2), position[:1], batch[:1], 1, k=3, self_edges=False)
    assert lonely.senders.numel() == 0 and lonely.displacement.shape == (0, 2)
