"""``gns demo`` (``gns_framework.cli.demo``): the whole pipeline end to end with a tiny short model, the error for a
missing pretrained model, and how the models are grouped into reports by how they see the data."""

from __future__ import annotations

from types import SimpleNamespace

import yaml
from cli_runner import gns
from tiny import tiny_recipe_mapping

from gns_framework.cli.demo import _by_data_view


def test_demo_runs_end_to_end(tmp_path):
    """The demo's whole pipeline with a tiny short model: simulate, train, roll out the shipped model, animate,
    report."""
    recipe = tmp_path / "tiny.yaml"
    recipe.write_text(yaml.safe_dump(tiny_recipe_mapping(tmp_path / "unused", tmp_path / "unused-run")))
    demo = tmp_path / "demo"
    result = gns(
        "demo",
        "--steps",
        "2",
        "--repeats",
        "1",
        "--held-out",
        "1",
        "--recipe",
        str(recipe),
        "--no-progress",
        "--out",
        str(demo),
    )
    assert result.returncode == 0, result.stderr
    assert "short model: validation one-step loss" in result.stdout
    assert "(seed 2)" in result.stdout, "the held-out collapses come from a seed the shipped model never trained on"
    assert (demo / "rollout.gif").is_file()
    # The shipped model steps over 2 frames, the tiny one over 1: one report each, both against the simulator.
    shipped, short = (demo / "report" / "report.md").read_text(), (demo / "report_2" / "report.md").read_text()
    assert "| sand2d-fast-pretrained | learned |" in shipped and "| tiny-2-steps | learned |" in short
    for table in (shipped, short):
        assert "mls_mpm grid 48 x 40 substeps (reference)" in table
    assert (demo / "report" / "error_vs_time.png").is_file()


def test_demo_without_the_pretrained_model_says_where_it_should_be(tmp_path):
    result = gns("demo", "--model", str(tmp_path / "missing.pt"), "--out", str(tmp_path / "demo"))
    assert result.returncode == 2
    assert "missing.pt: pretrained model not found" in result.stderr
    assert not (tmp_path / "demo").exists()


def model_seeing(stride: int, history: int) -> SimpleNamespace:
    """What ``_by_data_view`` reads of a loaded model: its recipe's frame stride and its setup's history."""
    return SimpleNamespace(
        recipe=SimpleNamespace(dataset=SimpleNamespace(frame_stride=stride)),
        simulator=SimpleNamespace(setup=SimpleNamespace(history=history)),
    )


def test_models_share_a_report_only_when_they_see_the_data_alike():
    a, b, c, d = model_seeing(2, 6), model_seeing(1, 6), model_seeing(2, 6), model_seeing(2, 4)
    groups = _by_data_view([("a", a), ("b", b), ("c", c), ("d", d)])
    # Same stride and history (a, c) compare in one report; another stride (b) or history (d) gets its own.
    # Groups keep the order of their first model, so the pretrained model's report comes first.
    assert [[name for name, _ in group] for group in groups] == [["a", "c"], ["b"], ["d"]]
    assert groups[0][1][1] is c
