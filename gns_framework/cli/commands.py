"""The ``gns`` subcommands: collected through the ``gns_commands`` hook, the built-in ones included.

Command plugins register under their own entry-point group, ``gns_framework.commands``,
so collecting every command loads no component plugin (nor torch) and ``gns --help``
stays fast. The built-in commands are this module's own hook implementation, always
registered: ``gns`` keeps them under ``$GNS_DISABLE_PLUGINS=*``.
"""

from __future__ import annotations

import sys
from collections.abc import Iterable
from dataclasses import dataclass

from .. import __version__
from ..errors import PluginError
from ..hookspecs import hookimpl
from ..plugin_types import Command
from ..plugins import COMMAND_GROUP, DISABLE_ENV, hook_results, make_plugin_manager

BUILTIN_COMMANDS = (
    Command(
        "demo",
        "roll the pretrained model out on sand collapses it never saw, train a short model, report error vs run time",
        "gns_framework.cli.demo",
    ),
    Command(
        "plugins",
        "list installed components, metrics and commands with their source and distribution, "
        "and the free particle types",
        "gns_framework.cli.plugins",
    ),
    Command("check", "validate recipes and report every problem at once", "gns_framework.cli.check"),
    Command("train", "train a learned simulator from a recipe", "gns_framework.cli.train"),
    Command("rollout", "roll a trained simulator out on a dataset split", "gns_framework.cli.rollout"),
    Command(
        "evaluate",
        "report error against run time of trained models and the ground-truth simulator",
        "gns_framework.cli.evaluate",
    ),
    Command(
        "invert",
        "recover material properties or initial velocities from an observed trajectory through a trained model",
        "gns_framework.cli.invert",
    ),
    Command(
        "track-sync",
        "send a run's metrics its MLflow run missed (an outage at the end of training), and its final status",
        "gns_framework.cli.track_sync",
    ),
    Command("render", "write VTK frames and a prediction-vs-truth GIF of a rollout file", "gns_framework.cli.render"),
    Command(
        "import-geoelements",
        "convert a geoelements/gns checkpoint (model-<step>.pt) into a gns-framework checkpoint",
        "gns_framework.cli.import_geoelements",
    ),
    Command(
        "generate",
        "simulate a scene spec into a dataset of train/valid/test trajectories",
        "gns_framework.cli.generate",
    ),
    Command(
        "convert",
        "convert a dataset between layouts (safe, npz, tfrecord, lagrangebench)",
        "gns_framework.cli.convert",
    ),
    Command(
        "stability",
        "run the stiff-integrator and extreme-input cases and print each outcome with its figures",
        "gns_framework.cli.stability",
    ),
    Command(
        "envelope",
        "what a model was trained on, in a scene file's terms; check a scene file against it before generating data",
        "gns_framework.cli.envelope",
    ),
    Command(
        "compare",
        "tracked runs of any experiments side by side: metrics, params and differing recipe fields, with a plot",
        "gns_framework.cli.compare",
    ),
)


@hookimpl
def gns_commands() -> list[Command]:
    return list(BUILTIN_COMMANDS)


@dataclass(frozen=True)
class CommandEntry:
    """A ``gns`` subcommand and the plugin that provides it."""

    command: Command
    plugin: str
    distribution: str
    version: str


def load_commands(load_entry_points: bool = True, plugins: Iterable[tuple[str, object]] = ()) -> dict[str, Command]:
    """Every ``gns`` subcommand by name: the built-in ones, then those of command plugins.

    Args:
        load_entry_points: load the plugins of the ``gns_framework.commands`` group.
        plugins: extra ``(name, module_or_object)`` command plugins (tests, embedding).
    """
    return {entry.command.name: entry.command for entry in command_entries(load_entry_points, plugins)}


def command_entries(load_entry_points: bool = True, plugins: Iterable[tuple[str, object]] = ()) -> list[CommandEntry]:
    """Every ``gns`` subcommand with its provider, as :func:`load_commands` orders them; two of one name are an
    error."""
    builtin = [("builtin-commands", sys.modules[__name__])]
    pm, origin, _ = make_plugin_manager(load_entry_points, [*builtin, *plugins], group=COMMAND_GROUP)
    origin["builtin-commands"] = ("gns-framework", __version__)
    entries: dict[str, tuple[CommandEntry, str]] = {}
    results = hook_results(pm, origin, "gns_commands")
    results.sort(key=lambda result: result[0].plugin_name != "builtin-commands")  # built-ins first, in --help too
    for impl, where, records in results:
        for command in records:
            if not isinstance(command, Command):
                raise PluginError(f"{where} returned {command!r}, which is not a gns_framework.plugin_types.Command")
            if command.name in entries:
                raise PluginError(
                    f"two gns commands are named {command.name!r}: from {entries[command.name][1]} and from {where}; "
                    f"uninstall one of them, or disable its plugin with the environment variable {DISABLE_ENV}"
                )
            entries[command.name] = (CommandEntry(command, impl.plugin_name, *origin[impl.plugin_name]), where)
    return [entry for entry, _ in entries.values()]
