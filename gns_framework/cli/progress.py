"""The report phase's progress bar: which candidate is being timed and scored, and how many cases are left.

Timing every model and simulator setting on every case (repeats included) is the
longest silent part of ``gns evaluate`` and ``gns demo`` (minutes with the MPM rows).
"""

from __future__ import annotations

import contextlib
import sys
from collections.abc import Callable, Iterator


@contextlib.contextmanager
def report_progress(quiet: bool) -> Iterator[Callable[[str, int, int], None] | None]:
    """A ``progress(candidate, done, total)`` callback drawing a bar on stderr, or None when ``quiet``."""
    if quiet:
        yield None
        return
    from tqdm import tqdm

    with tqdm(desc="timing and scoring", unit="case", file=sys.stderr) as bar:

        def progress(candidate: str, done: int, total: int) -> None:
            bar.total = total
            bar.set_postfix_str(candidate, refresh=False)
            bar.update(done - bar.n)

        yield progress
