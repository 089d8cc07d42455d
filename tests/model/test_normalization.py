"""Normalisation statistics: the noise-combined std as the reference computes it, in float32."""

from __future__ import annotations

import torch

from gns_framework.model.normalization import noise_combined_std


def test_noise_combined_std_matches_float32_reference():
    std = noise_combined_std([0.0011, 0.0012], 6.7e-4)
    expected = torch.sqrt(torch.FloatTensor([0.0011, 0.0012]) ** 2 + 6.7e-4**2)
    assert torch.equal(std, expected) and std.dtype == torch.float32
