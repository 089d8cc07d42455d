"""gns_framework.training.clipping: every update sees gradients of global norm at most the bound, and gradients
below it are left as they are."""

from __future__ import annotations

import pytest
import torch

from gns_framework.config.recipe import OptimizerSpec
from gns_framework.training.clipping import clip_before_each_update


def sgd_step(gradients: list[torch.Tensor], max_norm: float | None) -> list[torch.Tensor]:
    """The moves of plain SGD (lr 1: a move is minus the gradient it used) with these gradients."""
    parameters = [torch.zeros_like(g, requires_grad=True) for g in gradients]
    optimizer = torch.optim.SGD(parameters, lr=1.0)
    if max_norm is not None:
        clip_before_each_update(optimizer, max_norm)
    for p, g in zip(parameters, gradients, strict=True):
        p.grad = g.clone()
    optimizer.step()
    return [-p.detach() for p in parameters]


def test_a_large_gradient_is_scaled_down_to_the_bound_across_all_parameters():
    gradients = [torch.tensor([3.0, 0.0]), torch.tensor([[4.0]])]  # global norm 5
    moves = sgd_step(gradients, max_norm=1.0)
    torch.testing.assert_close(moves[0], torch.tensor([0.6, 0.0]), rtol=1e-5, atol=0)
    torch.testing.assert_close(moves[1], torch.tensor([[0.8]]), rtol=1e-5, atol=0)
    assert torch.linalg.vector_norm(torch.cat([m.flatten() for m in moves])) == pytest.approx(1.0, rel=1e-5)


def test_a_gradient_within_the_bound_is_left_as_it_is():
    gradients = [torch.tensor([0.3, -0.4])]  # norm 0.5
    assert torch.equal(sgd_step(gradients, max_norm=1.0)[0], gradients[0])
    assert torch.equal(sgd_step(gradients, max_norm=None)[0], gradients[0])


def test_the_recipe_field_is_optional_and_positive():
    assert OptimizerSpec().clip_grad_norm is None
    assert OptimizerSpec(clip_grad_norm=2.5).clip_grad_norm == 2.5
    with pytest.raises(ValueError, match="clip_grad_norm"):
        OptimizerSpec(clip_grad_norm=0.0)
