"""The learned-part base (contracts.LearnedPart): a torch module that keeps its recipe parameters."""

from __future__ import annotations

import pytest
import torch
from pydantic import ValidationError
from torch import nn

from gns_framework.contracts import ComponentParams, LearnedPart, ModelSizes

SIZES = ModelSizes(node_in=7, edge_in=3, latent=8, mlp_hidden=8, mlp_hidden_layers=1, output=2, dim=2)


class Scaled(LearnedPart):
    """A learned part with one parameter of its own and one layer sized by the model's sizes."""

    name = "scaled"

    class Params(ComponentParams):
        gain: float = 2.0

    def __init__(self, params, sizes):
        super().__init__(params, sizes)
        self.layer = nn.Linear(sizes.latent, sizes.output)

    def forward(self, x):
        return self.params.gain * self.layer(x)


def test_a_learned_part_is_a_torch_module_that_keeps_its_params():
    part = Scaled(Scaled.Params(gain=3.0), SIZES)
    assert isinstance(part, nn.Module) and part.params.gain == 3.0
    # super().__init__ ran nn.Module's own __init__, so the layer built after it is registered.
    assert set(part.state_dict()) == {"layer.weight", "layer.bias"}
    x = torch.ones(4, SIZES.latent)
    torch.testing.assert_close(part(x), 3.0 * part.layer(x))


def test_the_default_params_accept_nothing_unknown():
    # A part that declares no Params takes none: any key in its recipe section is a typo.
    assert LearnedPart.Params().model_dump() == {}
    with pytest.raises(ValidationError, match="Extra inputs are not permitted"):
        LearnedPart.Params.model_validate({"latent": 3})


def test_a_parts_own_params_are_strict_too():
    with pytest.raises(ValidationError, match="gian"):
        Scaled.Params.model_validate({"gian": 1.0})
