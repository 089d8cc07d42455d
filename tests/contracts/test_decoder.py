"""The decoder contract: a learned part that must define forward(node_latent)."""

from __future__ import annotations

import pytest
import torch

from gns_framework.contracts import Decoder, LearnedPart, ModelSizes, Params

SIZES = ModelSizes(node_in=5, edge_in=3, latent=4, mlp_hidden=4, mlp_hidden_layers=1, output=2, dim=2)


def test_a_decoder_without_forward_cannot_be_built():
    class NoForward(Decoder):
        name = "no_forward"

    with pytest.raises(TypeError, match="abstract method forward"):
        NoForward(Params(), SIZES)


def test_a_decoder_with_forward_maps_latents_to_the_output_size():
    class Linear(Decoder):
        name = "linear"

        def __init__(self, params, sizes):
            super().__init__(params, sizes)
            self.layer = torch.nn.Linear(sizes.latent, sizes.output)

        def forward(self, node_latent):
            return self.layer(node_latent)

    decoder = Linear(Params(), SIZES)
    assert isinstance(decoder, LearnedPart) and len(list(decoder.parameters())) == 2
    assert decoder(torch.zeros(6, SIZES.latent)).shape == (6, SIZES.output)
