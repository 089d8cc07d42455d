"""The ``gns`` command line itself (``gns_framework.cli``): ``--help`` lists every command, ``gns plugins`` and
``gns check`` answer as a user runs them, and plugin warnings are one line each. End to end, in subprocesses; each
command's own tests are in ``test_<command>.py`` (or ``test_cli_<command>.py``) beside this."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path


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


def test_a_reader_that_leaves_early_ends_the_command_quietly():
    """``gns plugins --json | head -1``: the reader closed the pipe (here before the command writes at all),
    and the command stops with the shell's status for a stopped writer and no traceback."""
    read_end, write_end = os.pipe()
    os.close(read_end)
    try:
        result = subprocess.run(
            [sys.executable, "-m", "gns_framework.cli", "plugins", "--json"],
            stdout=write_end,
            stderr=subprocess.PIPE,
            text=True,
            timeout=600,
        )
    finally:
        os.close(write_end)
    assert result.returncode == 141
    assert "Traceback" not in result.stderr and "BrokenPipeError" not in result.stderr, result.stderr


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
