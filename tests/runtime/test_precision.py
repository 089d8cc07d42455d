"""The TF32 setting goes through one of torch's two precision APIs, so every getter of both stays readable.

These run on any build (the flags exist without a GPU); benchmarks/gpu_check.sh runs
them on the GPU machine too, with its torch.
"""

from __future__ import annotations

import pytest
import torch

from gns_framework.runtime.precision import _cuda_tf32, autocast, backward_precision


def _getters() -> dict[str, object]:
    """Every getter of both APIs; each raises where the two APIs' records disagree."""
    return {
        "legacy matmul.allow_tf32": torch.backends.cuda.matmul.allow_tf32,
        "legacy get_float32_matmul_precision": torch.get_float32_matmul_precision(),
        "legacy cudnn.allow_tf32": torch.backends.cudnn.allow_tf32,
        "new matmul.fp32_precision": torch.backends.cuda.matmul.fp32_precision,
        "new cudnn.conv.fp32_precision": torch.backends.cudnn.conv.fp32_precision,
        "new cudnn.rnn.fp32_precision": torch.backends.cudnn.rnn.fp32_precision,
    }


def _effective(getters: dict[str, object]) -> dict[str, object]:
    """What the setting means: the new API's 'none' (inherit) and 'ieee' (the default it inherits) are one."""
    return {key: ("ieee" if value == "none" else value) for key, value in getters.items()}


def test_inside_the_tf32_block_every_legacy_and_new_getter_reads_tf32():
    with _cuda_tf32():
        inside = _getters()
    assert inside == {
        "legacy matmul.allow_tf32": True,
        "legacy get_float32_matmul_precision": "high",
        "legacy cudnn.allow_tf32": True,
        "new matmul.fp32_precision": "tf32",
        "new cudnn.conv.fp32_precision": "tf32",
        "new cudnn.rnn.fp32_precision": "tf32",
    }


def test_after_the_block_every_getter_reads_what_it_read_before():
    before = _getters()
    with _cuda_tf32():
        pass
    assert _effective(_getters()) == _effective(before)
    assert torch.backends.cuda.matmul.allow_tf32 is False and torch.get_float32_matmul_precision() == "highest"


def test_the_training_and_rollout_contexts_for_cuda_leave_every_getter_readable():
    """autocast/backward_precision for tf32 on CUDA enter the block (no GPU needed to set the flags)."""
    for context in (autocast("tf32", "cuda"), backward_precision("tf32", "cuda")):
        with context:
            assert _getters()["legacy get_float32_matmul_precision"] == "high"
        assert _getters()["legacy get_float32_matmul_precision"] == "highest"


def test_nested_blocks_restore_the_outer_setting():
    with _cuda_tf32():
        with _cuda_tf32():
            pass
        assert torch.backends.cuda.matmul.allow_tf32 is True and torch.get_float32_matmul_precision() == "high"
    assert torch.backends.cuda.matmul.allow_tf32 is False


def test_bfloat16_and_float32_set_no_process_flag():
    before = _getters()
    for precision in ("float32", "bfloat16"):
        with autocast(precision, "cpu"), backward_precision(precision, "cpu"):
            assert _getters() == before


def test_why_one_api_setting_the_new_api_alone_leaves_the_legacy_getters_unreadable():
    """The reason the block uses ``allow_tf32``: torch (2.11 to 2.13) refuses a legacy read after a new-API-only write.

    If a torch release stops refusing, ``fp32_precision`` becomes an equal choice; this says so.
    """
    matmul = torch.backends.cuda.matmul
    saved = matmul.fp32_precision
    try:
        matmul.fp32_precision = "tf32"
        with pytest.raises(RuntimeError, match="mix of the legacy and new APIs"):
            torch.get_float32_matmul_precision()
    finally:
        matmul.fp32_precision = saved
    _getters()  # readable again once the new API's record matches the legacy one
