"""Training memory mode honoured by components with hand-written backwards.

Storing activations for the backward is fastest; recomputing them from the
layer inputs instead keeps about half the peak memory of a training step for
~10 % more time (docs/performance.md). Set from ``training.recompute_activations``.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager

_recompute = False


def set_recompute_activations(enabled: bool) -> None:
    global _recompute
    _recompute = bool(enabled)


def recompute_activations() -> bool:
    return _recompute


@contextmanager
def activations_recomputed(enabled: bool = True) -> Iterator[None]:
    """Recompute activations within the block (forward and backward), then restore the mode.

    Gradient checkpointing needs it around both passes: a component that stored its
    activations would hold them beside the checkpoint's recomputation, and the memory
    checkpointing saves would be spent anyway.
    """
    before = _recompute
    set_recompute_activations(enabled or before)
    try:
        yield
    finally:
        set_recompute_activations(before)
