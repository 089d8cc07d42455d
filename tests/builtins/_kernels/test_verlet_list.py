"""Verlet lists: the radius graph of every frame, exactly, with the search skipped while particles move little."""

from __future__ import annotations

import pytest
import torch

from gns_builtins._kernels import verlet_list
from gns_builtins._kernels.cell_list import radius_pairs
from gns_builtins._kernels.verlet_list import VerletList

R = 0.05
SKIN = 0.5 * R


def _walk(frames: int, n: int = 400, step: float = 0.002, seed: int = 0) -> list[torch.Tensor]:
    """Frames of ``n`` particles in a unit square of two examples, each moving ``step`` a frame in a random
    direction."""
    generator = torch.Generator().manual_seed(seed)
    position = torch.rand(n, 2, generator=generator)
    out = [position]
    for _ in range(frames - 1):
        direction = torch.randn(n, 2, generator=generator)
        position = position + step * direction / direction.norm(dim=1, keepdim=True)
        out.append(position)
    return out


BATCH = torch.cat([torch.zeros(200, dtype=torch.long), torch.ones(200, dtype=torch.long)])


def test_every_frame_gets_exactly_the_radius_graph_with_fewer_searches():
    verlet = VerletList(R, SKIN)
    frames = _walk(40)
    for position in frames:
        senders, receivers = verlet.pairs(position, BATCH)
        expected = radius_pairs(position, BATCH, R)
        assert torch.equal(senders, expected[0]) and torch.equal(receivers, expected[1])
    # 0.002 a frame: a particle reaches 0.45 x 0.025 m after 6 frames at the earliest.
    assert 1 < verlet.searches <= 40 // 5


def test_a_pair_closing_in_from_beyond_the_skin_is_found():
    # Two particles at R + s + 1e-4 at the search (not candidates) close in by 0.6 s each: now inside R.
    gap = R + SKIN + 1e-4
    searched = torch.tensor([[0.3, 0.5], [0.3 + gap, 0.5]], dtype=torch.float32)
    one = torch.zeros(2, dtype=torch.long)
    verlet = VerletList(R, SKIN)
    assert verlet.pairs(searched, one)[0].tolist() == [0, 1]  # self-pairs only
    closer = searched + torch.tensor([[0.6 * SKIN, 0.0], [-0.6 * SKIN, 0.0]])
    senders, receivers = verlet.pairs(closer, one)
    assert (senders.tolist(), receivers.tolist()) == ([0, 1, 0, 1], [0, 0, 1, 1])
    assert verlet.searches == 2


def test_a_lax_threshold_would_miss_that_pair(monkeypatch):
    """The check above catches a wrong bound: searching again only past the full skin loses the pair."""
    monkeypatch.setattr(verlet_list, "REBUILD_FRACTION", 1.0)
    gap = R + SKIN + 1e-4
    searched = torch.tensor([[0.3, 0.5], [0.3 + gap, 0.5]], dtype=torch.float32)
    one = torch.zeros(2, dtype=torch.long)
    verlet = VerletList(R, SKIN)
    verlet.pairs(searched, one)
    closer = searched + torch.tensor([[0.6 * SKIN, 0.0], [-0.6 * SKIN, 0.0]])
    assert verlet.pairs(closer, one)[0].tolist() == [0, 1], "the pair is lost: the bound matters"


def test_other_particles_or_examples_are_searched_afresh():
    verlet = VerletList(R, SKIN)
    position = _walk(1)[0]
    verlet.pairs(position, BATCH)
    regrouped = torch.cat([torch.zeros(100, dtype=torch.long), torch.ones(300, dtype=torch.long)])
    senders, _ = verlet.pairs(position, regrouped)
    assert torch.equal(senders, radius_pairs(position, regrouped, R)[0]) and verlet.searches == 2
    fewer = position[:300]
    assert torch.equal(verlet.pairs(fewer, BATCH[:300])[0], radius_pairs(fewer, BATCH[:300], R)[0])
    assert verlet.searches == 3
    empty = torch.empty(0, 2)
    assert verlet.pairs(empty, torch.empty(0, dtype=torch.long))[0].numel() == 0


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_pairs_on_the_radius_compare_as_the_search_does(dtype):
    # A lattice of spacing R: every neighbour sits on the radius, where only the rounding of the
    # comparison decides; the filter compares exactly as radius_pairs does.
    xs, ys = torch.meshgrid(torch.arange(12), torch.arange(12), indexing="ij")
    lattice = (torch.stack([xs.ravel(), ys.ravel()], 1) * R + 0.1).to(dtype)
    batch = torch.zeros(len(lattice), dtype=torch.long)
    verlet = VerletList(R, SKIN)
    for shift in (0.0, 1e-7, 3e-4):
        position = lattice + shift
        assert torch.equal(verlet.pairs(position, batch)[0], radius_pairs(position, batch, R)[0])
    assert verlet.searches == 1
