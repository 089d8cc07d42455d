"""Whether sums at nodes must give the same bits run after run on accelerators (``training.deterministic``).

On CUDA ``index_add_`` adds with atomics in whatever order the threads arrive, so
float32 sums at a node differ in their last bits from run to run, and so do the
runs: two trainings, a run and its resume, or a rollout repeated. Deterministic
sums (the default) go through a segment reduction over receiver-sorted edges
instead (``gns_builtins._kernels.segment_sum``), O(E) like the atomics. CPUs sum in a fixed
order either way. Set from the recipe by the trainer and by loading a checkpoint.
"""

from __future__ import annotations

_deterministic = True


def set_deterministic_sums(enabled: bool) -> None:
    global _deterministic
    _deterministic = bool(enabled)


def deterministic_sums() -> bool:
    return _deterministic
