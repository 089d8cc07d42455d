"""Rows sent between processes: each row to the process that needs it, in one all-to-all per tensor.

Works with gloo (CPU tensors) and nccl (CUDA tensors) alike: the counts go first, so
every process knows how many rows it receives from each other, then the rows of each
tensor with those splits.
"""

from __future__ import annotations

import torch
import torch.distributed as dist
from torch import Tensor


def send_rows(destination: Tensor, tensors: list[Tensor | None], world_size: int) -> list[Tensor | None]:
    """Send row i of every tensor to process ``destination[i]``; return the rows received.

    Received rows come ordered by the sending process, and within one sender in the
    order it sent them. A None stays None (a field the scene does not have).

    Shapes: destination (M,) int64 in [0, world_size); each tensor (M, ...) -> (M', ...),
    M' the rows sent to this process.
    """
    if world_size == 1:
        return list(tensors)  # a single process sends every row to itself, in order
    order = torch.argsort(destination, stable=True)
    sent_counts = torch.bincount(destination, minlength=world_size)
    received_counts = torch.empty_like(sent_counts)
    dist.all_to_all_single(received_counts, sent_counts)
    sent, received = sent_counts.tolist(), received_counts.tolist()
    out: list[Tensor | None] = []
    for tensor in tensors:
        if tensor is None:
            out.append(None)
            continue
        rows = tensor.index_select(0, order).contiguous()
        # gloo has no bool all-to-all: masks travel as bytes.
        wire = rows.to(torch.uint8) if rows.dtype == torch.bool else rows
        into = wire.new_empty((sum(received),) + tuple(wire.shape[1:]))
        dist.all_to_all_single(into, wire, output_split_sizes=received, input_split_sizes=sent)
        out.append(into.to(torch.bool) if rows.dtype == torch.bool else into)
    return out
