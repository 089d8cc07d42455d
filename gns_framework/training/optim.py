"""Adam with the reference's exponential learning-rate decay, or a cosine schedule fitted to the step budget."""

from __future__ import annotations

import math

import torch

from ..config.recipe import OptimizerSpec
from ..runtime.host_sync import avoids_read_backs


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
    parameters, spec: OptimizerSpec, total_steps: int
) -> tuple[torch.optim.Optimizer, torch.optim.lr_scheduler.LambdaLR]:
    """Adam and its schedule as a LambdaLR factor of ``lr_init``; ``total_steps`` is the run's step budget.

    On accelerators Adam is torch's fused one (:func:`fused_adam`): one kernel per step for every
    parameter instead of a dozen per parameter, and no host read of the step count.
    """
    parameters = list(parameters)
    optimizer = torch.optim.Adam(parameters, lr=spec.lr_init, fused=fused_adam(parameters) or None)
    return optimizer, torch.optim.lr_scheduler.LambdaLR(
        optimizer, lambda step: learning_rate(spec, step, total_steps) / spec.lr_init
    )


def fused_adam(parameters: list) -> bool:
    """Whether Adam runs fused: all parameters (or parameter groups' ``params``) on an accelerator.

    On the CPU the per-parameter loop stays: it is the reference path, bit for bit as before.
    """
    tensors = [t for p in parameters for t in (p["params"] if isinstance(p, dict) else [p])]
    return bool(tensors) and all(avoids_read_backs(t.device) for t in tensors)
