"""Rows sent between processes: each row to the process that needs it, in one all-to-all per tensor.

Works with gloo (CPU tensors) and nccl (CUDA tensors) alike: the counts go first, so
every process knows how many rows it receives from each other, then the rows of each
tensor with those splits. The all-to-all is differentiable: its backward sends each row's
gradient back to its sender.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import torch
import torch.distributed as dist
from torch import Tensor

from ..runtime.processes import Processes


@dataclass(frozen=True)
class Routing:
    """Where each row goes: its order when sent (grouped by destination) and the counts each way.

    Attributes:
        order: (M,) the rows in the order they are sent.
        sent: rows sent to each process.
        received: rows received from each process.
        group: the processes exchanging (None: the whole job).
    """

    order: Tensor
    sent: list[int]
    received: list[int]
    group: Any = None

    @classmethod
    def of(cls, destination: Tensor, world_size: int, group: Any = None) -> Routing:
        """Row i goes to process ``destination[i]`` (M,) of ``group`` (None: the whole job); every process of it
        calls this at once."""
        if world_size == 1:
            count = int(destination.shape[0])
            return cls(torch.arange(count, device=destination.device), [count], [count])
        sent = torch.bincount(destination, minlength=world_size)
        received = torch.empty_like(sent)
        dist.all_to_all_single(received, sent, group=group)
        return cls(torch.argsort(destination, stable=True), sent.tolist(), received.tolist(), group)

    def send(self, rows: Tensor) -> Tensor:
        """``rows`` (M, ...) sent as routed; the rows received (M', ...), ordered by sender, then as sent."""
        if len(self.sent) == 1:
            return rows  # a single process keeps every row, in order
        wire = rows.index_select(0, self.order)
        # gloo has no bool all-to-all: masks travel as bytes.
        wire = wire.to(torch.uint8) if rows.dtype == torch.bool else wire.contiguous()
        into = _AllToAll.apply(wire, self.received, self.sent, self.group)
        return into.to(torch.bool) if rows.dtype == torch.bool else into


def send_rows(
    destination: Tensor, tensors: list[Tensor | None], world_size: int, group: Any = None
) -> list[Tensor | None]:
    """Send row i of every tensor to process ``destination[i]`` of ``group``; return the rows received (None stays
    None).

    Shapes: destination (M,) int64 in [0, world_size); each tensor (M, ...) -> (M', ...).
    """
    routing = Routing.of(destination, world_size, group)
    return [None if tensor is None else routing.send(tensor) for tensor in tensors]


def rows_everywhere(ids: Tensor, rows: Tensor, total: int, world_size: int, group: Any = None) -> Tensor:
    """Every process's ``rows``, placed by their global ``ids``, on every process (an all-gather of rows).

    Each global id in ``[0, total)`` must be held by exactly one process. Shapes: ids (n,)
    int64; rows (n, ...) -> (total, ...).
    """
    destination = torch.arange(world_size, device=ids.device).repeat_interleave(ids.shape[0])
    repeats = (world_size,) + (1,) * (rows.dim() - 1)
    every_id, every_row = send_rows(destination, [ids.repeat(world_size), rows.repeat(repeats)], world_size, group)
    assert every_id is not None and every_row is not None
    placed = rows.new_empty((total, *rows.shape[1:]))
    placed[every_id] = every_row
    return placed


def objects_everywhere(processes: Processes, value: Any) -> list[Any]:
    """Every process's ``value`` (any picklable object: a few numbers, a list of guard reports), in rank order,
    on every process."""
    if not processes.distributed:
        return [value]
    gathered: list[Any] = [None] * processes.world_size
    dist.all_gather_object(gathered, value, group=processes.group)
    return gathered


class _AllToAll(torch.autograd.Function):
    """All-to-all of rows whose backward sends each row's gradient back to the process it came from."""

    @staticmethod
    def forward(ctx, rows: Tensor, received: list[int], sent: list[int], group: Any) -> Tensor:
        ctx.received, ctx.sent, ctx.group = received, sent, group
        into = rows.new_empty((sum(received), *rows.shape[1:]))
        dist.all_to_all_single(
            into, rows.contiguous(), output_split_sizes=received, input_split_sizes=sent, group=group
        )
        return into

    @staticmethod
    def backward(ctx, gradient: Tensor) -> tuple[Tensor, None, None, None]:
        back = gradient.new_empty((sum(ctx.sent), *gradient.shape[1:]))
        dist.all_to_all_single(
            back,
            gradient.contiguous(),
            output_split_sizes=ctx.sent,
            input_split_sizes=ctx.received,
            group=ctx.group,
        )
        return back, None, None, None
