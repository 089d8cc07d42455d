"""Where the hot path may wait for the device, and the choices made to avoid waiting elsewhere.

On a GPU every read of a tensor's value on the host (``item``, ``tolist``, ``cpu``, ``bool``,
boolean-mask selection) waits until the device has run everything queued before it, so the host
stops queueing work ahead. A training or rollout step reads back only:

- the edge count of the graph it builds (``radius_pairs``: the candidate count, and the pairs
  kept within the radius), which is data and sizes every edge tensor (none with fixed capacity);
- on logging, validation and checkpoint steps, the losses since the last read.

Explicit reads go through :func:`read_back`, so a test can count them and make any other read
fail (``tests/runtime/test_host_sync.py``); :class:`~.sync_counter.SyncCounter` counts torch's own.
"""

from __future__ import annotations

from collections.abc import Callable
from contextvars import ContextVar
from typing import Any, Generic, TypeVar

import torch
from torch import Tensor

T = TypeVar("T")

EMULATED_ACCELERATOR: ContextVar[bool] = ContextVar("emulated_accelerator", default=False)
"""True while the CPU stands in for an accelerator: a captured step's emulation (runtime/capture.py)."""


def avoids_read_backs(device: torch.device) -> bool:
    """Whether code on ``device`` takes its read-back-free path (every accelerator).

    On the CPU a read costs nothing, and the CPU paths are the reference ones (bitwise as before).
    """
    return device.type != "cpu" or EMULATED_ACCELERATOR.get()


def read_back(tensor: Tensor) -> Any:
    """The values of ``tensor`` as a (nested) list on the host (a number for a 0-d tensor): one of the
    documented waits for the device."""
    return tensor.tolist()


class PerDevice(Generic[T]):
    """What ``make(like)`` returns, made the first time ``like``'s device and dtype are met and kept.

    Constants built on the host (index lists, box bounds) and moved to the device on
    every call would be a copy, and on a GPU a stream synchronisation, per call; made
    once per device and dtype (in ``made``) they cost nothing after the first step.
    """

    def __init__(self, make: Callable[[Tensor], T]):
        self._make = make
        self.made: dict[tuple[torch.device, torch.dtype], T] = {}

    def __call__(self, like: Tensor) -> T:
        key = (like.device, like.dtype)
        if key not in self.made:
            self.made[key] = self._make(like)
        return self.made[key]
