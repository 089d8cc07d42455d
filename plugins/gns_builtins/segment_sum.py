"""Sums of rows at indices that give the same bits run after run on GPUs, where ``index_add_`` does not.

``index_add_`` on CUDA adds with atomics in whatever order the threads arrive, so
the float32 sums at a node differ in their last bits from run to run: an exact
resume, or a CPU/GPU comparison, cannot hold. Here each run of equal (sorted) keys
is summed by a float64 prefix sum over the rows (a scan, whose order is fixed),
and only the last row of each run adds its run's total into the output; every
other row adds an exact zero, which leaves the sum unchanged in any order. The
float64 prefix keeps the run totals as accurate as float32 sums (the prefix of E
rows of magnitude m loses about E * m * 1e-16).

On CPUs ``index_add_`` is serial and already deterministic (and the fused kernels
of the edge block sum sorted receivers in order), so the edge block uses this on
accelerators only (:func:`needs_ordered_sums`).
"""

from __future__ import annotations

import torch
from torch import Tensor


def needs_ordered_sums(device: torch.device) -> bool:
    """Whether ``index_add_`` on ``device`` may sum in a varying order (every accelerator)."""
    return device.type != "cpu"


def sorted_segment_sum_(out: Tensor, keys: Tensor, rows: Tensor) -> Tensor:
    """``out[keys[k]] += rows[k]`` for non-decreasing ``keys``, in a fixed order; returns ``out``.

    Shapes: out (M, F); keys (K,) int64, sorted; rows (K, F). No host synchronisation.
    """
    if keys.numel() == 0:
        return out
    prefix = torch.cumsum(rows, 0, dtype=torch.float64)
    last = torch.ones_like(keys, dtype=torch.bool)
    last[:-1] = keys[1:] != keys[:-1]
    # For each row, the index of the last row of the run before its own (-1 for the first run).
    position = torch.arange(keys.numel(), device=keys.device)
    previous_end = torch.where(last, position, torch.full_like(position, -1))
    previous_end = torch.cat([previous_end.new_full((1,), -1), previous_end[:-1]]).cummax(0).values
    before = torch.where((previous_end >= 0)[:, None], prefix[previous_end.clamp(min=0)], torch.zeros_like(prefix))
    totals = torch.where(last[:, None], prefix - before, torch.zeros_like(prefix))
    return out.index_add_(0, keys, totals.to(out.dtype))


def segment_sum_(out: Tensor, keys: Tensor, rows: Tensor) -> Tensor:
    """``out[keys[k]] += rows[k]`` for keys in any order, in a fixed order; returns ``out``.

    The rows are put in key order by a stable sort (itself deterministic), then
    summed as by :func:`sorted_segment_sum_`.
    """
    order = torch.argsort(keys, stable=True)
    return sorted_segment_sum_(out, keys[order], rows[order])
