"""Adam with the reference's exponential learning-rate decay and floor."""

from __future__ import annotations

import torch

from ..recipe import OptimizerSpec


def exponential_decay(spec: OptimizerSpec):
    """``lr(step) = lr_min + (lr_init - lr_min) * lr_decay ** (step / lr_decay_steps)``, as a LambdaLR factor."""

    def factor(step: int) -> float:
        lr = spec.lr_min + (spec.lr_init - spec.lr_min) * spec.lr_decay ** (step / spec.lr_decay_steps)
        return lr / spec.lr_init

    return factor


def make_optimizer(parameters, spec: OptimizerSpec) -> tuple[torch.optim.Optimizer, torch.optim.lr_scheduler.LambdaLR]:
    optimizer = torch.optim.Adam(parameters, lr=spec.lr_init)
    return optimizer, torch.optim.lr_scheduler.LambdaLR(optimizer, exponential_decay(spec))
