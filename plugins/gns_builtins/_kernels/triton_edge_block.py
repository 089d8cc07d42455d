"""The interaction network's edge block as Triton kernels: one pass over the edges per message-passing step.

The same update as ``edge_block.py`` (and as the paper's three lines), for edges k
between receiver r(k) and sender s(k), with the node table ``T = [x W_r^T + b_1; x W_s^T]``::

    a_1 = e_k W_e^T + T[r(k)] + T[N + s(k)]
    h_1 = relu(a_1),  h_2 = relu(h_1 W_2^T + b_2)            (the middle layer, when there is one)
    u_k = LayerNorm(h_2 W_3^T + b_3)
    e'_k = e_k + u_k,  aggregate_i = sum of u_k over the edges received by i

Forward: one program per block of ``BLOCK_NODES`` receivers walks their edges
(contiguous, since builders sort edges by receiver) in tiles of ``BLOCK_EDGES``;
each tile goes through gathers, the three products with bias and ReLU, LayerNorm
and residual in registers, and is summed into the block's receivers by a
one-hot product (a segmented sum in a fixed order, exact in float32). A program
owns its receivers: no atomics, the same bits every run, and only ``e`` read and
``e'`` and the aggregate written: about 1 KB per edge in float32 where the
chunked path moves tens.

Backward (training): one program per tile of edges recomputes the tile's
activations from ``e``, the node table and the weights (FlashAttention's trade:
nothing but the edge latents is kept between forward and backward), writes the
gradient at ``e`` and the per-edge gradients the weight products need; the
weight gradients are then cuBLAS products over all edges, and the node table's
gradient is two segmented sums over the graph's orders (:mod:`.edge_order`), in a
fixed order.

Products run in the weights' dtype (bfloat16 under autocast) with float32
accumulation; ``precision="ieee"`` keeps float32 products exact to the torch path
(within 1e-5), ``"tf32"`` lets float32 products use tensor cores. Triton also runs
these kernels on the CPU under ``TRITON_INTERPRET=1``, which is how CI tests them.
"""

from __future__ import annotations

import os
from functools import cache

import torch
from torch import Tensor

from .chunked import for_products
from .edge_order import EdgeOrder

IMPLEMENTS = "processors/interaction_network.py: InteractionStep with edge_block: plain"  # see reading_cost.py

BLOCK_NODES = 16
"""Receivers per forward program: the one-hot sum's rows (tl.dot needs at least 16)."""

BLOCK_EDGES = 64
"""Edges per tile: rows of every product."""


@cache
def triton_module():
    """:mod:`.triton_kernels`, or None where Triton is not installed."""
    try:
        from . import triton_kernels
    except ImportError:
        return None
    return triton_kernels


def interpreted() -> bool:
    """Whether Triton runs kernels on the CPU (``TRITON_INTERPRET=1``, how the tests run them)."""
    return os.environ.get("TRITON_INTERPRET") == "1"


def applies(e: Tensor, hidden: int, num_weights: int) -> bool:
    """Whether the kernels take this edge block: Triton present, widths powers of two >= 16, one or two
    hidden layers (the paper's MLP has two), and on CUDA unless ``GNS_TRITON=0``, or on the CPU under
    Triton's interpreter where ``GNS_TRITON=interpret`` asks for it (the tests)."""
    choice = os.environ.get("GNS_TRITON", "")
    if choice == "0" or num_weights not in (2, 3):
        return False
    if not (e.device.type == "cuda" or (e.device.type == "cpu" and choice == "interpret" and interpreted())):
        return False
    if not all(n >= 16 and n & (n - 1) == 0 for n in (e.shape[1], hidden)):
        return False
    return triton_module() is not None


def _middle(weights: list[Tensor], biases: list[Tensor]) -> tuple[Tensor, Tensor, bool]:
    """The middle layer's weight and bias, or stand-ins (never read) when the MLP has none."""
    if len(weights) == 3:
        return weights[1], biases[0], True
    return weights[-1], biases[-1], False


def _precision(products: torch.dtype, allow_tf32: bool) -> str:
    return "tf32" if allow_tf32 and products == torch.float32 and not interpreted() else "ieee"


def _upcast(products: torch.dtype) -> bool:
    """Whether the kernels take low-precision operands to float32 for their products (the interpreter)."""
    return interpreted() and products != torch.float32


def forward(e, table, rows, order: EdgeOrder, weights, biases, gamma, beta, eps, allow_tf32=False):
    """``(e + u, aggregate of u at receivers)``; arguments as :func:`triton_edge_block`, weights in the products'
    dtype."""
    kernels = triton_module()
    num_nodes = table.shape[0] // 2
    latent, hidden = e.shape[1], table.shape[1]
    middle_weight, middle_bias, has_middle = _middle(weights, biases)
    out = torch.empty_like(e)
    aggregate = torch.empty(num_nodes, latent, dtype=e.dtype, device=e.device)
    if num_nodes == 0:
        return out, aggregate
    kernels.forward_kernel[(-(-num_nodes // BLOCK_NODES),)](
        e,
        table,
        rows,
        order.receiver_offsets,
        weights[0],
        middle_weight,
        middle_bias,
        weights[-1],
        biases[-1],
        gamma,
        beta,
        out,
        aggregate,
        num_nodes,
        eps,
        L=latent,
        H=hidden,
        HAS_MIDDLE=has_middle,
        PRECISION=_precision(weights[0].dtype, allow_tf32),
        UPCAST=_upcast(weights[0].dtype),
        BN=BLOCK_NODES,
        BE=BLOCK_EDGES,
    )
    return out, aggregate


def segment_sum_into(out: Tensor, first_row: int, rows: Tensor, offsets: Tensor, permutation: Tensor | None) -> Tensor:
    """``out[first_row + i] += `` the sum of node i's run of ``rows`` (through ``permutation`` when given); returns
    ``out``."""
    kernels = triton_module()
    num_nodes = offsets.shape[0] - 1
    if num_nodes == 0:
        return out
    kernels.segment_sum_kernel[(num_nodes,)](
        rows,
        offsets if permutation is None else permutation,
        offsets,
        out,
        out.stride(0),
        first_row,
        F=rows.shape[1],
        PERMUTED=permutation is not None,
        BE=BLOCK_EDGES,
    )
    return out


class _TritonEdgeBlock(torch.autograd.Function):
    @staticmethod
    def forward(ctx, e, table, rows, order, eps, allow_tf32, products, num_weights, gamma, beta, *parameters):
        weights, biases = list(parameters[:num_weights]), list(parameters[num_weights:])
        product_weights = for_products(products, weights)
        out, aggregate = forward(e, table, rows, order, product_weights, biases, gamma, beta, eps, allow_tf32)
        ctx.save_for_backward(e, table, rows, *order, gamma, beta, *weights, *biases)
        ctx.eps, ctx.allow_tf32, ctx.products, ctx.num_weights = eps, allow_tf32, products, len(weights)
        ctx.set_materialize_grads(False)
        return out, aggregate

    @staticmethod
    def backward(ctx, grad_out, grad_aggregate):
        e, table, rows, receiver_offsets, sender_permutation, sender_offsets, gamma, beta, *parameters = (
            ctx.saved_tensors
        )
        weights, biases = parameters[: ctx.num_weights], parameters[ctx.num_weights :]
        products = ctx.products
        product_weights = for_products(products, weights)
        middle_weight, middle_bias, has_middle = _middle(product_weights, biases)
        kernels = triton_module()
        num_edges, latent = e.shape
        hidden, num_nodes = table.shape[1], table.shape[0] // 2
        tiles = -(-num_edges // BLOCK_EDGES)
        new = {"device": e.device}
        grad_e = torch.empty_like(e)
        grad_a1 = torch.empty(num_edges, hidden, dtype=products, **new)
        grad_a_middle = torch.empty(num_edges if has_middle else 0, hidden, dtype=products, **new)
        h_first = torch.empty_like(grad_a_middle)
        grad_a_last = torch.empty(num_edges, latent, dtype=products, **new)
        h_last_in = torch.empty(num_edges, hidden, dtype=products, **new)
        grad_gamma_tiles = torch.empty(tiles, latent, dtype=torch.float32, **new)
        grad_beta_tiles = torch.empty_like(grad_gamma_tiles)
        if tiles:
            kernels.backward_kernel[(tiles,)](
                e,
                table,
                rows,
                product_weights[0],
                middle_weight,
                middle_bias,
                product_weights[-1],
                biases[-1],
                gamma,
                beta,
                *(None if g is None else g.contiguous() for g in (grad_out, grad_aggregate)),
                grad_e,
                grad_a1,
                grad_a_middle,
                h_first,
                grad_a_last,
                h_last_in,
                grad_gamma_tiles,
                grad_beta_tiles,
                num_edges,
                ctx.eps,
                L=latent,
                H=hidden,
                HAS_MIDDLE=has_middle,
                PRECISION=_precision(products, ctx.allow_tf32),
                UPCAST=_upcast(products),
                HAS_GRAD_OUT=grad_out is not None,
                HAS_GRAD_AGGREGATE=grad_aggregate is not None,
                BE=BLOCK_EDGES,
            )
        # Weight gradients: products over all edges (cuBLAS, float32 accumulation), in the parameters' dtype.
        dtype = weights[0].dtype
        grad_weights = [(grad_a1.T @ e.to(products)).to(dtype)]
        grad_biases = []
        if has_middle:
            grad_weights.append((grad_a_middle.T @ h_first).to(dtype))
            grad_biases.append(grad_a_middle.sum(0, dtype=torch.float32).to(dtype))
        grad_weights.append((grad_a_last.T @ h_last_in).to(dtype))
        grad_biases.append(grad_a_last.sum(0, dtype=torch.float32).to(dtype))
        # The node table's gradient: each edge's first-layer gradient at its receiver's row and its sender's.
        grad_table = torch.zeros(table.shape, dtype=torch.float32, device=e.device)
        segment_sum_into(grad_table, 0, grad_a1, receiver_offsets, None)
        segment_sum_into(grad_table, num_nodes, grad_a1, sender_offsets, sender_permutation)
        return (
            grad_e,
            grad_table.to(table.dtype),
            *(None,) * 6,  # the graph's indices and the options: no gradient
            grad_gamma_tiles.sum(0).to(gamma.dtype),
            grad_beta_tiles.sum(0).to(beta.dtype),
            *grad_weights,
            *grad_biases,
        )


def triton_edge_block(
    e: Tensor,
    table: Tensor,
    rows: Tensor,
    order: EdgeOrder,
    weights: list[Tensor],
    biases: list[Tensor],
    gamma: Tensor,
    beta: Tensor,
    eps: float,
    products: torch.dtype = torch.float32,
    allow_tf32: bool = False,
) -> tuple[Tensor, Tensor]:
    """The edge update of one interaction step, ``(e + u, aggregate of u at receivers)``, by the Triton kernels.

    Args:
        e: (E, L) float32 edge latents, edges sorted by receiver.
        table: (2N, H) float32 node table (``edge_block.node_table``).
        rows: (2E,) int64 ``edge_block.table_rows``: each edge's receiver row, then its sender's.
        order: the graph's :class:`~.edge_order.EdgeOrder`.
        weights: ``[W_e (H, L), W_2 (H, H), W_3 (L, H)]``, or without ``W_2`` for one hidden layer.
        biases: ``[b_2 (H,), b_3 (L,)]``, or ``[b_3]``.
        gamma, beta, eps: (L,), (L,) and epsilon of the LayerNorm after the MLP.
        products: the products' dtype (bfloat16 under autocast); sums stay in float32.
        allow_tf32: let float32 products use TF32 on the GPU.

    Shapes: returns (E, L) and (N, L) float32.
    """
    e, table = e.contiguous(), table.contiguous()
    return _TritonEdgeBlock.apply(
        e, table, rows, order, eps, allow_tf32, products, len(weights), gamma, beta, *weights, *biases
    )
