"""Normalisation statistics, with the standard deviation combined with the training noise."""

from __future__ import annotations

import torch
from torch import Tensor, nn


def noise_combined_std(std: list[float], noise_std: float) -> Tensor:
    """``sqrt(std^2 + noise_std^2)`` in float32, with the reference's exact operations.

    The model sees noisy inputs during training, so their spread is the data's plus
    the noise's; the same std is used at inference.
    """
    return torch.sqrt(torch.tensor(std, dtype=torch.float32) ** 2 + noise_std**2)


class Stats(nn.Module):
    """Mean and (noise-combined) std of one quantity, per component, as buffers.

    Shapes: mean, std (k,). ``normalize``/``denormalize`` broadcast over leading dims.
    A zero std (a constant quantity) is replaced by 1 so normalising never divides by 0.
    """

    mean: Tensor  # buffers (register_buffer)
    std: Tensor

    def __init__(self, mean: list[float], std: list[float], noise_std: float = 0.0):
        super().__init__()
        combined = noise_combined_std(std, noise_std)
        self.register_buffer("mean", torch.tensor(mean, dtype=torch.float32))
        self.register_buffer("std", torch.where(combined > 0, combined, torch.ones_like(combined)))

    def normalize(self, x: Tensor) -> Tensor:
        return (x - self.mean) / self.std

    def denormalize(self, x: Tensor) -> Tensor:
        return x * self.std + self.mean
