"""Training memory mode honoured by components with hand-written backwards.

Storing activations for the backward is fastest; recomputing them from the
layer inputs instead keeps about half the peak memory of a training step for
~10 % more time (docs/performance.md). Set from ``training.recompute_activations``.
"""

from __future__ import annotations

_recompute = False


def set_recompute_activations(enabled: bool) -> None:
    global _recompute
    _recompute = bool(enabled)


def recompute_activations() -> bool:
    return _recompute
