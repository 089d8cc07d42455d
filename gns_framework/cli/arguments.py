"""Arguments and argument types shared by the commands: bad values are argparse errors (usage, exit code 2)."""

from __future__ import annotations

import argparse
from pathlib import Path


def _int_at_least(text: str, minimum: int) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"invalid int value: {text!r}") from None
    if value < minimum:
        raise argparse.ArgumentTypeError(f"must be >= {minimum}, got {value}")
    return value


def positive_int(text: str) -> int:
    """An integer >= 1 (steps, counts)."""
    return _int_at_least(text, 1)


def non_negative_int(text: str) -> int:
    """An integer >= 0 (seeds)."""
    return _int_at_least(text, 0)


def non_negative_float(text: str) -> float:
    """A finite number >= 0 (margins, distances)."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"invalid float value: {text!r}") from None
    if not value >= 0 or value == float("inf"):
        raise argparse.ArgumentTypeError(f"must be a finite number >= 0, got {text}")
    return value


def positive_float(text: str) -> float:
    """A finite number > 0 (durations)."""
    value = non_negative_float(text)
    if value == 0:
        raise argparse.ArgumentTypeError(f"must be a finite number > 0, got {text}")
    return value


def ratio_above_one_or_never(text: str) -> float | None:
    """A finite number > 1, or ``never`` (None): how far one process may hold more than its share."""
    if text == "never":
        return None
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number > 1 or 'never', got {text!r}") from None
    if not 1 < value < float("inf"):
        raise argparse.ArgumentTypeError(f"expected a number > 1 or 'never', got {text}")
    return value


def add_allow_pickle(parser: argparse.ArgumentParser) -> None:
    """``--allow-pickle FOLDER``: the per-command grant to unpickle anything from one dataset folder."""
    parser.add_argument(
        "--allow-pickle",
        type=Path,
        metavar="FOLDER",
        help="let the npz layout unpickle any object from the dataset in FOLDER, which must be the dataset this "
        "command reads; only for data you trust, as unpickling can run code stored in the files. geoelements "
        "files of numpy arrays read without it. Recipes and checkpoints never grant it",
    )


def add_overwrite(parser: argparse.ArgumentParser, grant: str) -> None:
    """``--overwrite``: the grant to write where the output holds something else, ``grant`` saying what it lets
    the command replace or write into (off by default: nothing already written is lost unasked)."""
    parser.add_argument("--overwrite", action="store_true", help=grant)
