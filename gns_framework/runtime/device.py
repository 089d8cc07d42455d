"""Where computation runs: one policy for the learned model (torch) and the ground-truth simulator (Warp).

``auto`` means the first CUDA device when there is one, else the CPU; ``cpu``,
``cuda`` and ``cuda:N`` are taken as given once checked against the devices the
backend sees. Each backend brings its own count of CUDA devices (torch's for the
model, Warp's for the MPM), so a machine where only one of them sees a GPU is
still described truly.
"""

from __future__ import annotations

from collections.abc import Callable

import torch

from ..errors import GnsError


def choose_device(name: str, cuda_devices: Callable[[], int], where: str = "--device") -> str:
    """``cpu`` or ``cuda[:N]`` for ``name``, given how many CUDA devices the backend sees.

    A GnsError names ``where`` (the option or recipe field) when ``name`` is no device
    or names one this machine lacks.
    """
    if name == "auto":
        return "cuda:0" if cuda_devices() > 0 else "cpu"
    try:
        device = torch.device(name)
    except (RuntimeError, ValueError, TypeError):
        raise GnsError(f"{where} {name!r}: not a device: expected auto, cpu, cuda or cuda:N") from None
    if device.type == "cpu":
        return "cpu"
    if device.type != "cuda":
        raise GnsError(f"{where} {name!r}: not supported: expected auto, cpu, cuda or cuda:N")
    count = cuda_devices()
    if count == 0:
        raise GnsError(f"{where} {name!r}: no CUDA device is available on this machine (use cpu or auto)")
    index = device.index or 0
    if index >= count:
        raise GnsError(
            f"{where} {name!r}: this machine has {count} CUDA device{'s' if count != 1 else ''} "
            f"(cuda:0 to cuda:{count - 1})"
        )
    return f"cuda:{index}"


def _torch_cuda_devices() -> int:
    return torch.cuda.device_count() if torch.cuda.is_available() else 0


def resolve_device(name: str, where: str = "--device") -> torch.device:
    """The torch device ``name`` (auto, cpu, cuda or cuda:N) means here, for the learned model."""
    return torch.device(choose_device(name, _torch_cuda_devices, where))


def is_cuda(device: torch.device | str | None) -> bool:
    """Whether ``device`` is a CUDA GPU: the one test behind every CUDA-only step.

    Pinned host buffers, ``torch.cuda.synchronize``, TF32, NCCL and per-rank GPU
    binding exist only there; ``None`` (no device given) is the CPU.
    """
    return device is not None and torch.device(device).type == "cuda"


def synchronize(device: torch.device | str | None) -> None:
    """Wait for the work queued on ``device``: CUDA kernels run asynchronously to Python (a no-op elsewhere)."""
    if is_cuda(device):
        torch.cuda.synchronize(device)
