"""The graph-builder contract: build is required; the builder keeps its params and setup; its defaults."""

from __future__ import annotations

import pytest
import torch

from gns_framework.contracts import Graph, GraphBuilder, ModelSetup, Params

SETUP = ModelSetup(dim=2, bounds=((0.0, 1.0), (0.0, 1.0)), connectivity_radius=0.5, particle_types=(5,))


def test_a_builder_without_build_cannot_be_built():
    class NoBuild(GraphBuilder):
        name = "no_build"

    with pytest.raises(TypeError, match="abstract method build"):
        NoBuild(Params(), SETUP)


class AllPairs(GraphBuilder):
    """Connects every ordered pair of distinct particles of the same example within the radius."""

    name = "all_pairs"

    def build(self, position, batch, num_examples):
        receivers, senders = torch.nonzero(
            (batch[:, None] == batch[None]) & ~torch.eye(len(batch), dtype=torch.bool), as_tuple=True
        )
        displacement = position[senders] - position[receivers]
        close = displacement.norm(dim=1) < self.scene.connectivity_radius
        return Graph(senders[close], receivers[close], displacement[close], len(position), batch=batch)


def test_a_builder_keeps_its_params_and_the_setup_it_connects_for():
    builder = AllPairs(Params(), SETUP)
    assert builder.params == Params() and builder.scene is SETUP
    position = torch.tensor([[0.0, 0.0], [0.3, 0.0], [0.0, 0.9], [0.1, 0.0]])
    graph = builder.build(position, torch.tensor([0, 0, 0, 1]), 2)
    # 0 and 1 are 0.3 apart (connected both ways); 2 is too far; 3 is another example.
    assert sorted(zip(graph.senders.tolist(), graph.receivers.tolist(), strict=True)) == [(0, 1), (1, 0)]


def test_by_default_a_builder_is_not_periodic_and_needs_no_optional_module():
    assert AllPairs.supports_periodic is False and AllPairs.optional_modules == ()


def test_by_default_a_builder_does_not_promise_edges_within_the_radius_alone():
    """A domain decomposition refuses a builder that does not declare it (decomposition/halo.py)."""
    assert AllPairs.joins_within_radius is False
