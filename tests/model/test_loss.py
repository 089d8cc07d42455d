"""The training loss: squared error over dimensions, summed or averaged over the predicted particles only."""

from __future__ import annotations

import torch

from gns_framework.model.loss import masked_acceleration_loss, masked_squared_error_sum


def test_kinematic_particles_contribute_nothing_and_the_mean_is_over_predicted_ones():
    prediction = torch.tensor([[1.0, 2.0], [0.0, 0.0], [3.0, -1.0]])
    target = torch.tensor([[0.0, 0.0], [100.0, 100.0], [1.0, 1.0]])
    predicted = torch.tensor([True, False, True])
    # (1 + 4) + (4 + 4): the second particle's huge error is prescribed motion, not the model's.
    assert masked_squared_error_sum(prediction, target, predicted).item() == 13.0
    assert masked_acceleration_loss(prediction, target, predicted).item() == 6.5


def test_no_predicted_particle_is_a_zero_loss_not_a_division_by_zero():
    prediction, target = torch.ones(3, 2), torch.zeros(3, 2)
    none = torch.zeros(3, dtype=torch.bool)
    assert masked_acceleration_loss(prediction, target, none).item() == 0.0


def test_the_gradient_reaches_predicted_particles_only():
    prediction = torch.tensor([[1.0, 2.0], [5.0, 5.0]], requires_grad=True)
    masked_acceleration_loss(prediction, torch.zeros(2, 2), torch.tensor([True, False])).backward()
    assert torch.equal(prediction.grad, torch.tensor([[2.0, 4.0], [0.0, 0.0]]))
