"""Adam with the reference's exponential learning-rate decay, or a cosine schedule fitted to the step budget."""

from __future__ import annotations

import math

import torch

from ..config.recipe import OptimizerSpec


def learning_rate(spec: OptimizerSpec, step: int, total_steps: int) -> float:
    """The learning rate of optimiser step ``step`` (0-based) of a ``total_steps`` run.

    Warm-up ramps linearly to ``lr_init``: Adam's first steps take full-size moves whatever the
    gradient scale, which a fresh network with LayerNorm turns into large jumps. The exponential
    schedule then decays as the reference's; the cosine one reaches ``lr_min`` at ``anneal_fraction
    * total_steps`` and holds it, so a short run ends with small steps, not at a high learning rate.
    """
    if step < spec.warmup_steps:
        return spec.lr_init * (step + 1) / spec.warmup_steps
    if spec.schedule == "exponential":
        return spec.lr_min + (spec.lr_init - spec.lr_min) * spec.lr_decay ** (step / spec.lr_decay_steps)
    span = max(round(spec.anneal_fraction * total_steps) - spec.warmup_steps, 1)
    progress = min((step - spec.warmup_steps) / span, 1.0)
    return spec.lr_min + (spec.lr_init - spec.lr_min) * 0.5 * (1.0 + math.cos(math.pi * progress))


def make_optimizer(
    parameters, spec: OptimizerSpec, total_steps: int, fused: bool | None = None
) -> tuple[torch.optim.Optimizer, torch.optim.lr_scheduler.LambdaLR]:
    """Adam (fused by default on accelerators: one kernel, no step read) and its schedule as a LambdaLR factor."""
    parameters = list(parameters)
    fused = fused if fused is not None else all(p.device.type != "cpu" for p in parameters) and bool(parameters)
    optimizer = torch.optim.Adam(parameters, lr=spec.lr_init, fused=fused or None)
    return optimizer, torch.optim.lr_scheduler.LambdaLR(
        optimizer, lambda step: learning_rate(spec, step, total_steps) / spec.lr_init
    )
