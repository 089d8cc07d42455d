"""``gns plugins``: components, metrics, commands, and the particle-type ids taken and free."""

from __future__ import annotations

import json

import pytest

from gns_framework.cli import main
from gns_framework.cli import plugins as plugins_command
from gns_framework.cli.plugins import id_ranges
from gns_framework.contracts import Material
from gns_framework.hookspecs import hookimpl
from gns_framework.plugins import load_registry


class _Ballast(Material):
    name = "ballast"
    particle_type = 4
    kinematic = True
    constitutive_model = "rigid"


class _BallastPlugin:
    @staticmethod
    @hookimpl
    def gns_materials():
        return [_Ballast]


@pytest.fixture
def with_ballast(monkeypatch):
    """gns plugins sees one more material, of type 4, registered in process."""
    registry = load_registry(plugins=[("ballast", _BallastPlugin)])
    monkeypatch.setattr(plugins_command, "load_registry", lambda: registry)
    return registry


def run_plugins(capsys, *args: str) -> str:
    assert main(["plugins", *args]) == 0
    return capsys.readouterr().out


def test_the_table_lists_components_metrics_and_commands(capsys):
    rows = {tuple(line.split()[:2]) for line in run_plugins(capsys).splitlines() if line.strip()}
    assert {
        ("processor", "interaction_network"),
        ("material", "clay"),
        ("metric", "mse_full"),
        ("metric", "runout_error"),
        ("command", "train"),
        ("command", "plugins"),
    } <= rows


def test_the_particle_types_taken_and_free_are_listed(capsys, with_ballast):
    out = run_plugins(capsys)
    taken = out.split("PARTICLE TYPE")[1].splitlines()[1:-1]
    assert [line.split()[:3] for line in taken] == [
        ["3", "rigid", "yes"],
        ["4", "ballast", "yes"],
        ["5", "water", "no"],
        ["6", "sand", "no"],
        ["7", "goop", "no"],
        ["8", "clay", "no"],
    ]
    assert out.rstrip().splitlines()[-1] == "free particle types: 0-2, 9-1023 (a new material takes one)"


def test_one_kind_lists_only_its_rows(capsys):
    out = run_plugins(capsys, "--kind", "metric")
    table, _, tracked = out.partition("\n\n")
    kinds = {line.split()[0] for line in table.splitlines()[1:]}
    assert kinds == {"metric"} and "free particle types" not in out
    assert "training.best_metric" in tracked and "valid_rollout_deposit_error_pct (deposit_error_pct)" in tracked
    assert "<name>_worst, the worst rollout" in tracked
    assert "free particle types: 0-2, 4, 9-1023" in run_plugins(capsys, "--kind", "material")


def test_json_rows_carry_each_kinds_own_fields(capsys):
    rows = json.loads(run_plugins(capsys, "--json"))
    by_kind = {}
    for row in rows:
        by_kind.setdefault(row["kind"], {})[row["name"]] = row
    assert by_kind["material"]["clay"]["particle_type"] == 8 and by_kind["material"]["rigid"]["kinematic"] is True
    assert by_kind["metric"]["mse_full"]["unit"].startswith("L^2")
    assert by_kind["metric"]["mse_full"]["distribution"].startswith("gns-framework ")
    assert (
        by_kind["metric"]["mse_full"]["validation"] == "valid_rollout_mse"
        and by_kind["metric"]["mse_final"]["validation"] is None
    )
    train = by_kind["command"]["train"]
    assert train["module"] == "gns_framework.cli.train" and train["source"].endswith("train.py")
    assert all(row["source"].endswith(".py") and row["plugin"] for row in rows)


@pytest.mark.parametrize("ids, expected", [([], "none"), ([4], "4"), ([0, 1, 2, 4, 9, 10], "0-2, 4, 9-10")])
def test_id_ranges(ids, expected):
    assert id_ranges(ids) == expected
