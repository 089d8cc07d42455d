"""The ``gns`` command line. Each built-in subcommand lives in its own module of this package.

A command is a :class:`~gns_framework.plugin_types.Command` record (name, one-line
help, module) from the ``gns_commands`` hook (:mod:`gns_framework.cli.commands`); a
plugin adds one the same way. Its module defines ``add_arguments(parser)`` and
``run(args) -> int`` and is imported only when its command runs (or for its own
``--help``), so ``gns --help`` stays fast and imports no heavy optional package.
"""

from __future__ import annotations

import argparse
import functools
import importlib
import os
import sys
import warnings

from ..errors import GnsError, PluginWarning
from ..plugin_types import Command
from .commands import load_commands


def _command_module(command: Command):
    return importlib.import_module(command.module)


def build_parser(
    chosen: list[str] | None = None, commands: dict[str, Command] | None = None
) -> argparse.ArgumentParser:
    """The ``gns`` parser; only the ``chosen`` commands' modules are imported (all when None).

    ``commands``: the subcommands by name (default: :func:`~gns_framework.cli.commands.load_commands`).
    """
    commands = load_commands() if commands is None else commands
    parser = argparse.ArgumentParser(
        prog="gns",
        description="gns-framework: train, roll out and evaluate learned particle simulators (GNS).",
    )
    parser.add_argument("--version", action="version", version=f"gns-framework {_version()}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name, command in commands.items():
        command_parser = sub.add_parser(name, help=command.help, description=command.help)
        if chosen is None or name in chosen:
            _command_module(command).add_arguments(command_parser)
    return parser


def _version() -> str:
    from .. import __version__

    return __version__


def _show_warning(default, message, category, filename, lineno, file=None, line=None) -> None:
    """A :class:`~gns_framework.errors.PluginWarning` as one ``gns: warning:`` line; others as ``default`` shows them.

    A plugin warning is about the installation, not about the line of code that
    loaded the plugins, so the file, line and source Python adds would only hide it.
    """
    if issubclass(category, PluginWarning):
        print(f"gns: warning: {message}", file=sys.stderr if file is None else file)
    else:
        default(message, category, filename, lineno, file, line)


def main(argv: list[str] | None = None, commands: dict[str, Command] | None = None) -> int:
    """Run ``gns`` with ``argv``; ``commands`` as in :func:`build_parser`. Returns the exit status."""
    with warnings.catch_warnings():
        warnings.showwarning = functools.partial(_show_warning, warnings.showwarning)
        return _run(list(sys.argv[1:] if argv is None else argv), commands)


def _run(argv: list[str], commands: dict[str, Command] | None) -> int:
    try:
        commands = load_commands() if commands is None else commands
    except GnsError as exc:
        print(f"gns: error: {exc}", file=sys.stderr)
        return 2
    # Only the chosen command's module is imported; top-level --help imports none.
    chosen = [a for a in argv if a in commands][:1]
    parser = build_parser(chosen, commands)
    args = parser.parse_args(argv)
    if args.command is None:
        parser.print_help()
        return 0
    try:
        return int(_command_module(commands[args.command]).run(args) or 0)
    except GnsError as exc:
        print(f"gns {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"gns {args.command}: interrupted", file=sys.stderr)
        return 130
    except MemoryError:
        # What the command holds did not fit what this process may use: a resource, not a bug to trace back.
        print(
            f"gns {args.command}: error: out of memory: what this command holds does not fit the memory this "
            "process may use (a scene split over processes needs less in each: docs/domain_decomposition.md)",
            file=sys.stderr,
        )
        return 1
    except BrokenPipeError:
        # The reader of stdout left (``gns plugins --json | head``): not an error of the command. Python
        # would report the failed flush of stdout at exit, so stdout goes to nowhere from here on.
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 141  # 128 + SIGPIPE, as a shell reports a pipe's writer stopped by its reader


if __name__ == "__main__":
    sys.exit(main())
