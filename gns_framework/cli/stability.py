"""``gns stability``: run the stiff and extreme cases and print each with its outcome and figures.

Figures and their meaning are in docs/stability.md. Exits 1 when a case fails: an
outcome that the case must not show (a limit off theory, a symplectic integrator that
diverges or gains energy, non-finite predictions, a guard that neither stops nor clamps).
"""

from __future__ import annotations

import argparse
import time

import torch

from ..plugins import load_registry
from ..stability.report import Row, format_row, run_report
from .arguments import positive_int


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--threads", type=positive_int, default=1, help="torch intra-op threads (default 1)")


def run(args: argparse.Namespace) -> int:
    torch.set_num_threads(args.threads)
    started = time.perf_counter()
    print(format_row(Row("group", "case", "outcome", "figures")))
    failures = []
    for row in run_report(load_registry()):
        print(format_row(row), flush=True)
        if row.failing:
            failures.append(row)
    print(f"\n{len(failures)} failing case(s); {time.perf_counter() - started:.0f} s")
    for row in failures:
        print(f"FAIL: {row.group}: {row.case}: {row.outcome}")
    return 1 if failures else 0
