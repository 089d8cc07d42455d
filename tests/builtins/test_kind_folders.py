"""Every public module in a built-in kind folder is a registered component of that kind.

A newcomer who opens ``processors/`` (or any kind folder) finds components only:
each module there defines at least one component the registry serves under that
kind, and helpers shared by components live in underscore packages (``_kernels/``,
``datasets/_formats/``, ``simulators/_mpm/``). A helper dropped among the
components, or a component left unregistered, fails here by name.
"""

from __future__ import annotations

import importlib
import pkgutil
from pathlib import Path

import pytest

import gns_builtins
from gns_framework.contracts import COMPONENT_KINDS

FOLDERS = {
    "graph_builder": "graph_builders",
    "encoder": "encoders",
    "processor": "processors",
    "decoder": "decoders",
    "integrator": "integrators",
    "dataset": "datasets",
    "material": "materials",
    "simulator": "simulators",
}


def public_modules(folder: str) -> list[str]:
    path = Path(gns_builtins.__file__).parent / folder
    return sorted(info.name for info in pkgutil.iter_modules([str(path)]) if not info.name.startswith("_"))


def modules_without_a_component(registry, kind: str, folder: str | None = None) -> list[str]:
    """The public modules of ``folder`` (default: the kind's own) that define no registered ``kind``."""
    folder = folder or FOLDERS[kind]
    registered = {entry.cls.__module__ for entry in registry.entries(kind)}
    missing = []
    for name in public_modules(folder):
        module = f"gns_builtins.{folder}.{name}"
        importlib.import_module(module)
        if module not in registered:
            missing.append(module)
    return missing


def test_every_kind_has_its_folder():
    assert set(FOLDERS) == set(COMPONENT_KINDS)


@pytest.mark.parametrize("kind", sorted(FOLDERS))
def test_a_kind_folder_holds_components_only(registry, kind):
    assert public_modules(FOLDERS[kind]), f"{FOLDERS[kind]}/ has no component modules"
    assert modules_without_a_component(registry, kind) == [], (
        f"modules in gns_builtins/{FOLDERS[kind]}/ that register no {kind}: move helpers to an underscore package"
    )


def test_a_helper_among_the_components_is_named(registry):
    # The kernels folder, read as if it were processors/, holds helpers only: each is named.
    assert modules_without_a_component(registry, "processor", "_kernels") == [
        f"gns_builtins._kernels.{name}"
        for name in (
            "cell_list",
            "chunked",
            "edge_block",
            "edge_order",
            "fixed_capacity",
            "fused_kernels",
            "padded_cell_list",
            "segment_sum",
            "triton_edge_block",
            "triton_kernels",
            "verlet_list",
        )
    ]
