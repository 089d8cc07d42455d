"""``gns plugins``: every installed component by kind, with its source file and distribution."""

from __future__ import annotations

import argparse
import json

from ..contracts import COMPONENT_KINDS
from ..plugins import load_registry


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--kind", choices=list(COMPONENT_KINDS), help="only this kind")
    parser.add_argument("--json", action="store_true", help="print JSON instead of a table")


def run(args: argparse.Namespace) -> int:
    registry = load_registry()
    entries = registry.entries(args.kind)
    rows = [
        {
            "kind": e.kind,
            "name": e.name,
            "class": f"{e.cls.__module__}.{e.cls.__qualname__}",
            "source": e.source_file,
            "plugin": e.plugin,
            "distribution": f"{e.distribution} {e.version}",
        }
        for e in entries
    ]
    if args.json:
        print(json.dumps(rows, indent=2))
        return 0
    columns = ("kind", "name", "distribution", "plugin", "source")
    widths = {c: max(len(c), *(len(r[c]) for r in rows)) for c in columns} if rows else {c: len(c) for c in columns}
    print("  ".join(c.upper().ljust(widths[c]) for c in columns))
    for row in rows:
        print("  ".join(row[c].ljust(widths[c]) for c in columns))
    return 0
