"""Import time of the package and of the ``gns --help`` start, each in a fresh interpreter.

Usage: python benchmarks/import_time.py [--repeat 5]

Prints one line per case: the median wall time of the subprocess's import (or CLI
start) in milliseconds, measured inside the subprocess so interpreter start-up
is excluded.
"""

from __future__ import annotations

import argparse
import statistics
import subprocess
import sys

CASES = {
    "import gns_framework": "import gns_framework",
    "gns --help": "from gns_framework.cli import main\ntry:\n    main(['--help'])\nexcept SystemExit:\n    pass",
    "registry (gns plugins)": "from gns_framework.plugins import load_registry\nload_registry()",
}

PROBE = """
import contextlib, io, time
start = time.perf_counter()
with contextlib.redirect_stdout(io.StringIO()):
{body}
print((time.perf_counter() - start) * 1000)
"""


def measure(body: str) -> float:
    code = PROBE.format(body="\n".join("    " + line for line in body.splitlines()))
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    return float(out.strip().splitlines()[-1])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=5)
    args = parser.parse_args()
    for label, body in CASES.items():
        times = [measure(body) for _ in range(args.repeat)]
        print(f"import-time {label}: {statistics.median(times):.1f} ms (median of {args.repeat})")


if __name__ == "__main__":
    main()
