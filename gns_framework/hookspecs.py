"""Every extension point of gns-framework: one hook per component kind, the metrics and the commands hook.

A plugin is a module (or object) exposed under the ``gns_framework`` entry-point
group; it implements any of these hooks with ``@hookimpl`` (from this module) and
returns the component classes (or metric records) it provides. Built-in
components and metrics register the same way, from the ``gns_builtins`` package.
Commands have their own entry-point group (:mod:`gns_framework.cli.commands`),
so that ``gns --help`` loads no component.

The kinds are listed once, in :data:`gns_framework.contracts.COMPONENT_KINDS`;
the hook of kind ``k`` is ``gns_<k>s``.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import pluggy

if TYPE_CHECKING:  # annotations only: importing the contracts would load torch for `gns --help`
    from .contracts import (
        Dataset,
        Decoder,
        Encoder,
        GraphBuilder,
        GroundTruthSimulator,
        Integrator,
        Material,
        Processor,
    )
    from .plugin_types import Command, Metric

PROJECT = "gns_framework"
hookspec = pluggy.HookspecMarker(PROJECT)
hookimpl = pluggy.HookimplMarker(PROJECT)


@hookspec
def gns_graph_builders() -> list[type[GraphBuilder]]:
    """Return :class:`~gns_framework.contracts.GraphBuilder` subclasses."""


@hookspec
def gns_encoders() -> list[type[Encoder]]:
    """Return :class:`~gns_framework.contracts.Encoder` subclasses."""


@hookspec
def gns_processors() -> list[type[Processor]]:
    """Return :class:`~gns_framework.contracts.Processor` subclasses."""


@hookspec
def gns_decoders() -> list[type[Decoder]]:
    """Return :class:`~gns_framework.contracts.Decoder` subclasses."""


@hookspec
def gns_integrators() -> list[type[Integrator]]:
    """Return :class:`~gns_framework.contracts.Integrator` subclasses."""


@hookspec
def gns_datasets() -> list[type[Dataset]]:
    """Return :class:`~gns_framework.contracts.Dataset` subclasses."""


@hookspec
def gns_materials() -> list[type[Material]]:
    """Return :class:`~gns_framework.contracts.Material` subclasses."""


@hookspec
def gns_simulators() -> list[type[GroundTruthSimulator]]:
    """Return :class:`~gns_framework.contracts.GroundTruthSimulator` subclasses."""


@hookspec
def gns_metrics() -> list[Metric]:
    """Return :class:`~gns_framework.plugin_types.Metric` records (name, unit, function).

    ``gns evaluate``, rollout files and validation rollouts report every installed
    metric; the built-in ones come from ``gns_builtins.metrics`` through this hook.
    """


@hookspec
def gns_commands() -> list[Command]:
    """Return :class:`~gns_framework.plugin_types.Command` records: ``gns`` subcommands.

    Implemented by plugins of the ``gns_framework.commands`` entry-point group (not
    ``gns_framework``), so that ``gns --help`` loads no component; the built-in
    commands come from :mod:`gns_framework.cli.commands` through this hook.
    """


def hook_of_kind(kind: str) -> str:
    """The hook of a component kind (a key of :data:`gns_framework.contracts.COMPONENT_KINDS`): ``gns_<kind>s``."""
    return f"gns_{kind}s"
