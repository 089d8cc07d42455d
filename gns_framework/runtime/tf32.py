"""TF32 matrix products on CUDA for one block of code: ``training.precision: tf32`` and ``--precision tf32``.

Its own module because only a CUDA run enters it, and the way it sets the flags
answers a torch quirk that a reader of a CPU step need not meet.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator

import torch


@contextlib.contextmanager
def cuda_tf32() -> Iterator[None]:
    """float32 products on CUDA in TF32 inside the block; the process-wide setting is restored after.

    Set through one API only, the ``allow_tf32`` flags. torch 2.9 and later (2.11 to
    2.13 checked) keep two records of the setting: ``allow_tf32`` and
    ``set_float32_matmul_precision`` write both, ``fp32_precision`` writes only the
    new one. Set through ``fp32_precision`` alone, the legacy getters
    (``torch.backends.cuda.matmul.allow_tf32``, ``torch.get_float32_matmul_precision()``),
    which other code may read, raise "mix of the legacy and new APIs" inside the block.
    Through ``allow_tf32`` every getter, legacy and new, stays readable
    (tests/runtime/test_tf32.py). Only the CUDA flags change: the CPU's (oneDNN)
    setting is left alone.
    """
    matmul, cudnn = torch.backends.cuda.matmul, torch.backends.cudnn
    saved = matmul.allow_tf32, cudnn.allow_tf32
    matmul.allow_tf32 = cudnn.allow_tf32 = True
    try:
        yield
    finally:
        matmul.allow_tf32, cudnn.allow_tf32 = saved
