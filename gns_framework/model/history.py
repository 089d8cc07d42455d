"""The position history a model reads, and how it moves on by one frame.

A learned simulator sees the last C positions of every particle (C = ``history``:
C - 1 velocities by finite differences). After each step the oldest frame falls
out of the window and the newly predicted one enters at the end, so rollouts,
push-forward training and inverse problems all advance the same window the same way.
"""

from __future__ import annotations

import torch
from torch import Tensor


def advance_window(position_sequence: Tensor, next_position: Tensor) -> Tensor:
    """The window one frame on: drop the oldest frame, append ``next_position``.

    Shapes: position_sequence (N, C, d), next_position (N, d) -> (N, C, d).
    """
    return torch.cat([position_sequence[:, 1:], next_position[:, None]], dim=1)
