"""The ``gns`` subcommands (``gns_framework.cli.commands``): the built-in ones first, with their provider; a plugin's
command that ``--help`` lists and ``gns`` runs; two commands of one name, or a record that is not a Command, refused."""

from __future__ import annotations

import contextlib
import importlib

import pytest

from gns_framework import __version__
from gns_framework.cli import main
from gns_framework.cli.commands import BUILTIN_COMMANDS, command_entries, load_commands
from gns_framework.errors import PluginError
from gns_framework.hookspecs import hookimpl
from gns_framework.plugin_types import Command

COMMAND_MODULE = '''
"""A plugin's gns subcommand."""


def add_arguments(parser):
    parser.add_argument("--grains", type=int, default=3)


def run(args):
    print(f"sieved {args.grains} grains")
    return 0
'''


def _providing(*commands: Command) -> type:
    """A plugin whose ``gns_commands`` hook returns ``commands``."""

    class Plugin:
        @staticmethod
        @hookimpl
        def gns_commands():
            return list(commands)

    return Plugin


def test_a_plugin_adds_a_command_that_help_lists_and_gns_runs(tmp_path, monkeypatch, capsys):
    (tmp_path / "sieve_command.py").write_text(COMMAND_MODULE)
    monkeypatch.syspath_prepend(str(tmp_path))

    commands = load_commands(
        plugins=[("sieve-plugin", _providing(Command("sieve", "count the grains", "sieve_command")))]
    )
    assert next(iter(commands)) == "demo" and list(commands)[-1] == "sieve"  # built-ins first
    assert main(["sieve", "--grains", "7"], commands=commands) == 0
    assert "sieved 7 grains" in capsys.readouterr().out
    with contextlib.suppress(SystemExit):
        main(["--help"], commands=commands)
    assert "count the grains" in capsys.readouterr().out

    clashing = _providing(Command("train", "another train", "sieve_command"))
    with pytest.raises(PluginError, match=r"two gns commands are named 'train'.*clash-plugin"):
        load_commands(plugins=[("clash-plugin", clashing)])


def test_the_built_in_commands_come_in_their_order_from_gns_framework():
    entries = command_entries(load_entry_points=False)
    assert [entry.command for entry in entries] == list(BUILTIN_COMMANDS)
    assert {(entry.plugin, entry.distribution, entry.version) for entry in entries} == {
        ("builtin-commands", "gns-framework", __version__)
    }
    assert list(load_commands(load_entry_points=False)) == [command.name for command in BUILTIN_COMMANDS]


def test_every_built_in_command_module_has_the_two_functions_gns_calls():
    # gns imports a command's module only when it runs: a typo in a module name would show only then.
    for command in BUILTIN_COMMANDS:
        module = importlib.import_module(command.module)
        assert callable(module.add_arguments) and callable(module.run), command.name


def test_a_record_that_is_not_a_command_is_refused_naming_its_plugin():
    class TuplePlugin:
        @staticmethod
        @hookimpl
        def gns_commands():
            return [("sieve", "count the grains", "sieve_command")]

    with pytest.raises(PluginError, match=r"plugin 'tuple-plugin' .* returned \('sieve'.*not a .*Command"):
        load_commands(load_entry_points=False, plugins=[("tuple-plugin", TuplePlugin)])


def test_a_command_out_of_memory_ends_with_one_line(tmp_path, monkeypatch, capsys):
    (tmp_path / "greedy_command.py").write_text(
        "def add_arguments(parser):\n    pass\n\n\ndef run(args):\n    raise MemoryError\n"
    )
    monkeypatch.syspath_prepend(str(tmp_path))

    greedy = _providing(Command("greedy", "hold too much", "greedy_command"))
    assert main(["greedy"], commands=load_commands(plugins=[("greedy-plugin", greedy)])) == 1
    err = capsys.readouterr().err
    assert err.startswith("gns greedy: error: out of memory: ") and err.count("\n") == 1, err
