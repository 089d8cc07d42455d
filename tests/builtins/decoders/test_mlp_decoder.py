"""The MLP decoder: Linear, ReLU, ..., Linear from the node latent to the prediction, with no LayerNorm."""

from __future__ import annotations

import torch
from torch import nn

from gns_builtins.decoders.mlp import MLPDecoder
from gns_framework.contracts import ModelSizes
from gns_framework.plugins import load_registry


def sizes(latent=2, hidden=2, hidden_layers=1, output=2) -> ModelSizes:
    return ModelSizes(
        node_in=5, edge_in=3, latent=latent, mlp_hidden=hidden, mlp_hidden_layers=hidden_layers, output=output, dim=2
    )


def test_it_is_the_registered_mlp_decoder():
    assert load_registry().get("decoder", "mlp") is MLPDecoder


def test_by_hand_the_output_is_neither_clipped_nor_normalised():
    decoder = MLPDecoder(MLPDecoder.Params(), sizes())
    first, last = decoder.mlp.linears
    with torch.no_grad():
        first.weight.copy_(torch.eye(2))
        first.bias.copy_(torch.tensor([0.0, -1.0]))
        last.weight.copy_(torch.tensor([[1.0, 1.0], [1.0, -1.0]]))
        last.bias.zero_()
    # [3, 0.5] -> hidden [3, -0.5] -> ReLU [3, 0] -> [3, 3]: a LayerNorm would have made it [0, 0].
    # [0, 2] -> hidden [0, 1] -> [1, -1]: a ReLU after the last layer would have made it [1, 0].
    out = decoder(torch.tensor([[3.0, 0.5], [0.0, 2.0]]))
    assert out.tolist() == [[3.0, 3.0], [1.0, -1.0]]


def test_its_layers_follow_the_sizes():
    decoder = MLPDecoder(MLPDecoder.Params(), sizes(latent=16, hidden=8, hidden_layers=3, output=3))
    shapes = [tuple(linear.weight.shape) for linear in decoder.mlp.linears]
    assert shapes == [(8, 16), (8, 8), (8, 8), (3, 8)]
    assert not any(isinstance(module, nn.LayerNorm) for module in decoder.modules())
    assert decoder(torch.zeros(5, 16)).shape == (5, 3)


def test_it_is_the_composition_of_its_layers():
    torch.manual_seed(0)
    decoder = MLPDecoder(MLPDecoder.Params(), sizes(latent=6, hidden=5, hidden_layers=2, output=3))
    x = torch.randn(7, 6)
    a, b, c = decoder.mlp.linears
    expected = c(torch.relu(b(torch.relu(a(x)))))
    torch.testing.assert_close(decoder(x), expected, rtol=0, atol=0)
