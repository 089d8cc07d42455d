"""Float32 results checked against a float64 computation of the same thing, at a tolerance from magnitudes.

A fixed absolute tolerance between two float32 paths depends on the machine: each
path's rounding follows its kernels (vector width, FMA contraction, blocking, thread
count), and the rounding of a sum scales with the magnitude of its terms, not with a
constant. An edge block whose gradients reach a few hundred differs between two
float32 paths by 1.5e-5 on one machine and passes at 1e-5 on another (issue 16).

So each float32 path is compared with a float64 evaluation of the same computation
on the same float32 inputs, whose own rounding is about 2**-29 of float32's and can
be taken as exact, and the tolerance is a number of float32 epsilons of the
magnitude the rounding scales with. For a tensor that is large enough, the largest
magnitude of the reference stands for the magnitudes of its terms; where terms
cancel (a short sum, a mean near zero, a LayerNorm of nearly equal values), the
caller passes that scale, e.g. the sum of the terms' absolute values.
"""

from __future__ import annotations

import torch
from torch import Tensor

FLOAT32_EPS = torch.finfo(torch.float32).eps

ULPS = 16
"""Float32 epsilons allowed per unit of scale. The fused and torch paths measured up
to 2.6 (edge block values and gradients against the largest reference magnitude; the
LayerNorm, ReLU and column-sum kernels against the magnitudes of their terms), so 16
leaves a margin of 6 while an error of 1e-4 relative (840 epsilons) still fails."""


def assert_close_to_reference(
    got: Tensor, reference: Tensor, ulps: float = ULPS, scale: Tensor | float | None = None, msg: str = ""
) -> None:
    """``|got - reference| <= ulps * eps32 * scale`` elementwise, ``scale`` by default ``max |reference|``.

    ``reference`` is the float64 computation; ``scale`` may be a tensor that
    broadcasts against it (a per-row or per-column magnitude).
    """
    if reference.dtype != torch.float64:
        raise TypeError(f"the reference must be a float64 computation, got {reference.dtype}")
    label = f"{msg}: " if msg else ""
    if got.shape != reference.shape:
        raise AssertionError(f"{label}shape {tuple(got.shape)} != reference {tuple(reference.shape)}")
    if scale is None:
        scale = reference.abs().max() if reference.numel() else torch.zeros((), dtype=torch.float64)
    allowed = ulps * FLOAT32_EPS * torch.as_tensor(scale, dtype=torch.float64)
    error = (got.double() - reference).abs()
    over = ~(error <= allowed)  # NaN in got is over
    if over.any():
        worst = int((error - allowed).nan_to_num(nan=torch.inf).flatten().argmax())
        index = tuple(int(i) for i in torch.unravel_index(torch.tensor(worst), error.shape))
        allowed_there = allowed.expand_as(error)[index].item()
        raise AssertionError(
            f"{label}{int(over.sum())} of {error.numel()} elements differ from the float64 "
            f"reference by more than {ulps} float32 epsilons of their scale; the worst at {index}: got "
            f"{got[index].item()!r}, reference {reference[index].item()!r}, allowed {allowed_there:.3g}"
        )
