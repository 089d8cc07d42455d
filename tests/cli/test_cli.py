"""End-to-end: the ``gns`` command as a user runs it, in subprocesses (in process where a test looks inside)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
import yaml
from tiny import tiny_recipe_mapping

from gns_framework.cli import main


def gns(*args: str, cwd: Path | None = None) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "gns_framework.cli", *args], capture_output=True, text=True, cwd=cwd, timeout=600
    )


def test_help_lists_every_command():
    result = gns("--help")
    assert result.returncode == 0
    for command in ("demo", "plugins", "check", "train", "rollout", "render", "import-geoelements"):
        assert command in result.stdout
    for command in ("train", "rollout", "check", "plugins"):
        sub = gns(command, "--help")
        assert sub.returncode == 0 and "usage: gns " + command in sub.stdout


def test_plugins_lists_builtins_with_source():
    rows = json.loads(gns("plugins", "--json").stdout)
    found = {(r["kind"], r["name"]) for r in rows}
    assert {("processor", "interaction_network"), ("material", "water"), ("dataset", "safe")} <= found
    assert all(r["source"].endswith(".py") and r["distribution"] for r in rows)
    table = gns("plugins", "--kind", "integrator").stdout
    assert "semi_implicit_euler" in table and "interaction_network" not in table


def test_check_reports_each_problem_and_fails(tmp_path):
    bad = tmp_path / "bad.yaml"
    bad.write_text(
        "name: x\ndataset: {path: d}\nmodel: {latent_size: 0, procesor: {name: interaction_network}}\ntraning: {}\n"
    )
    result = gns("check", "--no-data", str(bad), "recipes")  # the recipes alone: their data may not be made here
    assert result.returncode == 1
    assert "3 problem(s)" in result.stderr
    for location in ("model.latent_size", "model.procesor", "traning"):
        assert location in result.stderr
    assert "recipes/water2d.yaml: ok" in result.stdout


def test_bad_arguments_exit_2_with_a_message(tmp_path):
    result = gns("train", "recipes/water2d.yaml", "--steps", "many")
    assert result.returncode == 2 and "invalid int value" in result.stderr
    missing = gns("train", str(tmp_path / "nope.yaml"))
    assert missing.returncode == 2 and "nope.yaml" in missing.stderr and "file not found" in missing.stderr


def test_train_resume_rollout_render(dataset_multimaterial, tmp_path):
    recipe = tmp_path / "tiny.yaml"
    raw = tiny_recipe_mapping(dataset_multimaterial, tmp_path / "run")
    raw["training"]["log_every"] = 2
    recipe.write_text(yaml.safe_dump(raw))
    first = gns("train", str(recipe), "--steps", "3", "--no-progress")
    assert first.returncode == 0, first.stderr
    resumed = gns("train", str(recipe), "--steps", "5", "--resume", "--no-progress")
    assert resumed.returncode == 0, resumed.stderr
    assert "resumed from" in resumed.stdout and "to step 5" in resumed.stdout
    assert "step 4 of 5" in resumed.stdout and "to go" in resumed.stdout, "without a bar, the run says how long is left"
    checkpoint = tmp_path / "run" / "checkpoints" / "checkpoint-000000005.pt"
    # Trained for 5 steps on 3 trajectories, the model's envelope is narrow: the test split's friction lies outside.
    refused = gns("rollout", str(checkpoint), "--steps", "4", "--out", str(tmp_path / "rollouts"), "--no-progress")
    assert refused.returncode == 2 and "outside the envelope of" in refused.stderr
    assert "property friction" in refused.stderr and "--outside-envelope" in refused.stderr
    assert not (tmp_path / "rollouts").exists()
    rolled = gns(
        "rollout",
        str(checkpoint),
        "--steps",
        "4",
        "--out",
        str(tmp_path / "rollouts"),
        "--no-progress",
        "--outside-envelope",
    )
    assert rolled.returncode == 0, rolled.stderr
    assert "warning: outside the envelope of" in rolled.stderr
    rollout_file = tmp_path / "rollouts" / "test_0000.npz"
    with np.load(rollout_file, allow_pickle=False) as z:
        assert z["predicted_rollout"].shape[0] == 4
        assert "property friction" in json.loads(str(z["metadata_json"]))["outside_envelope"][0]
    # In process, to see the dtypes of the Linear layers' products as the rollout runs them.
    products = []

    def record(module, inputs, output):
        if isinstance(module, torch.nn.Linear):
            products.append(output.dtype)

    hook = torch.nn.modules.module.register_module_forward_hook(record)
    try:
        low = main(
            [
                "rollout",
                str(checkpoint),
                "--steps",
                "4",
                "--out",
                str(tmp_path / "low"),
                "--no-progress",
                "--precision",
                "bfloat16",
                "--outside-envelope",
            ]
        )
    finally:
        hook.remove()
    assert low == 0
    assert products and set(products) == {torch.bfloat16}, "--precision bfloat16 left products in float32"
    with np.load(rollout_file) as full, np.load(tmp_path / "low" / "test_0000.npz") as bf16:
        assert bf16["predicted_rollout"].dtype == full["predicted_rollout"].dtype == np.float32
        assert np.allclose(bf16["predicted_rollout"], full["predicted_rollout"], atol=1e-3)
    # --batch rolls the two training trajectories out together: each file as when rolled out alone.
    for folder, batch in (("alone", "1"), ("batched", "2")):
        code = main(
            [
                "rollout",
                str(checkpoint),
                "--split",
                "train",
                "--steps",
                "4",
                "--out",
                str(tmp_path / folder),
                "--no-progress",
                "--batch",
                batch,
                "--outside-envelope",
            ]
        )
        assert code == 0
    for index in range(2):
        with (
            np.load(tmp_path / "alone" / f"train_{index:04d}.npz") as alone,
            np.load(tmp_path / "batched" / f"train_{index:04d}.npz") as batched,
        ):
            expected = alone["predicted_rollout"]
            np.testing.assert_allclose(
                batched["predicted_rollout"], expected, rtol=0, atol=1e-5 * np.abs(expected).max()
            )
    rendered = gns("render", str(rollout_file), "--gif", str(tmp_path / "r.gif"))
    assert rendered.returncode == 0 and (tmp_path / "r.gif").stat().st_size > 0


def test_corrupt_checkpoint_is_a_clear_error(tmp_path):
    bad = tmp_path / "checkpoint-000000001.pt"
    bad.write_bytes(b"not a checkpoint")
    result = gns("rollout", str(bad))
    assert result.returncode == 2
    assert str(bad) in result.stderr and "unreadable checkpoint" in result.stderr


def test_demo_runs_end_to_end(tmp_path):
    """The demo's whole pipeline with a tiny short model: simulate, train, roll out the shipped model, animate, report."""
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


COMMAND_MODULE = '''
"""A plugin's gns subcommand."""


def add_arguments(parser):
    parser.add_argument("--grains", type=int, default=3)


def run(args):
    print(f"sieved {args.grains} grains")
    return 0
'''


def test_a_plugin_adds_a_command_that_help_lists_and_gns_runs(tmp_path, monkeypatch, capsys):
    from gns_framework.cli.commands import load_commands
    from gns_framework.errors import PluginError
    from gns_framework.hookspecs import hookimpl
    from gns_framework.plugin_types import Command

    (tmp_path / "sieve_command.py").write_text(COMMAND_MODULE)
    monkeypatch.syspath_prepend(str(tmp_path))

    class SievePlugin:
        @staticmethod
        @hookimpl
        def gns_commands():
            return [Command("sieve", "count the grains", "sieve_command")]

    commands = load_commands(plugins=[("sieve-plugin", SievePlugin)])
    assert list(commands)[0] == "demo" and list(commands)[-1] == "sieve"  # built-ins first
    assert main(["sieve", "--grains", "7"], commands=commands) == 0
    assert "sieved 7 grains" in capsys.readouterr().out
    try:
        main(["--help"], commands=commands)
    except SystemExit:
        pass
    assert "count the grains" in capsys.readouterr().out

    class ClashingPlugin:
        @staticmethod
        @hookimpl
        def gns_commands():
            return [Command("train", "another train", "sieve_command")]

    with pytest.raises(PluginError, match="two gns commands are named 'train'.*clash-plugin"):
        load_commands(plugins=[("clash-plugin", ClashingPlugin)])


def test_a_broken_plugin_and_a_mistyped_disable_name_are_one_warning_line_each(tmp_path):
    """gns runs on without the broken plugin; each warning is one line, not Python's file, line and source."""
    dist = tmp_path / "broken_gns_plugin-1.2.3.dist-info"
    dist.mkdir()
    (dist / "METADATA").write_text("Metadata-Version: 2.1\nName: broken-gns-plugin\nVersion: 1.2.3\n")
    (dist / "entry_points.txt").write_text("[gns_framework]\nbroken = broken_gns_module\n")
    (tmp_path / "broken_gns_module.py").write_text("raise ImportError('missing dependency xyz')\n")
    env = {**os.environ, "PYTHONPATH": str(tmp_path), "GNS_DISABLE_PLUGINS": "exmple-clay"}
    result = subprocess.run(
        [sys.executable, "-m", "gns_framework.cli", "plugins", "--kind", "processor"],
        capture_output=True,
        text=True,
        env=env,
        timeout=600,
    )
    assert result.returncode == 0 and "interaction_network" in result.stdout
    lines = result.stderr.splitlines()
    assert len(lines) == 2, result.stderr
    (disabled,) = [line for line in lines if "GNS_DISABLE_PLUGINS:" in line]
    assert disabled.startswith("gns: warning: GNS_DISABLE_PLUGINS: 'exmple-clay' (did you mean 'example-clay'?)")
    (broken,) = [line for line in lines if "'broken'" in line]
    assert broken.startswith(
        "gns: warning: plugin entry point 'broken' = 'broken_gns_module' of distribution "
        "broken-gns-plugin 1.2.3 failed to load and was skipped: ImportError: missing dependency xyz"
    )
