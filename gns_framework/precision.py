"""Precision of the learned simulator's matrix products: float32, or bfloat16 under autocast.

In ``bfloat16`` the Linear layers (and the interaction network's chunked edge
products) run in bfloat16 with float32 accumulation; LayerNorm, residuals,
aggregation, the loss, the optimiser and the integrator stay in float32. CPUs with
AMX or AVX512-BF16 and GPUs with bfloat16 tensor cores run the products several
times faster; the error this adds is measured in docs/performance.md.
"""

from __future__ import annotations

import contextlib
from typing import TYPE_CHECKING, Literal, get_args

if TYPE_CHECKING:
    import torch

Precision = Literal["float32", "bfloat16"]
"""The choices of the recipe's ``training.precision`` and of ``gns rollout --precision``."""
PRECISIONS: tuple[str, ...] = get_args(Precision)


def autocast(precision: Precision, device: torch.device | str) -> contextlib.AbstractContextManager:
    """The context in which the model's products run in ``precision`` (float32: autocast off)."""
    import torch  # here: naming the choices (recipes, CLI help) needs no torch

    device_type = torch.device(device).type
    return torch.autocast(device_type, dtype=torch.bfloat16, enabled=precision == "bfloat16")
