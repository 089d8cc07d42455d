"""``gns`` run as a user runs it, in a subprocess, for the tests that check a whole command."""

from __future__ import annotations

import subprocess
import sys


def gns(*args: str) -> subprocess.CompletedProcess:
    """``python -m gns_framework.cli ARGS``, its output captured as text (15 minutes at most)."""
    return subprocess.run(
        [sys.executable, "-m", "gns_framework.cli", *args], capture_output=True, text=True, timeout=900
    )
