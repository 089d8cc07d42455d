"""The plugin API's MLP: its layout, and that the built-in models are made of it alone."""

from __future__ import annotations

import pytest
import torch
from torch import nn

from gns_framework.layers import MLP, NormedMLP
from gns_framework.testing import small_sizes


def test_mlp_has_its_hidden_layers_and_no_activation_after_the_last():
    mlp = MLP(5, 8, 2, 3)
    assert [(linear.in_features, linear.out_features) for linear in mlp.linears] == [(5, 8), (8, 8), (8, 3)]
    x = torch.randn(40, 5, generator=torch.Generator().manual_seed(0))
    out = mlp(x)
    assert out.shape == (40, 3) and bool((out < 0).any())  # a final ReLU would clip these
    expected = mlp.linears[2](torch.relu(mlp.linears[1](torch.relu(mlp.linears[0](x)))))
    assert torch.equal(out, expected)
    assert torch.equal(mlp.rest(mlp.linears[0](x)), out)


def test_mlp_without_hidden_layers_is_one_linear():
    mlp = MLP(4, 16, 0, 2)
    assert len(mlp.linears) == 1 and mlp.linears[0].in_features == 4 and mlp.linears[0].out_features == 2


def test_normed_mlp_normalises_each_row_over_its_outputs():
    block = NormedMLP(6, 8, 1, 4)
    x = torch.randn(2, 7, 6, generator=torch.Generator().manual_seed(1))
    out = block(x)
    assert out.shape == (2, 7, 4)  # leading dimensions pass through
    assert torch.allclose(out.mean(-1), torch.zeros(2, 7), atol=1e-5)
    before = block.mlp(x).var(-1, unbiased=False)  # LayerNorm scales it to 1, short by its eps
    assert torch.allclose(out.var(-1, unbiased=False), before / (before + block.norm.eps), atol=1e-5)
    assert list(dict(block.named_parameters())) == [
        "mlp.linears.0.weight",
        "mlp.linears.0.bias",
        "mlp.linears.1.weight",
        "mlp.linears.1.bias",
        "norm.weight",
        "norm.bias",
    ]  # the names checkpoints store


@pytest.mark.parametrize(
    "kind, name",
    [
        ("encoder", "mlp"),
        ("processor", "interaction_network"),
        ("processor", "shared_interaction_network"),
        ("processor", "egnn"),
        ("decoder", "mlp"),
    ],
)
def test_every_linear_layer_of_the_builtins_is_in_the_shared_mlp(kind, name, registry):
    """One MLP builder: a built-in that grew its own copy fails here. (graph_attention's GATv2 layers are PyG's.)"""
    cls = registry.get(kind, name)
    component = cls(cls.Params(), small_sizes())
    in_mlps = {id(linear) for module in component.modules() if isinstance(module, MLP) for linear in module.linears}
    linears = [name for name, module in component.named_modules() if isinstance(module, nn.Linear)]
    assert linears, f"{kind} {name} has no Linear layer"
    assert [
        name
        for name, module in component.named_modules()
        if isinstance(module, nn.Linear) and id(module) not in in_mlps
    ] == []
