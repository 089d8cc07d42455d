"""The encoder contract: a learned part that must define forward(node_features, edge_features)."""

from __future__ import annotations

import pytest
import torch

from gns_framework.contracts import Encoder, LearnedPart, ModelSizes, Params

SIZES = ModelSizes(node_in=5, edge_in=3, latent=4, mlp_hidden=4, mlp_hidden_layers=1, output=2, dim=2)


def test_an_encoder_without_forward_cannot_be_built():
    class NoForward(Encoder):
        name = "no_forward"

    with pytest.raises(TypeError, match="abstract method forward"):
        NoForward(Params(), SIZES)


def test_an_encoder_with_forward_is_a_learned_part_called_as_a_module():
    class Widen(Encoder):
        """Pads node features and edge features to the latent size with zeros."""

        name = "widen"

        def forward(self, node_features, edge_features):
            pad = lambda t: torch.nn.functional.pad(t, (0, SIZES.latent - t.shape[1]))  # noqa: E731
            return pad(node_features[:, : SIZES.latent]), pad(edge_features)

    encoder = Widen(Params(), SIZES)
    assert isinstance(encoder, LearnedPart) and encoder.params == Params()
    nodes, edges = encoder(torch.ones(6, SIZES.node_in), torch.ones(9, SIZES.edge_in))
    assert nodes.shape == (6, SIZES.latent) and edges.shape == (9, SIZES.latent)
    assert edges[:, SIZES.edge_in :].abs().sum() == 0
