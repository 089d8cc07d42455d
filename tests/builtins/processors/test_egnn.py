"""The EGNN processor is invariant to rotations, reflections and translations of the positions."""

from __future__ import annotations

import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from gns_framework.contracts import Graph
from gns_framework.plugins import load_registry
from gns_framework.testing import small_sizes

REGISTRY = load_registry()


@settings(max_examples=25, deadline=None)
@given(st.integers(2, 3), st.integers(0, 2**31 - 1))
def test_egnn_outputs_do_not_change_under_orthogonal_maps_of_the_positions(dim, seed):
    generator = torch.Generator().manual_seed(seed)
    torch.manual_seed(seed)
    sizes = small_sizes(dim)
    cls = REGISTRY.get("processor", "egnn")
    processor = cls(cls.Params(message_passing_steps=3), sizes).double()
    n = 15
    position = torch.rand(n, dim, generator=generator, dtype=torch.float64) * 0.3
    receivers, senders = (torch.cdist(position, position) < 0.15).nonzero(as_tuple=True)
    x = torch.randn(n, sizes.latent, generator=generator, dtype=torch.float64)
    e = torch.randn(senders.numel(), sizes.latent, generator=generator, dtype=torch.float64)
    rotation, _ = torch.linalg.qr(torch.randn(dim, dim, generator=generator, dtype=torch.float64))
    shift = torch.randn(dim, generator=generator, dtype=torch.float64)

    def run(p):
        return processor(x, e, Graph(senders, receivers, p[senders] - p[receivers], n))

    x_out, e_out = run(position)
    x_moved, e_moved = run(position @ rotation.T + shift)
    assert torch.allclose(x_out, x_moved, atol=1e-9)
    assert torch.allclose(e_out, e_moved, atol=1e-9)


def test_egnn_depends_on_the_geometry():
    sizes = small_sizes(2)
    cls = REGISTRY.get("processor", "egnn")
    processor = cls(cls.Params(message_passing_steps=2), sizes).double()
    senders, receivers = torch.tensor([0, 1, 0, 1]), torch.tensor([0, 0, 1, 1])
    x, e = torch.randn(2, sizes.latent, dtype=torch.float64), torch.randn(4, sizes.latent, dtype=torch.float64)

    def run(distance):
        p = torch.tensor([[0.0, 0.0], [distance, 0.0]], dtype=torch.float64)
        return processor(x, e, Graph(senders, receivers, p[senders] - p[receivers], 2))[0]

    assert not torch.allclose(run(0.02), run(0.08))
