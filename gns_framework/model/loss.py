"""Training loss: squared error of normalised accelerations, averaged over predicted particles."""

from __future__ import annotations

import torch
from torch import Tensor


def masked_squared_error_sum(prediction: Tensor, target: Tensor, predicted_mask: Tensor) -> Tensor:
    """Squared error summed over dimensions and over the particles with ``predicted_mask``.

    Kinematic particles (mask False) have prescribed motion and contribute nothing.

    Shapes: prediction, target (N, d); predicted_mask (N,) bool -> scalar.
    """
    error = ((prediction - target) ** 2).sum(dim=-1)
    return torch.where(predicted_mask, error, torch.zeros_like(error)).sum()


def masked_acceleration_loss(prediction: Tensor, target: Tensor, predicted_mask: Tensor) -> Tensor:
    """Sum over dimensions of the squared error, averaged over particles with ``predicted_mask``.

    Shapes: prediction, target (N, d); predicted_mask (N,) bool -> scalar.
    """
    return masked_squared_error_sum(prediction, target, predicted_mask) / predicted_mask.sum().clamp(min=1)
