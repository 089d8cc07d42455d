"""Sums of rows at indices that give the same bits run after run on GPUs, where ``index_add_`` does not.

``index_add_`` on CUDA adds with atomics in whatever order the threads arrive, so
the float32 sums at a node differ in their last bits from run to run: an exact
resume, or a CPU/GPU comparison, cannot hold. Here the rows are put in key order
(the graph builders sort edges by receiver, so receivers come sorted) and each
run of equal keys is summed by ``torch.segment_reduce`` over CSR offsets: one pass
over the E rows, each output element summing its own run in order, with no
atomics, no prefix scan (PyTorch's outer-dimension scans run in one block on
CUDA, PyTorch issue 122170) and no read-back to the host. The sums are float32;
``GNS_FLOAT64_SUMS=1`` sums in float64 instead (the run totals then round to the
same float32 whatever the order within a run: for comparing a GPU run with a CPU
one bit for bit), at 4x the memory traffic.

On CPUs ``index_add_`` is serial and already deterministic (and the fused kernels
of the edge block sum sorted receivers in order), so the edge block uses this on
accelerators only, and only while ``training.deterministic`` holds
(:func:`needs_ordered_sums`); with it off, accelerators use the atomic ``index_add_``.
On CUDA with Triton the edge block sums in its own kernels (``triton_edge_block.py``).
"""

from __future__ import annotations

import os

import torch
from torch import Tensor

from gns_framework.api import deterministic_sums

IMPLEMENTS = "processors/interaction_network.py: InteractionStep with edge_block: plain"  # see reading_cost.py


def needs_ordered_sums(device: torch.device) -> bool:
    """Whether sums on ``device`` go through :func:`segment_sum_`: accelerators, unless deterministic sums are off."""
    return device.type != "cpu" and deterministic_sums()


def sorted_segment_sum_(out: Tensor, keys: Tensor, rows: Tensor) -> Tensor:
    """``out[keys[k]] += rows[k]`` for non-decreasing ``keys``, each output row summed in key order; returns ``out``.

    Shapes: out (M, F); keys (K,) int64, sorted, in [0, M); rows (K, F). No host synchronisation.
    """
    if keys.numel() == 0:
        return out
    # offsets[i]: the first row whose key is >= i, so output row i sums rows [offsets[i], offsets[i + 1]).
    offsets = torch.searchsorted(keys, torch.arange(out.shape[0] + 1, device=keys.device, dtype=keys.dtype))
    sums = torch.segment_reduce(rows.to(sum_dtype(rows.dtype)), "sum", offsets=offsets, axis=0, unsafe=True)
    return out.add_(sums.to(out.dtype))


def sum_dtype(dtype: torch.dtype) -> torch.dtype:
    """The dtype runs are summed in: ``dtype`` (float32 at least), or float64 under ``GNS_FLOAT64_SUMS=1``."""
    if os.environ.get("GNS_FLOAT64_SUMS") == "1":
        return torch.float64
    return torch.promote_types(dtype, torch.float32)


def segment_sum_(out: Tensor, keys: Tensor, rows: Tensor) -> Tensor:
    """``out[keys[k]] += rows[k]`` for keys in any order, in a fixed order; returns ``out``.

    The rows are put in key order by a stable sort (itself deterministic), then
    summed as by :func:`sorted_segment_sum_`.
    """
    order = torch.argsort(keys, stable=True)
    return sorted_segment_sum_(out, keys[order], rows[order])
