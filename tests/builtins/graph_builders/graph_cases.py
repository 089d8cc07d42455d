"""Random scenes, brute-force neighbour sets and a builder shortcut shared by the graph-builder tests."""

from __future__ import annotations

import numpy as np
import torch
from hypothesis import strategies as st

from gns_framework.plugins import load_registry

REGISTRY = load_registry()
RADIUS = 0.1


def build(name, scene, position, batch, num_examples, **params):
    cls = REGISTRY.get("graph_builder", name)
    return cls(cls.Params.model_validate(params), scene).build(position, batch, num_examples)


def edge_set(graph):
    """The (sender, receiver) pairs between particles: a fixed-size graph's padding edges (between its sink
    nodes, those past the particles of ``node_particle``) left out."""
    pairs = set(zip(graph.senders.tolist(), graph.receivers.tolist(), strict=True))
    if graph.node_particle is None:
        return pairs
    particles = int(graph.node_particle.max()) + 1
    return {(s, r) for s, r in pairs if r < particles}


def brute_force_radius(position, batch, radius, box_length=None):
    """Pairs (sender, receiver) of one example at squared distance < R^2 (minimum image where given)."""
    p = position.double().numpy()
    diff = p[:, None] - p[None]
    if box_length is not None:
        diff = diff - box_length * np.floor(diff / box_length + 0.5)
    close = (diff**2).sum(-1) < radius**2
    close &= batch.numpy()[:, None] == batch.numpy()[None]
    receivers, senders = np.nonzero(close)
    return set(zip(senders.tolist(), receivers.tolist(), strict=True))


scenes = st.tuples(
    st.integers(2, 3),
    st.lists(st.integers(1, 40), min_size=1, max_size=3),
    st.integers(0, 2**31 - 1),
    st.sampled_from([0.5, 1.0, 3.0]),
)
"""(dim, particles per example, seed, spread of the positions)."""


def random_positions(dim, counts, seed, spread):
    generator = torch.Generator().manual_seed(seed)
    position = torch.rand(sum(counts), dim, generator=generator, dtype=torch.float64) * spread
    batch = torch.repeat_interleave(torch.arange(len(counts)), torch.tensor(counts))
    return position, batch
