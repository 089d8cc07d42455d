"""Chunking, product dtype and hidden layers of an MLP + LayerNorm run on cache-sized chunks of rows.

Done on whole (E, H) tensors, every elementwise operation of the edge MLP streams
the activations through main memory, as long in all as the matrix products. The
chunked edge block (``edge_block.py``) instead takes each chunk of edges
through every layer while it sits in cache, with a hand-written backward; these are
its generic parts: chunking, the dtype of the products under autocast, and the
layers after the first, forward and backward. (The edge encoder, tried the same
way, gained nothing: its whole-tensor MLP is as fast; docs/performance.md.)
"""

from __future__ import annotations

from collections.abc import Iterator

import torch
from torch import Tensor

from . import fused_kernels

IMPLEMENTS = "processors/interaction_network.py: InteractionStep with edge_block: plain"  # see reading_cost.py

ROWS_PER_THREAD = 1024
"""Rows per chunk and intra-op thread on CPU: each thread's share of a 128-wide chunk
activation is 512 KiB, so its working set stays in its core's L2. Chunks grow with the
threads because every operation on a chunk pays a fork/join and ~5 us of Python."""

ROWS_PER_CHUNK_ACCELERATOR = 1 << 18
"""Rows per chunk on GPUs, where every operation is a kernel launch: chunks only bound the temporaries."""


def chunk_size(device: torch.device) -> int:
    return ROWS_PER_THREAD * torch.get_num_threads() if device.type == "cpu" else ROWS_PER_CHUNK_ACCELERATOR


def chunks(num_rows: int, size: int) -> Iterator[tuple[int, int]]:
    """``(first, end)`` row ranges of at most ``size`` rows."""
    return ((lo, min(lo + size, num_rows)) for lo in range(0, num_rows, size))


def widest_dtype(*tensors: Tensor) -> torch.dtype:
    """The dtype sums, LayerNorm and gradients are kept in: the widest of ``tensors``."""
    dtype = tensors[0].dtype
    for t in tensors[1:]:
        dtype = torch.promote_types(dtype, t.dtype)
    return dtype


def product_dtype(dtype: torch.dtype, device_type: str) -> torch.dtype:
    """The dtype of the matrix products: autocast's when it is on for this device, else ``dtype``.

    Under autocast to bfloat16 or float16 the products run in that dtype, as autocast
    would run the unchunked MLP's Linears; LayerNorm, residuals, aggregates and every
    gradient sum stay in ``dtype``.
    """
    return torch.get_autocast_dtype(device_type) if torch.is_autocast_enabled(device_type) else dtype


def for_products(dtype: torch.dtype, tensors) -> list[Tensor]:
    """``tensors`` cast to the products' dtype, contiguous (once per call; a no-op in full precision)."""
    return [t.to(dtype).contiguous() for t in tensors]


def hidden_forward(a: Tensor, weights, biases) -> tuple[list[Tensor], Tensor]:
    """ReLU and the layers after the first, on the first layer's output ``a`` (modified in place).

    Returns the post-ReLU input of each of those layers (kept for the backward) and the
    last layer's product *without* its bias, ``biases[-1]``: the caller adds it in its
    next pass over the chunk. ``weights`` and ``biases`` are in ``a``'s dtype.
    """
    inputs = []
    for j, weight in enumerate(weights):
        z = bias_relu_(a, biases[j - 1] if j > 0 else None)
        inputs.append(z)
        a = torch.mm(z, weight.t())
    return inputs, a


def bias_relu_(a: Tensor, bias: Tensor | None) -> Tensor:
    """``a = relu(a + bias)`` in place (``relu(a)`` when ``bias`` is None); one pass on float32 CPU tensors."""
    if bias is None:
        return a.relu_()
    if fused_kernels.applies(a, bias):
        return fused_kernels.bias_relu_(a, bias)
    return a.add_(bias).relu_()


def hidden_backward(grad: Tensor, inputs, weights, grad_weights, grad_biases, dtypes) -> Tensor:
    """Back from the gradient at the last layer's output to the first layer's output.

    ``dtypes`` is (the products' dtype, the sums' dtype). Accumulates into
    ``grad_weights`` and ``grad_biases`` (of the layers after the first, in the sums'
    dtype), except the last layer's bias gradient, the column sum of ``grad``, which
    the caller adds (the edge block does it in its LayerNorm backward). Returns the
    gradient at the first layer's output in the products' dtype.
    """
    products, _ = dtypes
    for j in range(len(weights) - 1, -1, -1):
        z = inputs[j]
        grad = grad.to(products)
        add_product(grad_weights[j], grad.t(), z)
        grad = relu_backward(grad @ weights[j], z, grad_biases[j - 1] if j > 0 else None)
    return grad.to(products)


def relu_backward(grad: Tensor, z: Tensor, grad_bias: Tensor | None) -> Tensor:
    """``grad`` (the gradient at ``z = relu(a)``) taken back to ``a``; its column sum added into ``grad_bias``.

    May overwrite ``grad``. One fused pass on float32 CPU tensors (fused_kernels.py).
    """
    if fused_kernels.applies(grad, z, grad_bias):
        return fused_kernels.relu_backward_(grad, z, grad_bias)
    grad = torch.ops.aten.threshold_backward(grad, z, 0)
    if grad_bias is not None:
        grad_bias += grad.sum(0, dtype=grad_bias.dtype)
    return grad


def add_product(total: Tensor, a: Tensor, b: Tensor) -> None:
    """``total += a @ b``, with the product in the operands' dtype and the sum in ``total``'s."""
    if a.dtype == total.dtype:
        total.addmm_(a, b)
    else:
        total += a @ b


def product_into(out: Tensor, a: Tensor, b: Tensor) -> None:
    """``out = a @ b``, with the product in the operands' dtype and the result in ``out``'s."""
    if a.dtype == out.dtype:
        torch.mm(a, b, out=out)
    else:
        out.copy_(a @ b)
