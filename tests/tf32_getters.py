"""Every getter of torch's two TF32 APIs, for tests that check a TF32 block leaves them readable."""

from __future__ import annotations

import torch


def getters() -> dict[str, object]:
    """Every getter of both APIs; each raises where the two APIs' records disagree."""
    return {
        "legacy matmul.allow_tf32": torch.backends.cuda.matmul.allow_tf32,
        "legacy get_float32_matmul_precision": torch.get_float32_matmul_precision(),
        "legacy cudnn.allow_tf32": torch.backends.cudnn.allow_tf32,
        "new matmul.fp32_precision": torch.backends.cuda.matmul.fp32_precision,
        "new cudnn.conv.fp32_precision": torch.backends.cudnn.conv.fp32_precision,
        "new cudnn.rnn.fp32_precision": torch.backends.cudnn.rnn.fp32_precision,
    }


def effective(getters: dict[str, object]) -> dict[str, object]:
    """What the setting means: the new API's 'none' (inherit) and 'ieee' (the default it inherits) are one."""
    return {key: ("ieee" if value == "none" else value) for key, value in getters.items()}
