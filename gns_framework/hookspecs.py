"""Every extension point of gns-framework, one hook per component kind.

A plugin is a module (or object) exposed under the ``gns_framework`` entry-point
group; it implements any of these hooks with ``@gns_framework.hookimpl`` and
returns the component classes it provides. Built-in components register the
same way, from the ``gns_builtins`` package.
"""

from __future__ import annotations

import pluggy

PROJECT = "gns_framework"
hookspec = pluggy.HookspecMarker(PROJECT)
hookimpl = pluggy.HookimplMarker(PROJECT)


@hookspec
def gns_graph_builders() -> list[type]:
    """Return :class:`~gns_framework.contracts.GraphBuilder` subclasses."""


@hookspec
def gns_encoders() -> list[type]:
    """Return :class:`~gns_framework.contracts.Encoder` subclasses."""


@hookspec
def gns_processors() -> list[type]:
    """Return :class:`~gns_framework.contracts.Processor` subclasses."""


@hookspec
def gns_decoders() -> list[type]:
    """Return :class:`~gns_framework.contracts.Decoder` subclasses."""


@hookspec
def gns_integrators() -> list[type]:
    """Return :class:`~gns_framework.contracts.Integrator` subclasses."""


@hookspec
def gns_datasets() -> list[type]:
    """Return :class:`~gns_framework.contracts.Dataset` subclasses."""


@hookspec
def gns_materials() -> list[type]:
    """Return :class:`~gns_framework.contracts.Material` subclasses."""


@hookspec
def gns_simulators() -> list[type]:
    """Return :class:`~gns_framework.contracts.GroundTruthSimulator` subclasses."""


HOOK_OF_KIND = {
    "graph_builder": "gns_graph_builders",
    "encoder": "gns_encoders",
    "processor": "gns_processors",
    "decoder": "gns_decoders",
    "integrator": "gns_integrators",
    "dataset": "gns_datasets",
    "material": "gns_materials",
    "simulator": "gns_simulators",
}
