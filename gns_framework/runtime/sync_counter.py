"""Counting, on any device, the operators that would make the host wait for a GPU.

A test of the hot path runs a step under :class:`SyncCounter` on the CPU and checks
that it waits only where :mod:`.host_sync` says it may.
"""

from __future__ import annotations

import torch
import torch.utils._python_dispatch
from torch import Tensor

SYNCING_OPS = frozenset(
    {
        "aten._local_scalar_dense",  # .item(), bool(), int() of a tensor
        "aten.nonzero",
        "aten.masked_select",
        "aten._unique",
        "aten._unique2",
        "aten.unique_dim",
        "aten.unique_consecutive",
        "aten.equal",
        "aten.is_nonzero",
    }
)
"""Operators whose output size or result must come to the host: on a GPU each waits for the device."""


class SyncCounter(torch.utils._python_dispatch.TorchDispatchMode):
    """Counts the operators that would make the host wait for a GPU, seen at the dispatch level.

    Unlike a check of Python-level reads it sees the waits inside torch too: a boolean
    mask index (``x[mask]`` is a ``nonzero``), ``torch.unique``, ``repeat_interleave``
    without ``output_size``, ``.item()``. Works on the CPU, so a test counts what a GPU
    step would wait for. ``counts`` maps each operator to its calls.
    """

    def __init__(self):
        super().__init__()
        self.counts: dict[str, int] = {}

    @property
    def total(self) -> int:
        return sum(self.counts.values())

    def __torch_dispatch__(self, func, types, args=(), kwargs=None):
        kwargs = kwargs or {}
        name = str(func.overloadpacket)
        syncs = name in SYNCING_OPS
        if name == "aten.index" and any(
            isinstance(i, Tensor) and i.dtype == torch.bool for i in (args[1] if len(args) > 1 else ())
        ):
            syncs, name = True, "aten.index (boolean mask)"
        if (
            name == "aten.repeat_interleave"
            and kwargs.get("output_size") is None
            and not (len(args) > 3 and args[3] is not None)
        ):
            syncs, name = True, "aten.repeat_interleave (no output_size)"
        if syncs:
            self.counts[name] = self.counts.get(name, 0) + 1
        return func(*args, **kwargs)
