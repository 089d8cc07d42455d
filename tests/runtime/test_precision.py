"""The precision contexts: TF32 blocks on CUDA only, and no process flag for float32 or bfloat16.

These run on any build (the flags exist without a GPU); benchmarks/gpu_check.sh runs
them on the GPU machine too, with its torch.
"""

from __future__ import annotations

from tf32_getters import getters

from gns_framework.runtime.precision import autocast, backward_precision


def test_the_training_and_rollout_contexts_for_cuda_leave_every_getter_readable():
    """autocast/backward_precision for tf32 on CUDA enter the block (no GPU needed to set the flags)."""
    for context in (autocast("tf32", "cuda"), backward_precision("tf32", "cuda")):
        with context:
            assert getters()["legacy get_float32_matmul_precision"] == "high"
        assert getters()["legacy get_float32_matmul_precision"] == "highest"


def test_bfloat16_and_float32_set_no_process_flag():
    before = getters()
    for precision in ("float32", "bfloat16"):
        with autocast(precision, "cpu"), backward_precision(precision, "cpu"):
            assert getters() == before
