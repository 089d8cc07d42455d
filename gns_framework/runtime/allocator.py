"""Keep freed memory in the process instead of returning it to the OS (glibc only).

glibc's malloc serves blocks above its mmap threshold (at most 32 MB) with a fresh
``mmap`` and unmaps them on ``free``; it also trims the heap top once more than
the trim threshold is free. A GNS step allocates and frees the same (E, L) edge
tensors every step, so without this each step page-faults its whole working set
in again: ~0.5 ms per MB on a 2-core machine, as long as the arithmetic itself.
Disabling mmap for large blocks and raising the trim threshold lets the heap
reuse them, at the price that the resident size never shrinks below its peak.

Applied by training and rollouts on the CPU (on a GPU the host's allocations are
small and the setting would only pin the process's peak); ``GNS_KEEP_FREED_MEMORY=0``
opts out (read when first applied).
"""

from __future__ import annotations

import ctypes
import os
import platform

_M_TRIM_THRESHOLD = -1
_M_MMAP_MAX = -4
_TRIM_THRESHOLD = 2**31 - 1
"""mallopt takes an int: up to 2 GB of free heap top is kept."""

_applied: bool | None = None


def keep_freed_memory() -> bool:
    """Tune glibc's malloc once per process; True when the tuning is in effect."""
    global _applied
    if _applied is None:
        _applied = _apply()
    return _applied


def _apply() -> bool:
    if os.environ.get("GNS_KEEP_FREED_MEMORY", "1") == "0" or platform.libc_ver()[0] != "glibc":
        return False
    mallopt = ctypes.CDLL(None).mallopt
    return bool(mallopt(_M_MMAP_MAX, 0)) and bool(mallopt(_M_TRIM_THRESHOLD, _TRIM_THRESHOLD))
