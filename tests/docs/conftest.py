"""The documented-commands harness imports its helpers by module name (this folder first on sys.path)."""

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
