"""The cell-list radius search: exact against brute force, strict radius, invariances (hypothesis), and its parts.

Its parts are the dense ranks that keep cell keys small, the left-to-right squared
distance the reference rounds with, the chunking of the candidate list, and the
expansion of cell ranges into candidate pairs.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from gns_builtins._kernels import cell_list
from gns_builtins._kernels.cell_list import DenseRanks, radius_pairs, squared_distance


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
    assert set(zip(senders.tolist(), receivers.tolist(), strict=True)) == brute_force(position, batch, radius)
    keys = (receivers * len(position) + senders).tolist()
    assert keys == sorted(keys), "edges are sorted by (receiver, sender)"


@settings(max_examples=30, deadline=None)
@given(scenes, st.lists(st.floats(-5, 5), min_size=3, max_size=3))
def test_translation_invariance(scene, shift):
    position, batch, radius = make(*scene)
    # A shift by a multiple of a power of two keeps float32 differences exact.
    offset = torch.tensor(shift[: position.shape[1]], dtype=torch.float32).round()
    before = set(zip(*[t.tolist() for t in radius_pairs(position, batch, radius)], strict=True))
    after = set(zip(*[t.tolist() for t in radius_pairs(position + offset, batch, radius)], strict=True))
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
        for a, c in zip(idx, shuffled, strict=True):
            perm[a] = c
    perm_t = torch.tensor(perm)
    original = set(zip(*[t.tolist() for t in radius_pairs(position, batch, radius)], strict=True))
    s, r = radius_pairs(position[perm_t], batch, radius)
    mapped = {(perm[a], perm[b]) for a, b in zip(s.tolist(), r.tolist(), strict=True)}
    assert mapped == original


def test_strict_radius_and_self_edges():
    position = torch.tensor([[0.0, 0.0], [0.5, 0.0], [0.25, 0.0]])
    batch = torch.zeros(3, dtype=torch.long)
    s, r = radius_pairs(position, batch, 0.5)
    pairs = set(zip(s.tolist(), r.tolist(), strict=True))
    assert (0, 1) not in pairs and (1, 0) not in pairs, "distance == R is not an edge"
    assert {(0, 0), (1, 1), (2, 2), (0, 2), (2, 0), (1, 2), (2, 1)} == pairs


def test_dense_cluster_keeps_every_neighbour():
    """No cap: 400 particles within R of each other give 400 * 400 edges."""
    position = torch.rand(400, 2) * 0.01
    s, _r = radius_pairs(position, torch.zeros(400, dtype=torch.long), 0.1)
    assert len(s) == 400 * 400


def test_far_apart_particles_do_not_overflow_cell_keys():
    position = torch.tensor([[0.0, 0.0], [1e30, -1e30], [1e30, -1e30], [1e6, 1e6], [1e6 + 0.5, 1e6]])
    s, r = radius_pairs(position, torch.zeros(5, dtype=torch.long), 1.0)
    expected = {(i, i) for i in range(5)} | {(1, 2), (2, 1), (3, 4), (4, 3)}
    assert set(zip(s.tolist(), r.tolist(), strict=True)) == expected


def test_chunked_search_finds_the_same_edges(monkeypatch):
    """Chunks of a few candidates (cuts inside and between receivers' ranges) change no edge and no order."""
    position, batch, radius = make(3, [60, 40], 0.3, 7)
    whole = radius_pairs(position, batch, radius)
    for size in (1, 37, 500):
        monkeypatch.setattr(cell_list, "CANDIDATES_PER_CHUNK_CPU", size)
        for got, expected in zip(radius_pairs(position, batch, radius), whole, strict=True):
            assert torch.equal(got, expected), size


def test_empty_scene_has_no_pairs():
    senders, receivers = radius_pairs(torch.zeros(0, 3), torch.zeros(0, dtype=torch.long), 0.1)
    assert senders.shape == receivers.shape == (0,) and senders.dtype == torch.long


def test_dense_ranks_number_the_distinct_values_in_order():
    ranks = DenseRanks(torch.tensor([5, -3, 5, 100, -3, 7]))
    assert ranks.ranks.tolist() == [1, 0, 1, 3, 0, 2]
    assert int(ranks.size) == 4
    assert ranks.sorted_values.tolist() == [-3, -3, 5, 5, 7, 100]
    assert ranks.sorted_ranks.tolist() == [0, 0, 1, 1, 2, 3]


def test_rank_of_says_which_targets_occur_among_the_values():
    ranks = DenseRanks(torch.tensor([5, -3, 5, 100, -3, 7]))
    rank, exists = ranks.rank_of(torch.tensor([7, 6, 101, -3, -10, 100]))
    assert exists.tolist() == [True, False, False, True, False, True]
    # Only where the target occurs is the rank meaningful (a neighbouring cell that holds particles).
    assert rank[exists].tolist() == [2, 0, 3]


def test_squared_distance_sums_the_components_left_to_right_in_the_inputs_dtype():
    # Squares 1, 2^-24, 2^-24 in float32: (1 + 2^-24) rounds to 1 (ties to even), and so does adding 2^-24
    # again, while summing the two small squares first gives 1 + 2^-23. The reference rounds left to right.
    a = torch.tensor([[1.0, 2.0**-12, 2.0**-12]], dtype=torch.float32)
    d2 = squared_distance(a, torch.zeros_like(a))
    assert d2.dtype == torch.float32 and d2.tolist() == [1.0]
    assert float(torch.tensor(1.0) + torch.tensor(2.0**-23)) != 1.0, "the other order would differ"


def test_one_chunk_when_the_candidates_fit():
    assert cell_list._chunk_bounds(torch.tensor([3, 0, 2]), 5) == ([0, 3], [5])


def test_chunks_are_cut_after_the_receiver_where_the_count_passes_each_multiple_of_the_size():
    # Cumulative counts 3, 3, 8, 10, 14 with size 5: 5 is passed at receiver 2 and 10 reached at receiver 3,
    # so the chunks are receivers [0, 2), [2, 4), [4, 5) with 3, 7 and 4 candidates.
    per_receiver = torch.tensor([3, 0, 5, 2, 4])
    assert cell_list._chunk_bounds(per_receiver, 5) == ([0, 2, 4, 5], [3, 7, 4])


def test_a_receiver_with_more_candidates_than_a_chunk_is_never_split():
    # Receiver 1 alone holds 20 of the 22 candidates: the marks 5, 10, 15 and 20 all fall in its range.
    bounds, totals = cell_list._chunk_bounds(torch.tensor([1, 20, 1]), 5)
    assert (bounds, totals) == ([0, 1, 3], [1, 21])


def test_expand_lists_every_particle_of_each_receivers_cell_ranges():
    # Sorted particles 10..14; receiver 4 takes 2 from position 0 and 1 from position 3, receiver 5 takes 2 from 0.
    order = torch.tensor([10, 11, 12, 13, 14])
    starts = torch.tensor([[0, 3], [1, 0]])
    counts = torch.tensor([[2, 1], [0, 2]])
    senders, receivers = cell_list._expand(starts, counts, order, first_receiver=4, total=5)
    assert senders.tolist() == [10, 11, 13, 10, 11]
    assert receivers.tolist() == [4, 4, 4, 5, 5]


@pytest.mark.parametrize("device_type, expected", [("cpu", 1 << 20), ("cuda", 1 << 25)])
def test_chunks_are_larger_on_accelerators(device_type, expected):
    # No device is needed to ask: torch.device only names it.
    assert cell_list.candidates_per_chunk(torch.device(device_type)) == expected
