"""The radius graph: exact against brute force, strict radius, invariances (hypothesis)."""

from __future__ import annotations

import numpy as np
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from gns_framework.contracts import ModelSetup
from gns_builtins._kernels.cell_list import radius_pairs
from gns_builtins.graph_builders.radius import RadiusGraphBuilder


def brute_force(position: torch.Tensor, batch: torch.Tensor, radius: float) -> set[tuple[int, int]]:
    """Every pair, distance summed left to right in float32 as the reference does."""
    r2 = np.float32(radius * radius)
    pos = position.numpy()
    pairs = set()
    for i in range(len(pos)):
        for j in range(len(pos)):
            if batch[i] != batch[j]:
                continue
            diff = (pos[i] - pos[j]).astype(np.float32)
            d2 = np.float32(0)
            for k in range(pos.shape[1]):
                d2 = np.float32(d2 + diff[k] * diff[k])
            if d2 < r2:
                pairs.add((j, i))
    return pairs


scenes = st.integers(2, 3).flatmap(
    lambda dim: st.tuples(
        st.just(dim),
        st.lists(st.integers(1, 25), min_size=1, max_size=3),
        st.floats(0.05, 0.4),
        st.integers(0, 2**31 - 1),
    )
)


def make(dim, counts, radius, seed, scale=1.0):
    rng = np.random.default_rng(seed)
    n = sum(counts)
    position = torch.from_numpy((rng.uniform(0, scale, (n, dim))).astype(np.float32))
    batch = torch.repeat_interleave(torch.arange(len(counts)), torch.tensor(counts))
    return position, batch, radius


@settings(max_examples=60, deadline=None)
@given(scenes)
def test_matches_brute_force(scene):
    position, batch, radius = make(*scene)
    senders, receivers = radius_pairs(position, batch, radius)
    assert set(zip(senders.tolist(), receivers.tolist())) == brute_force(position, batch, radius)
    keys = (receivers * len(position) + senders).tolist()
    assert keys == sorted(keys), "edges are sorted by (receiver, sender)"


@settings(max_examples=30, deadline=None)
@given(scenes, st.lists(st.floats(-5, 5), min_size=3, max_size=3))
def test_translation_invariance(scene, shift):
    position, batch, radius = make(*scene)
    # A shift by a multiple of a power of two keeps float32 differences exact.
    offset = torch.tensor(shift[: position.shape[1]], dtype=torch.float32).round()
    before = set(zip(*[t.tolist() for t in radius_pairs(position, batch, radius)]))
    after = set(zip(*[t.tolist() for t in radius_pairs(position + offset, batch, radius)]))
    assert before == after


@settings(max_examples=30, deadline=None)
@given(scenes, st.randoms(use_true_random=False))
def test_permutation_equivariance(scene, rnd):
    position, batch, radius = make(*scene)
    n = len(position)
    perm = list(range(n))
    # Permute within examples only, so the batch vector stays non-decreasing.
    for b in batch.unique().tolist():
        idx = [i for i in range(n) if batch[i] == b]
        shuffled = idx[:]
        rnd.shuffle(shuffled)
        for a, c in zip(idx, shuffled):
            perm[a] = c
    perm_t = torch.tensor(perm)
    original = set(zip(*[t.tolist() for t in radius_pairs(position, batch, radius)]))
    s, r = radius_pairs(position[perm_t], batch, radius)
    mapped = {(perm[a], perm[b]) for a, b in zip(s.tolist(), r.tolist())}
    assert mapped == original


def test_strict_radius_and_self_edges():
    position = torch.tensor([[0.0, 0.0], [0.5, 0.0], [0.25, 0.0]])
    batch = torch.zeros(3, dtype=torch.long)
    s, r = radius_pairs(position, batch, 0.5)
    pairs = set(zip(s.tolist(), r.tolist()))
    assert (0, 1) not in pairs and (1, 0) not in pairs, "distance == R is not an edge"
    assert {(0, 0), (1, 1), (2, 2), (0, 2), (2, 0), (1, 2), (2, 1)} == pairs


def test_dense_cluster_keeps_every_neighbour():
    """No cap: 400 particles within R of each other give 400 * 400 edges."""
    position = torch.rand(400, 2) * 0.01
    s, r = radius_pairs(position, torch.zeros(400, dtype=torch.long), 0.1)
    assert len(s) == 400 * 400


def test_far_apart_particles_do_not_overflow_cell_keys():
    position = torch.tensor([[0.0, 0.0], [1e30, -1e30], [1e30, -1e30], [1e6, 1e6], [1e6 + 0.5, 1e6]])
    s, r = radius_pairs(position, torch.zeros(5, dtype=torch.long), 1.0)
    expected = {(i, i) for i in range(5)} | {(1, 2), (2, 1), (3, 4), (4, 3)}
    assert set(zip(s.tolist(), r.tolist())) == expected


def test_builder_returns_displacements():
    scene = ModelSetup(dim=2, bounds=((0, 1), (0, 1)), connectivity_radius=0.3, particle_types=(5,))
    position = torch.tensor([[0.1, 0.1], [0.3, 0.1]])
    graph = RadiusGraphBuilder(RadiusGraphBuilder.Params(), scene).build(position, torch.zeros(2, dtype=torch.long), 1)
    for s, r, d in zip(graph.senders, graph.receivers, graph.displacement):
        assert torch.equal(d, position[s] - position[r])


def test_chunked_search_finds_the_same_edges(monkeypatch):
    """Chunks of a few candidates (cuts inside and between receivers' ranges) change no edge and no order."""
    from gns_builtins._kernels import cell_list

    position, batch, radius = make(3, [60, 40], 0.3, 7)
    whole = radius_pairs(position, batch, radius)
    for size in (1, 37, 500):
        monkeypatch.setattr(cell_list, "CANDIDATES_PER_CHUNK_CPU", size)
        for got, expected in zip(radius_pairs(position, batch, radius), whole):
            assert torch.equal(got, expected), size
