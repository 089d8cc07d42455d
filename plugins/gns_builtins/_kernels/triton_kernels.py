"""Triton kernels of the edge block (``triton_edge_block.py`` wraps them): forward, backward, segmented sums.

Imported only where Triton is installed. Kernels index rows with the graph's indices,
int32 or int64, widened to int64 before a row's width multiplies them; every sum over
edges runs in a fixed order (no atomics). Shapes and the update they compute:
``triton_edge_block.py``.
"""

import triton
import triton.language as tl

IMPLEMENTS = "processors/interaction_network.py: InteractionStep with edge_block: plain"  # see reading_cost.py


@triton.jit
def _dot(a, b, PRECISION: tl.constexpr, UPCAST: tl.constexpr):
    """``a @ b`` with float32 accumulation, operands in their (products') dtype.

    ``UPCAST``: the operands' values taken to float32 first, the same products (a bfloat16
    product is exact in float32); for Triton's CPU interpreter, whose bfloat16 dot is wrong.
    """
    if UPCAST:
        return tl.dot(a.to(tl.float32), b.to(tl.float32), input_precision="ieee")
    return tl.dot(a, b, input_precision=PRECISION)


@triton.jit
def _activations(
    e,
    table_ptr,
    rows_ptr,
    edges,
    mask,
    w1,
    wm,
    bm,
    wl,
    bl,
    H: tl.constexpr,
    HAS_MIDDLE: tl.constexpr,
    PRECISION: tl.constexpr,
    UPCAST: tl.constexpr,
):
    """One tile's pre-activations: (a_1, a_middle, h_last_in, a_last). Shapes (BE, H) and (BE, L)."""
    hcols = tl.arange(0, H)
    receiver_rows = tl.load(rows_ptr + 2 * edges, mask=mask, other=0).to(tl.int64)
    sender_rows = tl.load(rows_ptr + 2 * edges + 1, mask=mask, other=0).to(tl.int64)
    a1 = _dot(e.to(w1.dtype), tl.trans(w1), PRECISION, UPCAST)
    a1 += tl.load(table_ptr + receiver_rows[:, None] * H + hcols[None, :], mask=mask[:, None], other=0.0)
    a1 += tl.load(table_ptr + sender_rows[:, None] * H + hcols[None, :], mask=mask[:, None], other=0.0)
    h = tl.maximum(a1, 0.0)
    a_middle = a1
    if HAS_MIDDLE:
        a_middle = _dot(h.to(wm.dtype), tl.trans(wm), PRECISION, UPCAST) + bm[None, :]
        h = tl.maximum(a_middle, 0.0)
    a_last = _dot(h.to(wl.dtype), tl.trans(wl), PRECISION, UPCAST) + bl[None, :]
    return a1, a_middle, h, a_last


@triton.jit
def _normalised(a, eps, L: tl.constexpr):
    """LayerNorm's normalisation of each row of ``a`` (BE, L), before its scale and shift: ``(normed, rstd)``."""
    mean = tl.sum(a, 1) / L
    centred = a - mean[:, None]
    rstd = 1.0 / tl.sqrt(tl.sum(centred * centred, 1) / L + eps)
    return centred * rstd[:, None], rstd


@triton.jit
def _load_weights(w1_ptr, wm_ptr, bm_ptr, wl_ptr, bl_ptr, L: tl.constexpr, H: tl.constexpr, HAS_MIDDLE: tl.constexpr):
    """The weights as stored (rows contiguous, so loads coalesce): W_e (H, L), W_2 (H, H), W_3 (L, H), and biases.

    The forward multiplies by their transposes (``tl.trans``, a layout change in shared memory), the
    backward by the weights themselves.
    """
    lcols = tl.arange(0, L)
    hcols = tl.arange(0, H)
    w1 = tl.load(w1_ptr + hcols[:, None] * L + lcols[None, :])
    wl = tl.load(wl_ptr + lcols[:, None] * H + hcols[None, :])
    bl = tl.load(bl_ptr + lcols).to(tl.float32)
    if HAS_MIDDLE:
        wm = tl.load(wm_ptr + hcols[:, None] * H + hcols[None, :])
        bm = tl.load(bm_ptr + hcols).to(tl.float32)
    else:
        wm = wl
        bm = bl
    return w1, wm, bm, wl, bl


@triton.jit
def forward_kernel(
    e_ptr,
    table_ptr,
    rows_ptr,
    offsets_ptr,
    w1_ptr,
    wm_ptr,
    bm_ptr,
    wl_ptr,
    bl_ptr,
    gamma_ptr,
    beta_ptr,
    out_ptr,
    aggregate_ptr,
    num_nodes,
    eps,
    L: tl.constexpr,
    H: tl.constexpr,
    HAS_MIDDLE: tl.constexpr,
    PRECISION: tl.constexpr,
    UPCAST: tl.constexpr,
    BN: tl.constexpr,
    BE: tl.constexpr,
):
    first = tl.program_id(0).to(tl.int64) * BN
    nodes = first + tl.arange(0, BN)
    lcols = tl.arange(0, L)
    lo = tl.load(offsets_ptr + first)
    hi = tl.load(offsets_ptr + tl.minimum(first + BN, num_nodes))
    gamma = tl.load(gamma_ptr + lcols)
    beta = tl.load(beta_ptr + lcols)
    aggregate = tl.zeros((BN, L), dtype=tl.float32)
    for start in range(lo, hi, BE):
        edges = start + tl.arange(0, BE)
        mask = edges < hi
        e = tl.load(e_ptr + edges[:, None] * L + lcols[None, :], mask=mask[:, None], other=0.0)
        # Loaded per tile (from L2 after the first): held across the loop, three 128 x 128 weights would
        # not fit a program's registers.
        w1, wm, bm, wl, bl = _load_weights(w1_ptr, wm_ptr, bm_ptr, wl_ptr, bl_ptr, L, H, HAS_MIDDLE)
        _, _, _, a = _activations(
            e, table_ptr, rows_ptr, edges, mask, w1, wm, bm, wl, bl, H, HAS_MIDDLE, PRECISION, UPCAST
        )
        normed, _ = _normalised(a, eps, L)
        update = normed * gamma[None, :] + beta[None, :]
        tl.store(out_ptr + edges[:, None] * L + lcols[None, :], e + update, mask=mask[:, None])
        receivers = tl.load(rows_ptr + 2 * edges, mask=mask, other=-1)
        # (BN, BE) one-hot of "edge k is received by node i": the product sums each receiver's
        # edges of this tile in a fixed order, exactly (products by 1.0 and 0.0 round nothing).
        onehot = ((receivers[None, :] == nodes[:, None]) & mask[None, :]).to(tl.float32)
        aggregate += tl.dot(onehot, update, input_precision="ieee")
    tl.store(aggregate_ptr + nodes[:, None] * L + lcols[None, :], aggregate, mask=(nodes < num_nodes)[:, None])


@triton.jit
def backward_kernel(
    e_ptr,
    table_ptr,
    rows_ptr,
    w1_ptr,
    wm_ptr,
    bm_ptr,
    wl_ptr,
    bl_ptr,
    gamma_ptr,
    beta_ptr,
    grad_out_ptr,
    grad_aggregate_ptr,
    grad_e_ptr,
    grad_a1_ptr,
    grad_a_middle_ptr,
    h_first_ptr,
    grad_a_last_ptr,
    h_last_in_ptr,
    grad_gamma_ptr,
    grad_beta_ptr,
    num_edges,
    eps,
    L: tl.constexpr,
    H: tl.constexpr,
    HAS_MIDDLE: tl.constexpr,
    PRECISION: tl.constexpr,
    UPCAST: tl.constexpr,
    HAS_GRAD_OUT: tl.constexpr,
    HAS_GRAD_AGGREGATE: tl.constexpr,
    BE: tl.constexpr,
):
    tile = tl.program_id(0)
    # int64: edge offsets times L pass 2^31 from ~17M edges (a 1M-particle 3D scene has 23M).
    edges = tile.to(tl.int64) * BE + tl.arange(0, BE)
    mask = edges < num_edges
    lcols = tl.arange(0, L)
    hcols = tl.arange(0, H)
    lmask = mask[:, None]
    w1, wm, bm, wl, bl = _load_weights(w1_ptr, wm_ptr, bm_ptr, wl_ptr, bl_ptr, L, H, HAS_MIDDLE)
    gamma = tl.load(gamma_ptr + lcols)
    e = tl.load(e_ptr + edges[:, None] * L + lcols[None, :], mask=lmask, other=0.0)
    a1, a_middle, h_last_in, a = _activations(
        e, table_ptr, rows_ptr, edges, mask, w1, wm, bm, wl, bl, H, HAS_MIDDLE, PRECISION, UPCAST
    )
    normed, rstd = _normalised(a, eps, L)
    # The gradient at u: from e' = e + u directly, and from the aggregate at the edge's receiver.
    grad_u = tl.zeros((BE, L), dtype=tl.float32)
    if HAS_GRAD_OUT:
        grad_out = tl.load(grad_out_ptr + edges[:, None] * L + lcols[None, :], mask=lmask, other=0.0)
        grad_u += grad_out
    if HAS_GRAD_AGGREGATE:
        receivers = tl.load(rows_ptr + 2 * edges, mask=mask, other=0).to(tl.int64)
        grad_u += tl.load(grad_aggregate_ptr + receivers[:, None] * L + lcols[None, :], mask=lmask, other=0.0)
    grad_u = tl.where(lmask, grad_u, 0.0)
    # LayerNorm's per-tile column sums (gamma, beta), summed over tiles in a fixed order by the caller.
    tl.store(grad_gamma_ptr + tile * L + lcols, tl.sum(grad_u * normed, 0))
    tl.store(grad_beta_ptr + tile * L + lcols, tl.sum(grad_u, 0))
    grad_normed = grad_u * gamma[None, :]
    grad_a = rstd[:, None] * (
        grad_normed - (tl.sum(grad_normed, 1) / L)[:, None] - normed * (tl.sum(grad_normed * normed, 1) / L)[:, None]
    )
    tl.store(
        grad_a_last_ptr + edges[:, None] * L + lcols[None, :], grad_a.to(grad_a_last_ptr.dtype.element_ty), mask=lmask
    )
    tl.store(
        h_last_in_ptr + edges[:, None] * H + hcols[None, :], h_last_in.to(h_last_in_ptr.dtype.element_ty), mask=lmask
    )
    # Back through the last product and ReLU: grad_h = grad_a W_3, W_3 (L, H).
    grad_h = _dot(grad_a.to(wl.dtype), wl, PRECISION, UPCAST)
    if HAS_MIDDLE:
        grad_a_middle = tl.where(a_middle > 0.0, grad_h, 0.0)
        tl.store(
            grad_a_middle_ptr + edges[:, None] * H + hcols[None, :],
            grad_a_middle.to(grad_a_middle_ptr.dtype.element_ty),
            mask=lmask,
        )
        h_first = tl.maximum(a1, 0.0)
        tl.store(
            h_first_ptr + edges[:, None] * H + hcols[None, :], h_first.to(h_first_ptr.dtype.element_ty), mask=lmask
        )
        grad_h = _dot(grad_a_middle.to(wm.dtype), wm, PRECISION, UPCAST)
    grad_a1 = tl.where(a1 > 0.0, grad_h, 0.0)
    tl.store(grad_a1_ptr + edges[:, None] * H + hcols[None, :], grad_a1.to(grad_a1_ptr.dtype.element_ty), mask=lmask)
    # The edge latent's gradient: the residual's share plus the first product's, grad_a1 W_e, W_e (H, L).
    grad_e = _dot(grad_a1.to(w1.dtype), w1, PRECISION, UPCAST)
    if HAS_GRAD_OUT:
        grad_e += grad_out
    tl.store(grad_e_ptr + edges[:, None] * L + lcols[None, :], grad_e, mask=lmask)


@triton.jit
def segment_sum_kernel(
    rows_ptr,
    permutation_ptr,
    offsets_ptr,
    out_ptr,
    out_stride,
    out_offset,
    F: tl.constexpr,
    PERMUTED: tl.constexpr,
    BE: tl.constexpr,
):
    """``out[i] += sum of rows[p[k]]`` over k in node i's run ``[offsets[i], offsets[i + 1])`` (p the
    permutation when ``PERMUTED``, else the identity), tile by tile in run order."""
    node = tl.program_id(0).to(tl.int64)
    cols = tl.arange(0, F)
    lo = tl.load(offsets_ptr + node)
    hi = tl.load(offsets_ptr + node + 1)
    total = tl.zeros((F,), dtype=tl.float32)
    for start in range(lo, hi, BE):
        positions = start + tl.arange(0, BE)
        mask = positions < hi
        source = tl.load(permutation_ptr + positions, mask=mask, other=0).to(tl.int64) if PERMUTED else positions
        rows = tl.load(rows_ptr + source[:, None] * F + cols[None, :], mask=mask[:, None], other=0.0)
        total += tl.sum(rows.to(tl.float32), 0)
    target = out_ptr + (out_offset + node) * out_stride + cols
    tl.store(target, tl.load(target) + total)
