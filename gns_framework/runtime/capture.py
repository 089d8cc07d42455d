"""A step captured once and replayed: a CUDA graph on CUDA, the same semantics emulated elsewhere (for tests).

A CUDA graph records the kernels a function launches, with the addresses of the
tensors they read and write; a replay launches them all again in one call, reading
whatever those tensors hold now. Per step the host then pays one launch instead of
hundreds (issue 45: a 10k-particle rollout step dispatches ~600 operations). What a
captured function may do follows from that: no read-back (the host learns nothing
during capture), no tensor made from host data (a copy from pageable memory cannot be
captured), no Python decision on values, and the Python code runs only once, so state
it keeps must live in tensors updated in place.

:class:`CapturedStep` captures ``step()`` after a few eager warm-up calls and returns
its outputs, fixed tensors rewritten by each replay. Its inputs are whatever tensors
``step`` reads: the caller copies each step's values into them before replaying.

On the CPU the same contract is emulated: capture records every ATen operation with
its argument and result tensors under a ``TorchDispatchMode``, refusing read-backs and
tensors made from host data; a replay re-runs the recorded operations on the recorded
tensors and writes each result into the tensor the capture returned. The Python code
is not re-run, exactly as on a GPU, so tests on the CPU catch a step that only works
eagerly (see tests/runtime/test_capture.py). Warm-up and capture run with the CPU
standing in for an accelerator (``host_sync.EMULATED_ACCELERATOR``): the read-back-free
paths, and no ctypes kernels, whose work the emulation could not see.
"""

from __future__ import annotations

import traceback
from collections.abc import Callable
from pathlib import Path
from typing import Any, Generic, TypeVar

import torch
from torch.utils._python_dispatch import TorchDispatchMode
from torch.utils._pytree import tree_flatten

from ..errors import GnsError
from .host_sync import EMULATED_ACCELERATOR
from .sync_counter import SYNCING_OPS

T = TypeVar("T")

HOST_DATA_OPS = frozenset({"aten.lift_fresh", "aten.lift_fresh_copy"})
"""Operations that make a tensor from host data (``torch.tensor([...])``): on CUDA a copy a graph cannot capture."""


class CaptureError(GnsError):
    """A step does something a captured step cannot (a read-back, host data, an operation outside ATen)."""


class CapturedStep(Generic[T]):
    """``step()`` captured once; calling the object replays it and returns its (fixed) outputs.

    Args:
        step: a function of no arguments returning tensors (any nesting); it reads its
            inputs from tensors the caller rewrites in place between calls.
        device: where the step runs: CUDA captures a ``torch.cuda.CUDAGraph``, any other
            device is emulated.
        warmup: eager calls before the capture (lazily made constants, allocator pools).
            Each runs the step once, as a replay would.

    ``replays`` counts the calls, for tests.
    """

    def __init__(self, step: Callable[[], T], device: torch.device, warmup: int = 2):
        self.device = torch.device(device)
        self.replays = 0
        if self.device.type == "cuda":
            self._graph, self.outputs = _capture_cuda(step, self.device, warmup)
            self._replay = self._graph.replay
        else:
            # Warm-up and capture take the accelerators' path, so the step they record is the one a GPU captures.
            standing_in = EMULATED_ACCELERATOR.set(True)
            try:
                # Compiled code cannot run under the recording mode: the tape records its operations run eagerly.
                with torch.compiler.set_stance("force_eager"):
                    for _ in range(warmup):
                        step()
                    tape = _Tape()
                    with tape:
                        self.outputs = step()
            finally:
                EMULATED_ACCELERATOR.reset(standing_in)
            self._replay = tape.replay

    def __call__(self) -> T:
        self._replay()
        self.replays += 1
        return self.outputs


def _capture_cuda(step: Callable[[], T], device: torch.device, warmup: int) -> tuple[Any, T]:
    # Warm-up on a side stream, as torch.cuda.graphs asks: the capture then sees no first-call work.
    stream = torch.cuda.Stream(device)
    stream.wait_stream(torch.cuda.current_stream(device))
    with torch.cuda.stream(stream):
        for _ in range(warmup):
            step()
    torch.cuda.current_stream(device).wait_stream(stream)
    graph = torch.cuda.CUDAGraph()
    with torch.cuda.graph(graph):
        outputs = step()
    return graph, outputs


class _Tape(TorchDispatchMode):
    """Every ATen operation of a capture, with its arguments and results, to run again on the same tensors."""

    def __init__(self):
        super().__init__()
        self.operations: list[tuple[Any, tuple, dict, list[torch.Tensor]]] = []

    def __torch_dispatch__(self, func, types, args=(), kwargs=None):
        kwargs = kwargs or {}
        name = str(func.overloadpacket)
        if name in SYNCING_OPS or (name == "aten.index" and _boolean_index(args)):
            raise CaptureError(f"{_caller()}: reads back from the device ({name})")
        if name in HOST_DATA_OPS:
            raise CaptureError(
                f"{_caller()}: makes a tensor from host data (torch.tensor): make it once, outside the step"
            )
        result = func(*args, **kwargs)
        outputs = [leaf for leaf in tree_flatten(result)[0] if isinstance(leaf, torch.Tensor)]
        self.operations.append((func, args, kwargs, outputs))
        return result

    @torch.no_grad()
    def replay(self) -> None:
        # The recorded operations include a captured backward's: replayed as plain ATen operations, as a CUDA
        # graph's kernels are, not tracked by autograd again.
        for func, args, kwargs, outputs in self.operations:
            again = [leaf for leaf in tree_flatten(func(*args, **kwargs))[0] if isinstance(leaf, torch.Tensor)]
            for captured, fresh in zip(outputs, again, strict=True):
                # A view or an in-place result shares the captured storage, already rewritten; a new
                # result goes into the tensor the capture returned, which later operations read.
                if not _same_storage(captured, fresh):
                    captured.copy_(fresh)


def _caller() -> str:
    """``file:line`` of the innermost project code on the stack (what the step ran when refused)."""
    project = str(Path(__file__).resolve().parents[2])
    for frame in reversed(traceback.extract_stack()):
        inside = frame.filename.startswith(project) and "site-packages" not in frame.filename
        if inside and not frame.filename.endswith("runtime/capture.py"):
            return f"{Path(frame.filename).relative_to(project)}:{frame.lineno}"
    return "the step"


def _boolean_index(args: tuple) -> bool:
    indices = args[1] if len(args) > 1 else ()
    return any(isinstance(i, torch.Tensor) and i.dtype == torch.bool for i in indices)


def _same_storage(a: torch.Tensor, b: torch.Tensor) -> bool:
    return a.untyped_storage().data_ptr() == b.untyped_storage().data_ptr() and a.device == b.device
