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
block while it sits in cache, so only the products remain costly.

The backward is written by hand. It reuses the chunk activations stored by the
forward, or, with :func:`~gns_framework.activation_memory.recompute_activations`,
recomputes them from ``e``, the node table and the weights: then a training step
keeps one (E, L) tensor per message-passing step (the edge latents, kept anyway)
instead of four, for a third more matrix-product work in the backward.
"""

from __future__ import annotations

import torch
from torch import Tensor
from torch.autograd.function import once_differentiable

from gns_framework.activation_memory import recompute_activations

from ..chunked import (
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


def _chunk_activations(e, table, rows, weights, biases):
    """Post-ReLU inputs of every layer after the first, and the last layer's output, for one chunk.

    Everything is in the products' dtype: ``table``, ``weights`` and ``biases`` come cast to it.
    """
    pairs = torch.arange(0, rows.shape[0], 2, device=rows.device)
    # One pass gathers and sums the receiver and sender rows of every edge.
    a = torch.nn.functional.embedding_bag(rows, table, pairs, mode="sum")
    a.addmm_(e.to(a.dtype), weights[0].t())
    return hidden_forward(a, weights[1:], biases)


def _forward(e, table, rows, receivers, norm_weight, norm_bias, eps, weights, biases, out, plan, stored=None):
    """Write ``e + u`` into ``out`` (may be ``e`` itself) and return the aggregate of ``u`` at receivers.

    ``plan`` is (edges per chunk, dtype of the products). ``stored``, when given, receives
    every chunk's activations for the backward.
    """
    size, products = plan
    table, weights, biases = table.to(products), for_products(products, weights), for_products(products, biases)
    latent = e.shape[1]
    aggregate = e.new_zeros(table.shape[0] // 2, latent)
    for lo, hi in chunks(e.shape[0], size):
        inputs, a = _chunk_activations(e[lo:hi], table, rows[2 * lo : 2 * hi], weights, biases)
        if stored is None:
            update = torch.layer_norm(a.to(e.dtype), (latent,), norm_weight, norm_bias, eps)
        else:
            update, mean, rstd = torch.native_layer_norm(a.to(e.dtype), (latent,), norm_weight, norm_bias, eps)
            stored.append((inputs, a, mean, rstd))
        aggregate.index_add_(0, receivers[lo:hi], update)
        torch.add(e[lo:hi], update, out=out[lo:hi])
    return aggregate


class _EdgeBlock(torch.autograd.Function):
    @staticmethod
    def forward(ctx, e, table, rows, receivers, eps, num_layers, products, norm_weight, norm_bias, *parameters):
        weights, biases = parameters[:num_layers], parameters[num_layers:]
        out = torch.empty_like(e)
        ctx.stored = None if recompute_activations() else []
        ctx.plan = (chunk_size(e.device), products)
        aggregate = _forward(
            e, table, rows, receivers, norm_weight, norm_bias, eps, weights, biases, out, ctx.plan, ctx.stored
        )
        ctx.save_for_backward(e, table, rows, receivers, norm_weight, norm_bias, *weights, *biases)
        ctx.eps, ctx.num_layers = eps, num_layers
        ctx.set_materialize_grads(False)
        return out, aggregate

    @staticmethod
    @once_differentiable
    def backward(ctx, grad_out, grad_aggregate):
        e, table, rows, receivers, norm_weight, norm_bias, *parameters = ctx.saved_tensors
        weights, biases = parameters[: ctx.num_layers], parameters[ctx.num_layers :]
        size, products = ctx.plan
        product_table = table.to(products)
        product_weights, product_biases = for_products(products, weights), for_products(products, biases)
        latent = e.shape[1]
        grad_e = torch.empty_like(e)
        grad_table = torch.zeros_like(table, dtype=e.dtype)
        grad_weights = [torch.zeros_like(w) for w in weights]
        grad_biases = [torch.zeros_like(b) for b in biases]
        grad_norm_weight, grad_norm_bias = torch.zeros_like(norm_weight), torch.zeros_like(norm_bias)
        for index, (lo, hi) in enumerate(chunks(e.shape[0], size)):
            chunk_rows, e_chunk = rows[2 * lo : 2 * hi], e[lo:hi]
            if grad_aggregate is None:
                grad_update = e.new_zeros(hi - lo, latent)
            else:
                grad_update = grad_aggregate.index_select(0, receivers[lo:hi])
            if grad_out is not None:
                grad_update += grad_out[lo:hi]
            if ctx.stored is None:
                inputs, a = _chunk_activations(e_chunk, product_table, chunk_rows, product_weights, product_biases)
                a = a.to(e.dtype)
                _, mean, rstd = torch.native_layer_norm(a, (latent,), norm_weight, norm_bias, ctx.eps)
            else:
                inputs, a, mean, rstd = ctx.stored[index]
                a = a.to(e.dtype)
            grad_a, grad_gamma, grad_beta = torch.ops.aten.native_layer_norm_backward(
                grad_update, a, (latent,), mean, rstd, norm_weight, norm_bias, [True, True, True]
            )
            grad_norm_weight += grad_gamma
            grad_norm_bias += grad_beta
            grad_a = hidden_backward(
                grad_a, inputs, product_weights[1:], grad_weights[1:], grad_biases, (products, e.dtype)
            )
            add_product(grad_weights[0], grad_a.t(), e_chunk.to(products))
            grad_a_summed = grad_a.to(e.dtype)
            grad_table.index_add_(0, chunk_rows[0::2], grad_a_summed)
            grad_table.index_add_(0, chunk_rows[1::2], grad_a_summed)
            product_into(grad_e[lo:hi], grad_a, product_weights[0], None if grad_out is None else grad_out[lo:hi])
        grad_table = grad_table.to(table.dtype)
        return (grad_e, grad_table, None, None, None, None, None, grad_norm_weight, grad_norm_bias, *grad_weights, *grad_biases)


def edge_block(
    e: Tensor,
    table: Tensor,
    rows: Tensor,
    receivers: Tensor,
    weights: list[Tensor],
    biases: list[Tensor],
    norm: torch.nn.LayerNorm,
    in_place: bool = False,
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
        in_place: write ``e + u`` into ``e`` (allowed only without autograd).

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
        if torch.is_grad_enabled() and any(t.requires_grad for t in (e, table, *weights, *biases, norm_weight)):
            if in_place:
                raise ValueError("in_place edge updates cannot be differentiated")
            return _EdgeBlock.apply(
                e, table, rows, receivers, norm.eps, len(weights), products, norm_weight, norm_bias, *weights, *biases
            )
        out = e if in_place else torch.empty_like(e)
        plan = (chunk_size(e.device), products)
        aggregate = _forward(e, table, rows, receivers, norm_weight, norm_bias, norm.eps, weights, biases, out, plan)
    return out, aggregate
