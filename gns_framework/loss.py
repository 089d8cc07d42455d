"""Training loss: squared error of normalised accelerations, averaged over predicted particles."""

from __future__ import annotations

import torch
from torch import Tensor


def masked_acceleration_loss(prediction: Tensor, target: Tensor, predicted_mask: Tensor) -> Tensor:
    """Sum over dimensions of the squared error, averaged over particles with ``predicted_mask``.

    Kinematic particles (mask False) have prescribed motion and contribute nothing.

    Shapes: prediction, target (N, d); predicted_mask (N,) bool -> scalar.
    """
    loss = ((prediction - target) ** 2).sum(dim=-1)
    loss = torch.where(predicted_mask, loss, torch.zeros_like(loss))
    return loss.sum() / predicted_mask.sum().clamp(min=1)
