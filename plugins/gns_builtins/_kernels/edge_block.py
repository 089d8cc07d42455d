"""The interaction network's edge block, evaluated in cache-sized chunks of edges.

For edges k with latents e_k between receiver r(k) and sender s(k), and node
projections ``P = [x W_r^T, x W_s^T]`` computed once per node::

    a_1 = e_k W_e^T + b_1 + P_r[r(k)] + P_s[s(k)]      (the split first layer)
    a_j = relu(a_{j-1}) W_j^T + b_j                     (the remaining layers)
    u_k = LayerNorm(a_last)
    e'_k = e_k + u_k,   aggregate_i = sum of u_k over edges with r(k) = i

Done on whole (E, H) tensors, every elementwise operation streams the edge
activations through main memory, and every (E, H) result is a fresh allocation
above glibc's mmap threshold that page-faults in on each call: together about as
much time as the matrix products. Here each chunk of edges goes through the whole
block while it sits in cache, so only the products remain costly. On CPUs the
elementwise passes of a chunk (bias and ReLU, LayerNorm with residual and sum at
receivers, and their backward) run as a few fused C loops (``fused_kernels.py``),
with the torch path as the fallback.

The backward is written by hand. It reuses the chunk activations stored by the
forward, or, with :func:`~gns_framework.runtime.activation_memory.recompute_activations`,
recomputes them from ``e``, the node table and the weights: then a training step
keeps one (E, L) tensor per message-passing step (the edge latents, kept anyway)
instead of four, for a third more matrix-product work in the backward.
"""

from __future__ import annotations

from typing import NamedTuple

import torch
from torch import Tensor
from torch.autograd.function import once_differentiable

from gns_framework.api import avoids_read_backs, recompute_activations

from . import fused_kernels, triton_edge_block
from .chunked import (
    add_product,
    chunk_size,
    chunks,
    for_products,
    hidden_backward,
    hidden_forward,
    product_dtype,
    product_into,
    widest_dtype,
)
from .edge_order import EdgeOrder
from .segment_sum import needs_ordered_sums, segment_sum_, sorted_segment_sum_

IMPLEMENTS = "processors/interaction_network.py: InteractionStep with edge_block: plain"  # see reading_cost.py


def node_table(x: Tensor, first_weight: Tensor, first_bias: Tensor) -> Tensor:
    """(2N, H) ``[x W_r^T + b_1; x W_s^T]``: the node columns of the first edge layer, with its bias.

    ``first_weight`` is the (H, 3L) first-layer weight over ``[e, x_receiver, x_sender]``.
    """
    latent = x.shape[1]
    receiver_part = torch.addmm(first_bias, x, first_weight[:, latent : 2 * latent].T)
    return torch.cat([receiver_part, x @ first_weight[:, 2 * latent :].T])


def table_rows(senders: Tensor, receivers: Tensor, num_nodes: int) -> Tensor:
    """(2E,) rows of :func:`node_table` each edge sums: its receiver's, then its sender's."""
    return torch.stack([receivers, senders + num_nodes], 1).reshape(-1)


class Plan(NamedTuple):
    """How one call runs: edges per chunk, the products' dtype, whether the receivers are sorted,
    and whether sums at nodes go through :mod:`~gns_builtins._kernels.segment_sum` instead of ``index_add_``."""

    chunk_size: int
    products: torch.dtype
    receivers_sorted: bool
    ordered_sums: bool

    @staticmethod
    def of(e: Tensor, receivers: Tensor, products: torch.dtype, known_sorted: bool = False) -> Plan:
        # Graph builders sort edges by receiver (``known_sorted``: the graph says so, Graph.receivers_sorted); else
        # the fused CPU kernels, which rely on it, check once per call (a read-back, so only on the CPU).
        check = not avoids_read_backs(e.device) and bool((receivers[1:] >= receivers[:-1]).all())
        return Plan(chunk_size(e.device), products, known_sorted or check, needs_ordered_sums(e.device))


def chunk_sender_order(senders: Tensor, size: int) -> Tensor:
    """(E,) edge indices sorted by chunk of ``size`` edges, then by sender: made once per graph, for every backward.

    The ordered sums need each chunk's sender rows in key order; chunks are contiguous edge
    ranges, so sorting by (chunk, sender) puts chunk ``[lo, hi)``'s edges at positions
    ``[lo, hi)``, sorted by sender: one stable sort per graph instead of one per chunk and call.
    """
    num_edges = senders.shape[0]
    chunk = torch.arange(num_edges, device=senders.device) // size
    return torch.argsort(chunk * (senders.max() + 1) + senders, stable=True) if num_edges else senders


def _add_at(out: Tensor, index: Tensor, rows: Tensor, plan: Plan, receivers: bool = False) -> None:
    """``out[index[k]] += rows[k]``: in a fixed order where ``index_add_`` has none (GPUs); ``index`` the
    receivers (``receivers``), when the plan knows them sorted, needs no sort."""
    if plan.ordered_sums:
        (sorted_segment_sum_ if receivers and plan.receivers_sorted else segment_sum_)(out, index, rows)
    else:
        out.index_add_(0, index, rows)


def _chunk_activations(e, table, rows, weights, biases):
    """For one chunk: the post-ReLU inputs of every layer after the first, and the last layer's product.

    The product lacks the last bias, ``biases[-1]``, when there are layers after the
    first (else the bias is in ``table``). Everything is in the products' dtype:
    ``table``, ``weights`` and ``biases`` come cast to it.
    """
    pairs = torch.arange(0, rows.shape[0], 2, device=rows.device)
    # One pass gathers and sums the receiver and sender rows of every edge.
    a = torch.nn.functional.embedding_bag(rows, table, pairs, mode="sum")
    a.addmm_(e.to(a.dtype), weights[0].t())
    return hidden_forward(a, weights[1:], biases)


def _forward(e, table, rows, receivers, norm_weight, norm_bias, eps, weights, biases, out, plan, stored=None):
    """Write ``e + u`` into ``out`` (may be ``e`` itself) and return the aggregate of ``u`` at receivers.

    ``plan`` is the call's :class:`Plan`. ``stored``, when given, receives
    every chunk's activations for the backward.
    """
    size, products = plan.chunk_size, plan.products
    last_bias = biases[-1] if biases else None
    table, weights, biases = table.to(products), for_products(products, weights), for_products(products, biases)
    aggregate = e.new_zeros(table.shape[0] // 2, e.shape[1])
    norm = (norm_weight, norm_bias, eps)
    for lo, hi in chunks(e.shape[0], size):
        inputs, a = _chunk_activations(e[lo:hi], table, rows[2 * lo : 2 * hi], weights, biases)
        a = a.to(e.dtype)
        mean, rstd = _layer_norm_residual(
            a, last_bias, norm, e[lo:hi], out[lo:hi], aggregate, receivers[lo:hi], stored is not None, plan
        )
        if stored is not None:
            stored.append((inputs, a, mean, rstd))
    return aggregate


def _layer_norm_residual(a, bias, norm, e, out, aggregate, receivers, stats, plan):
    """LayerNorm ``u`` of ``a + bias``: writes ``e + u`` into ``out``, adds ``u`` into ``aggregate`` at ``receivers``.

    ``a`` becomes ``a + bias`` (unless ``bias`` is None); ``norm`` is (weight, bias,
    eps). Returns the LayerNorm's ``(mean, rstd)`` for the backward when ``stats``,
    else ``(None, None)``.
    """
    norm_weight, norm_bias, eps = norm
    if plan.receivers_sorted and fused_kernels.applies(a, bias, e, out, aggregate, receivers, norm_weight, norm_bias):
        return fused_kernels.layer_norm_residual(
            a, bias, norm_weight, norm_bias, eps, e, out, aggregate, receivers, stats
        )
    if bias is not None:
        a += bias
    if stats:
        update, mean, rstd = torch.native_layer_norm(a, (a.shape[1],), norm_weight, norm_bias, eps)
    else:
        update, mean, rstd = torch.layer_norm(a, (a.shape[1],), norm_weight, norm_bias, eps), None, None
    torch.add(e, update, out=out)
    _add_at(aggregate, receivers, update, plan, receivers=True)
    return mean, rstd


def _layer_norm_backward(grad_aggregate, receivers, grad_out, a, mean, rstd, norm, grad_e, grad_norm, grad_last_bias):
    """Gradient at ``a`` from ``grad_aggregate[receivers] + grad_out`` (either may be None, not both).

    ``norm`` is the LayerNorm's (weight, bias). Writes ``grad_out`` into ``grad_e`` (the
    residual's share of the gradient at ``e``; untouched when None). Adds into
    ``grad_norm`` (LayerNorm weight, bias) and into ``grad_last_bias``, the bias of the
    layer that produced ``a`` (None when that is the first layer, whose bias is in the
    node table).
    """
    norm_weight, norm_bias = norm
    if fused_kernels.applies(grad_aggregate, receivers, grad_out, a, mean, rstd, norm_weight, grad_e, grad_last_bias):
        return fused_kernels.layer_norm_backward(
            grad_aggregate, receivers, grad_out, a, mean, rstd, norm_weight, grad_e, *grad_norm, grad_last_bias
        )
    if grad_out is not None:
        grad_e.copy_(grad_out)
    if grad_aggregate is None:
        grad_update = grad_out
    else:
        grad_update = grad_aggregate.index_select(0, receivers)
        if grad_out is not None:
            grad_update += grad_out
    grad_a, grad_gamma, grad_beta = torch.ops.aten.native_layer_norm_backward(
        grad_update, a, (a.shape[1],), mean, rstd, norm_weight, norm_bias, [True, True, True]
    )
    grad_norm[0].add_(grad_gamma)
    grad_norm[1].add_(grad_beta)
    if grad_last_bias is not None:
        grad_last_bias += grad_a.sum(0)
    return grad_a


class _EdgeBlock(torch.autograd.Function):
    @staticmethod
    def forward(
        ctx, e, table, rows, receivers, sender_order, eps, num_layers, products, norm_weight, norm_bias, *parameters
    ):
        weights, biases = parameters[:num_layers], parameters[num_layers:]
        out = torch.empty_like(e)
        ctx.sender_order = sender_order
        ctx.stored = None if recompute_activations() else []
        ctx.plan = Plan.of(e, receivers, products, known_sorted=sender_order is not None)
        aggregate = _forward(
            e, table, rows, receivers, norm_weight, norm_bias, eps, weights, biases, out, ctx.plan, ctx.stored
        )
        # The backward reads e only as an operand of products: kept in the products' dtype (bfloat16
        # under autocast) it gives the same gradients in half the memory, the largest saved tensor.
        ctx.save_for_backward(e.to(products), table, rows, receivers, norm_weight, norm_bias, *weights, *biases)
        ctx.eps, ctx.num_layers, ctx.dtype = eps, num_layers, e.dtype
        ctx.set_materialize_grads(False)
        return out, aggregate

    @staticmethod
    @once_differentiable
    def backward(ctx, grad_out, grad_aggregate):
        e, table, rows, receivers, norm_weight, norm_bias, *parameters = ctx.saved_tensors
        weights, biases = parameters[: ctx.num_layers], parameters[ctx.num_layers :]
        size, products = ctx.plan.chunk_size, ctx.plan.products
        product_table = table.to(products)
        product_weights, product_biases = for_products(products, weights), for_products(products, biases)
        latent, dtype = e.shape[1], ctx.dtype
        grad_e = torch.empty(e.shape, dtype=dtype, device=e.device)
        grad_table = torch.zeros_like(table, dtype=dtype)
        grad_weights = [torch.zeros_like(w) for w in weights]
        grad_biases = [torch.zeros_like(b) for b in biases]
        grad_norm_weight, grad_norm_bias = torch.zeros_like(norm_weight), torch.zeros_like(norm_bias)
        if grad_aggregate is None and grad_out is None:
            grad_out = torch.zeros_like(grad_e)
        last_bias = biases[-1] if biases else None
        if grad_aggregate is not None:
            # Often a column slice of the node MLP's input gradient; its rows are gathered per edge.
            grad_aggregate = grad_aggregate.contiguous()
        sender_order = None
        if ctx.plan.ordered_sums:  # the graph's, when the processor made it; else this call's
            sender_order = ctx.sender_order if ctx.sender_order is not None else chunk_sender_order(rows[1::2], size)
        for index, (lo, hi) in enumerate(chunks(e.shape[0], size)):
            chunk_rows, e_chunk = rows[2 * lo : 2 * hi], e[lo:hi]
            if ctx.stored is None:
                inputs, a = _chunk_activations(e_chunk, product_table, chunk_rows, product_weights, product_biases)
                a = a.to(dtype)
                if last_bias is not None:
                    a += last_bias
                _, mean, rstd = torch.native_layer_norm(a, (latent,), norm_weight, norm_bias, ctx.eps)
            else:
                inputs, a, mean, rstd = ctx.stored[index]
            grad_a = _layer_norm_backward(
                grad_aggregate,
                receivers[lo:hi],
                None if grad_out is None else grad_out[lo:hi],
                a,
                mean,
                rstd,
                (norm_weight, norm_bias),
                grad_e[lo:hi],
                (grad_norm_weight, grad_norm_bias),
                grad_biases[-1] if grad_biases else None,
            )
            grad_a = hidden_backward(
                grad_a, inputs, product_weights[1:], grad_weights[1:], grad_biases, (products, dtype)
            )
            add_product(grad_weights[0], grad_a.t(), e_chunk.to(products))
            grad_a_summed = grad_a.to(dtype)
            _add_at(grad_table, chunk_rows[0::2], grad_a_summed, ctx.plan, receivers=True)
            if sender_order is None:
                _add_at(grad_table, chunk_rows[1::2], grad_a_summed, ctx.plan)
            else:
                local = sender_order[lo:hi] - lo
                sorted_segment_sum_(grad_table, chunk_rows[1::2][local], grad_a_summed[local])
            if grad_out is None:
                product_into(grad_e[lo:hi], grad_a, product_weights[0])
            else:
                add_product(grad_e[lo:hi], grad_a, product_weights[0])
        grad_table = grad_table.to(table.dtype)
        return (
            grad_e,
            grad_table,
            *(None,) * 6,  # the graph's indices and the options: no gradient
            grad_norm_weight,
            grad_norm_bias,
            *grad_weights,
            *grad_biases,
        )


def uses_triton(latent: Tensor, weight: Tensor, num_weights: int) -> bool:
    """Whether :func:`edge_block` on edge latents like ``latent`` (any float dtype: they are summed in the
    weights') and float32 weights like ``weight`` (H, L) runs as Triton kernels, given the graph's order."""
    return weight.dtype == torch.float32 and triton_edge_block.applies(latent, weight.shape[0], num_weights)


class ChunkOrder(NamedTuple):
    """The chunked path's order of a graph's edges for ordered sums at senders (:func:`chunk_sender_order`)."""

    sender_order: Tensor


def edge_order(step, e: Tensor, graph) -> EdgeOrder | ChunkOrder | None:
    """The graph's edge orders, made once for all the message-passing steps of a processor call: an
    :class:`EdgeOrder` where an interaction step like ``step`` (``InteractionStep``) runs its edge block as Triton
    kernels, a :class:`ChunkOrder` where the chunked path sums in a fixed order (accelerators without Triton),
    else None (the CPU: sums in edge order, nothing to sort).

    Shapes: e (E, L) edge latents; ``graph`` a :class:`~gns_framework.contracts.Graph`.
    """
    if step.edge_block != "fused" or not graph.receivers_sorted:
        return None
    linears = step.edge_mlp.mlp.linears
    if uses_triton(e, linears[0].weight, len(linears)):
        return EdgeOrder.of(graph.senders, graph.receivers, graph.num_nodes)
    if needs_ordered_sums(e.device):
        return ChunkOrder(chunk_sender_order(graph.senders, chunk_size(e.device)))
    return None


def edge_block(
    e: Tensor,
    table: Tensor,
    rows: Tensor,
    receivers: Tensor,
    weights: list[Tensor],
    biases: list[Tensor],
    norm: torch.nn.LayerNorm,
    in_place: bool = False,
    order: EdgeOrder | ChunkOrder | None = None,
) -> tuple[Tensor, Tensor]:
    """The edge update of one interaction step: ``(e + u, aggregate of u at receivers)``.

    Args:
        e: (E, L) edge latents.
        table: (2N, H) :func:`node_table`, the node columns of the first layer and its bias.
        rows: (2E,) :func:`table_rows`.
        receivers: (E,) int64.
        weights: the edge MLP's weights; ``weights[0]`` is the (H, L) edge columns of the first layer.
        biases: the biases of the layers after the first.
        norm: the LayerNorm after the MLP.
        in_place: write ``e + u`` into ``e`` (allowed only without autograd; the Triton kernels write anew).
        order: the graph's orders (:func:`edge_order`): an :class:`~.edge_order.EdgeOrder` where the Triton
            kernels take the block (:func:`uses_triton`: on CUDA one pass per step), a :class:`ChunkOrder` where
            the chunked backward sums at senders in a fixed order (made per graph, not per call).

    Under autocast to a lower precision (bfloat16 or float16) the products run in that
    dtype, as autocast would run the unsplit MLP's Linears; LayerNorm, the residual,
    the aggregate and every gradient sum stay in the widest dtype given (float32).
    """
    dtype = widest_dtype(e, *weights, *biases, norm.weight)
    device_type = e.device.type
    products = product_dtype(dtype, device_type)
    e = e.to(dtype)
    weights, biases = [w.to(dtype) for w in weights], [b.to(dtype) for b in biases]
    norm_weight, norm_bias = norm.weight.to(dtype), norm.bias.to(dtype)
    with torch.autocast(device_type, enabled=False):
        if isinstance(order, EdgeOrder) and dtype == torch.float32:
            return triton_edge_block.triton_edge_block(
                e,
                table.to(dtype),
                rows,
                order,
                weights,
                biases,
                norm_weight,
                norm_bias,
                norm.eps,
                products,
                allow_tf32=torch.backends.cuda.matmul.allow_tf32,
            )
        if torch.is_grad_enabled() and any(t.requires_grad for t in (e, table, *weights, *biases, norm_weight)):
            if in_place:
                raise ValueError("in_place edge updates cannot be differentiated")
            sender_order = order.sender_order if isinstance(order, ChunkOrder) else None
            return _EdgeBlock.apply(
                e,
                table,
                rows,
                receivers,
                sender_order,
                norm.eps,
                len(weights),
                products,
                norm_weight,
                norm_bias,
                *weights,
                *biases,
            )
        out = e if in_place else torch.empty_like(e)
        plan = Plan.of(e, receivers, products, known_sorted=isinstance(order, ChunkOrder))
        aggregate = _forward(e, table, rows, receivers, norm_weight, norm_bias, norm.eps, weights, biases, out, plan)
    return out, aggregate
