"""The TF32 block sets the flags through one of torch's two precision APIs, so every getter of both stays readable.

These run on any build (the flags exist without a GPU); benchmarks/gpu_check.sh runs
them on the GPU machine too, with its torch.
"""

from __future__ import annotations

import pytest
import torch
from tf32_getters import effective, getters

from gns_framework.runtime.tf32 import cuda_tf32


def test_inside_the_tf32_block_every_legacy_and_new_getter_reads_tf32():
    with cuda_tf32():
        inside = getters()
    assert inside == {
        "legacy matmul.allow_tf32": True,
        "legacy get_float32_matmul_precision": "high",
        "legacy cudnn.allow_tf32": True,
        "new matmul.fp32_precision": "tf32",
        "new cudnn.conv.fp32_precision": "tf32",
        "new cudnn.rnn.fp32_precision": "tf32",
    }


def test_after_the_block_every_getter_reads_what_it_read_before():
    before = getters()
    with cuda_tf32():
        pass
    assert effective(getters()) == effective(before)
    assert torch.backends.cuda.matmul.allow_tf32 is False and torch.get_float32_matmul_precision() == "highest"


def test_nested_blocks_restore_the_outer_setting():
    with cuda_tf32():
        with cuda_tf32():
            pass
        assert torch.backends.cuda.matmul.allow_tf32 is True and torch.get_float32_matmul_precision() == "high"
    assert torch.backends.cuda.matmul.allow_tf32 is False


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
    getters()  # readable again once the new API's record matches the legacy one
