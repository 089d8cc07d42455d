"""The records plugin hooks return besides classes: Metric (and its tracked names) and Command."""

from __future__ import annotations

import dataclasses
import subprocess
import sys

import pytest

from gns_framework.plugin_types import Command, Metric, worst_of


def _metric(**fields) -> Metric:
    return Metric("runout_error", "%, runout error", lambda pair: None, **fields)


def test_a_metric_is_for_evaluation_only_unless_it_names_its_validation():
    metric = _metric()
    assert metric.validation is None and metric.tracked_as is None and metric.pairwise is False


def test_a_validated_metric_is_tracked_as_valid_rollout_its_validation_name():
    # The validation name, not the metric's own (a family's pattern may differ from what training tracks).
    metric = _metric(validation="runout_pct")
    assert metric.tracked_as == "valid_rollout_runout_pct"
    assert worst_of(metric.tracked_as) == "valid_rollout_runout_pct_worst"


def test_the_records_are_frozen():
    with pytest.raises(dataclasses.FrozenInstanceError):
        _metric().name = "other"
    with pytest.raises(dataclasses.FrozenInstanceError):
        Command("sieve", "sieve the data", "sieve_plugin.command").module = "elsewhere"


def test_a_command_names_the_module_that_implements_it():
    command = Command("sieve", "sieve the data", "sieve_plugin.command")
    assert (command.name, command.help, command.module) == ("sieve", "sieve the data", "sieve_plugin.command")


def test_importing_the_records_loads_neither_torch_nor_the_rest_of_gns_framework():
    # gns --help collects commands through these records: it must not pay for torch or the components.
    code = (
        "import sys, gns_framework.plugin_types; "
        "print(sorted(m for m in sys.modules if m == 'torch' or m.startswith('gns_framework.')))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "['gns_framework.plugin_types']"
