"""Precision of the learned simulator's matrix products: float32, TF32, or bfloat16 under autocast.

In ``tf32`` every tensor stays float32 and, on CUDA, float32 matrix products run on the tensor cores in TF32 (10-bit
mantissa inputs, float32 accumulation): several times faster on Ampere and later GPUs. On the CPU ``tf32`` is
``float32``.

In ``bfloat16`` the Linear layers (and the interaction network's chunked edge products) run in bfloat16 with float32
accumulation; LayerNorm, residuals, aggregation, the loss, the optimiser and the integrator stay in float32. CPUs
with AMX or AVX512-BF16 and GPUs with bfloat16 tensor cores run the products several times faster; the error this
adds is measured in docs/performance.md.
"""

from __future__ import annotations

import contextlib
from typing import TYPE_CHECKING, Literal, get_args

if TYPE_CHECKING:
    import torch

Precision = Literal["float32", "tf32", "bfloat16"]
"""The choices of the recipe's ``training.precision`` and of ``gns rollout --precision``."""
PRECISIONS: tuple[str, ...] = get_args(Precision)


def autocast(precision: Precision, device: torch.device | str) -> contextlib.AbstractContextManager:
    """The context in which the model's products run in ``precision`` (float32: autocast off)."""
    import torch  # here: naming the choices (recipes, CLI help) needs no torch

    from .device import is_cuda
    from .tf32 import cuda_tf32

    if precision == "tf32" and is_cuda(device):
        return cuda_tf32()
    return torch.autocast(torch.device(device).type, dtype=torch.bfloat16, enabled=precision == "bfloat16")


def backward_precision(precision: Precision, device: torch.device | str) -> contextlib.AbstractContextManager:
    """The context for ``loss.backward()``: TF32 products for ``tf32`` on CUDA, else nothing.

    Autocast is not entered for the backward (its ops follow the forward's dtypes);
    TF32 is a process setting, so the backward's float32 products need it again.
    """
    from .device import is_cuda
    from .tf32 import cuda_tf32

    return cuda_tf32() if precision == "tf32" and is_cuda(device) else contextlib.nullcontext()
