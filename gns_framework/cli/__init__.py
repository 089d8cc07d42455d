"""The ``gns`` command line. Each subcommand lives in its own module of this package.

A command module defines ``add_arguments(parser)`` and ``run(args) -> int``; its
one-line help is its entry in :data:`COMMANDS`. Modules are imported only when their command runs (or for
``--help``), so ``gns --help`` stays fast and imports no heavy optional package.
"""

from __future__ import annotations

import argparse
import importlib
import sys

from ..errors import GnsError

COMMANDS: dict[str, str] = {
    "demo": "simulate a small sand dataset, train the reference recipe briefly, roll out, report error vs run time",
    "plugins": "list installed components by kind, with their source and distribution",
    "check": "validate recipes and report every problem at once",
    "train": "train a learned simulator from a recipe",
    "rollout": "roll a trained simulator out on a dataset split",
    "evaluate": "report error against run time of trained models and the ground-truth simulator",
    "invert": "recover material properties or initial velocities from an observed trajectory through a trained model",
    "render": "write VTK frames and a prediction-vs-truth GIF of a rollout file",
    "import-geoelements": "convert a geoelements/gns checkpoint (model-<step>.pt) into a gns-framework checkpoint",
    "generate": "simulate a scene spec into a dataset of train/valid/test trajectories",
    "convert": "convert a dataset between layouts (safe, npz, tfrecord, lagrangebench)",
    "stability": "run the stiff-integrator and extreme-input cases and print each outcome with its figures",
    "compare": "tracked runs of any experiments side by side: metrics, params and differing recipe fields, with a plot",
}
"""Subcommand name -> one-line help. The module is ``gns_framework.cli.<name>``."""


def _command_module(name: str):
    return importlib.import_module(f"{__name__}.{name.replace('-', '_')}")


def build_parser(load_commands: list[str] | None = None) -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="gns",
        description="gns-framework: train, roll out and evaluate learned particle simulators (GNS).",
    )
    parser.add_argument("--version", action="version", version=f"gns-framework {_version()}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name, help_text in COMMANDS.items():
        command_parser = sub.add_parser(name, help=help_text, description=help_text)
        if load_commands is None or name in load_commands:
            _command_module(name).add_arguments(command_parser)
    return parser


def _version() -> str:
    from .. import __version__

    return __version__


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    # Only the chosen command's module is imported; top-level --help imports none.
    chosen = [a for a in argv if a in COMMANDS][:1]
    parser = build_parser(load_commands=chosen)
    args = parser.parse_args(argv)
    if args.command is None:
        parser.print_help()
        return 0
    try:
        return int(_command_module(args.command).run(args) or 0)
    except GnsError as exc:
        print(f"gns {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"gns {args.command}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
