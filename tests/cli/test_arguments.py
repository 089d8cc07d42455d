"""The argument types the commands share (``gns_framework.cli.arguments``): each accepts its range, boundary
included, and refuses the rest as an argparse error (a usage message and exit code 2, never a traceback)."""

from __future__ import annotations

import argparse
from pathlib import Path

import pytest

from gns_framework.cli.arguments import (
    add_allow_pickle,
    add_overwrite,
    non_negative_float,
    non_negative_int,
    positive_float,
    positive_int,
    ratio_above_one_or_never,
)


def test_counts_start_at_1_and_seeds_at_0():
    assert positive_int("1") == 1 and positive_int("250") == 250
    assert non_negative_int("0") == 0 and non_negative_int("7") == 7
    with pytest.raises(argparse.ArgumentTypeError, match=r"^must be >= 1, got 0$"):
        positive_int("0")
    with pytest.raises(argparse.ArgumentTypeError, match=r"^must be >= 0, got -1$"):
        non_negative_int("-1")


@pytest.mark.parametrize("text", ["many", "2.5", "1e3", ""])
def test_what_is_not_a_whole_number_is_named_as_written(text):
    with pytest.raises(argparse.ArgumentTypeError, match=rf"^invalid int value: {text!r}$"):
        positive_int(text)


def test_distances_are_finite_and_not_negative():
    assert non_negative_float("0") == 0.0 and non_negative_float("2.5e-3") == 2.5e-3
    for text in ("-0.1", "nan", "inf", "-inf"):
        # nan fails every comparison: a test written as `value < 0` would let it through.
        with pytest.raises(argparse.ArgumentTypeError, match=rf"^must be a finite number >= 0, got {text}$"):
            non_negative_float(text)
    with pytest.raises(argparse.ArgumentTypeError, match=r"^invalid float value: 'far'$"):
        non_negative_float("far")


def test_durations_are_finite_and_positive():
    assert positive_float("0.5") == 0.5 and positive_float("10") == 10.0
    for text in ("0", "-1", "nan", "inf"):
        with pytest.raises(argparse.ArgumentTypeError, match=r"^must be a finite number >"):
            positive_float(text)


def test_a_bad_value_on_the_command_line_is_a_usage_error_naming_the_option(capsys):
    parser = argparse.ArgumentParser(prog="gns x")
    parser.add_argument("--steps", type=positive_int)
    with pytest.raises(SystemExit) as exited:
        parser.parse_args(["--steps", "-5"])
    assert exited.value.code == 2
    assert "gns x: error: argument --steps: must be >= 1, got -5" in capsys.readouterr().err


def test_allow_pickle_names_one_folder_and_is_off_by_default():
    parser = argparse.ArgumentParser()
    add_allow_pickle(parser)
    assert parser.parse_args([]).allow_pickle is None
    assert parser.parse_args(["--allow-pickle", "data/old"]).allow_pickle == Path("data/old")


def test_a_rebalance_ratio_is_a_number_above_one_or_never():
    assert ratio_above_one_or_never("1.5") == 1.5 and ratio_above_one_or_never("never") is None
    for text in ("1", "0.9", "-2", "inf", "nan"):
        with pytest.raises(argparse.ArgumentTypeError, match=rf"^expected a number > 1 or 'never', got {text}$"):
            ratio_above_one_or_never(text)
    with pytest.raises(argparse.ArgumentTypeError, match=r"^expected a number > 1 or 'never', got 'often'$"):
        ratio_above_one_or_never("often")


def test_overwrite_is_off_unless_asked_and_its_help_says_what_it_replaces():
    parser = argparse.ArgumentParser()
    add_overwrite(parser, "replace DIR whole even when it holds something else")
    assert parser.parse_args([]).overwrite is False
    assert parser.parse_args(["--overwrite"]).overwrite is True
    assert "replace DIR whole" in parser.format_help()
    with pytest.raises(SystemExit):
        parser.parse_args(["--overwrite=yes"])
