"""``gns plugins``: what the installed plugins provide, each with its source and distribution.

Components by kind, metrics and commands, then the particle-type ids the materials
take and those still free, so a new material's author picks one without reading
any source.
"""

from __future__ import annotations

import argparse
import importlib.util
import inspect
import json

from ..contracts import COMPONENT_KINDS
from ..plugin_types import worst_of
from ..plugins import ComponentEntry, MetricEntry, Registry, load_registry
from .commands import CommandEntry, command_entries

KINDS = [*COMPONENT_KINDS, "metric", "command"]
COLUMNS = ("kind", "name", "distribution", "plugin", "source")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--kind", choices=KINDS, help="only this kind (a component kind, metric or command)")
    parser.add_argument("--json", action="store_true", help="print JSON rows instead of tables")


def run(args: argparse.Namespace) -> int:
    registry = load_registry()
    kinds = [args.kind] if args.kind else KINDS
    rows = [_component_row(e) for kind in kinds if kind in COMPONENT_KINDS for e in registry.entries(kind)]
    if "metric" in kinds:
        rows += [_metric_row(e) for e in registry.metric_entries()]
    if "command" in kinds:
        rows += [_command_row(e) for e in command_entries()]
    if args.json:
        print(json.dumps(rows, indent=2))
        return 0
    print(_table(rows, COLUMNS))
    if "metric" in kinds:
        tracked = ", ".join(f"{name} ({m.name})" for name, m in registry.validation_metrics().items())
        print(
            f"\nmeasured in training's validation rollouts (training.best_metric chooses one, as the mean "
            f"or as {worst_of('<name>')}, the worst rollout): {tracked}"
        )
    if "material" in kinds:
        print()
        print(_particle_types(registry))
    return 0


def _component_row(entry: ComponentEntry) -> dict:
    cls = entry.cls
    facts = {"particle_type": cls.particle_type, "kinematic": cls.kinematic} if entry.kind == "material" else {}
    row = _row(entry, entry.kind, entry.name, entry.source_file, {"class": f"{cls.__module__}.{cls.__qualname__}"})
    return row | facts


def _metric_row(entry: MetricEntry) -> dict:
    metric = entry.metric
    described = {"unit": metric.unit, "validation": metric.tracked_as}
    return _row(entry, "metric", metric.name, _function_file(metric.function), described)


def _command_row(entry: CommandEntry) -> dict:
    command = entry.command
    described = {"help": command.help, "module": command.module}
    return _row(entry, "command", command.name, _module_file(command.module), described)


def _row(entry: ComponentEntry | MetricEntry | CommandEntry, kind: str, name: str, source: str, described: dict):
    """One row of the listing: kind and name, what describes the entry, its source file, and who provides it."""
    return {"kind": kind, "name": name, **described, "source": source, **_provider(entry)}


def _function_file(function) -> str:
    """The file defining ``function``; "<unknown>" for a callable object or partial (no file of its own)."""
    try:
        return inspect.getsourcefile(function) or "<unknown>"
    except TypeError:
        return "<unknown>"


def _module_file(module: str) -> str:
    """The file of ``module``, found without running it (its parent packages are imported); "<not found>"."""
    try:
        spec = importlib.util.find_spec(module)
    except (ImportError, ValueError):
        return "<not found>"
    return spec.origin if spec is not None and spec.origin else "<not found>"


def _provider(entry: ComponentEntry | MetricEntry | CommandEntry) -> dict:
    """The plugin and the installed distribution (with its version) that provide an entry."""
    return {"plugin": entry.plugin, "distribution": f"{entry.distribution} {entry.version}"}


def _table(rows: list[dict], columns: tuple[str, ...]) -> str:
    widths = {c: max([len(c), *(len(str(r[c])) for r in rows)]) for c in columns}
    lines = ["  ".join(c.upper().ljust(widths[c]) for c in columns)]
    lines += ["  ".join(str(r[c]).ljust(widths[c]) for c in columns) for r in rows]
    return "\n".join(line.rstrip() for line in lines)


def _particle_types(registry: Registry) -> str:
    """The taken particle-type ids, one material each, and the free ones as ranges."""
    rows = [
        {
            "particle type": str(e.cls.particle_type),
            "material": e.name,
            "kinematic": "yes" if e.cls.kinematic else "no",
            "distribution": f"{e.distribution} {e.version}",
        }
        for e in sorted(registry.entries("material"), key=lambda e: e.cls.particle_type)
    ]
    columns = ("particle type", "material", "kinematic", "distribution")
    taken = _table(rows, columns) if rows else "no material installed"
    return f"{taken}\nfree particle types: {id_ranges(registry.free_particle_types())} (a new material takes one)"


def id_ranges(ids: list[int]) -> str:
    """Sorted ids as ranges: ``[0, 1, 2, 4, 9, 10]`` -> ``"0-2, 4, 9-10"`` (``"none"`` when empty)."""
    runs: list[list[int]] = []
    for i in ids:
        if runs and i == runs[-1][1] + 1:
            runs[-1][1] = i
        else:
            runs.append([i, i])
    return ", ".join(str(a) if a == b else f"{a}-{b}" for a, b in runs) or "none"
