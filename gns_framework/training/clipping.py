"""Gradient clipping before each update (``training.optimizer.clip_grad_norm``).

A loss through many unrolled learned steps (``training.unrolled_loss_steps``) jumps by an order of magnitude from one
batch to the next: a window whose rollout drifts far gives a gradient that would pull the weights far in one
update. Scaling the gradients down to a global L2 norm bounds any one update's move whatever the batch, and leaves
the gradients below that norm as they are.
"""

from __future__ import annotations

import torch


def clip_before_each_update(optimizer: torch.optim.Optimizer, max_norm: float) -> None:
    """Scale ``optimizer``'s gradients to a global L2 norm of at most ``max_norm`` before every ``step()``.

    Runs as the optimizer's step pre-hook, so it sees the gradients every rank's backward averaged (DDP) and
    a captured step's update clips as the eager one does.
    """
    parameters = [p for group in optimizer.param_groups for p in group["params"]]

    def clip(*_) -> None:
        torch.nn.utils.clip_grad_norm_(parameters, max_norm, foreach=True)

    optimizer.register_step_pre_hook(clip)
