"""The documented-commands harness itself: what counts as a block, what a skip mark covers, how commands are
scaled, and that a failing command or a missing stated output fails its block."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest
import shim
from doc_blocks import blocks

SHIM = Path(shim.__file__)


def test_only_shell_blocks_count_and_a_skip_mark_covers_the_fence_below_it(tmp_path):
    doc = tmp_path / "guide.md"
    doc.write_text(
        "# Guide\n\n```bash\ngns plugins   # run\n```\n\n"
        "<!-- docs-test: skip: needs two hosts -->\n```bash\ntorchrun --nnodes 2 x\n```\n\n"
        "<!-- docs-test: skip: not this one -->\n\nA paragraph between.\n\n```bash\ngns check recipes/\n```\n\n"
        "```yaml\nname: x\n```\n\n```bash\n# only a comment\n```\n"
    )
    found = blocks(doc, tmp_path)
    assert [(b.line, b.skip, b.first_command()) for b in found] == [
        (3, None, "gns plugins   # run"),
        (8, "needs two hosts", "torchrun --nnodes 2 x"),
        (16, None, "gns check recipes/"),
    ]


def test_flags_are_capped_and_lists_replaced():
    args = ["train", "recipes/a.yaml", "--steps", "2000", "--out", "runs/a"]
    assert shim.capped(args, {"--steps": 4})[0] == ["train", "recipes/a.yaml", "--steps", "4", "--out", "runs/a"]
    assert shim.capped(["--steps", "2"], {"--steps": 4})[0] == ["--steps", "2"], "a smaller value stays"
    out, notes = shim.capped(["--particles", "1000", "10000", "--json"], {"--particles": [300]})
    assert out == ["--particles", "300", "--json"] and notes == ["--particles 1000 10000 -> 300"]
    assert shim.capped(["--json"], {"--repeats": 1}, ("--repeats",))[0] == ["--json", "--repeats", "1"]


def test_generation_keeps_one_trajectory_per_split():
    out, _ = shim.scaled_generate(["generate", "s.yaml", "--trajectories", "274", "--valid", "12", "--test", "12"])
    assert out == ["generate", "s.yaml", "--trajectories", "3", "--valid", "1", "--test", "1"]
    out, _ = shim.scaled_generate(["generate", "s.yaml", "--trajectories", "2", "--valid", "0", "--test", "1"])
    assert out == ["generate", "s.yaml", "--trajectories", "2", "--valid", "0", "--test", "1"]


def _run_block(script: str, tmp_path: Path) -> subprocess.CompletedProcess:
    bin_dir = tmp_path / "bin"
    bin_dir.mkdir(exist_ok=True)
    gns = bin_dir / "gns"
    gns.write_text(f'#!/bin/sh\nexec "{sys.executable}" "{SHIM}" gns "$@"\n')
    gns.chmod(0o755)
    env = {"PATH": f"{bin_dir}:/usr/bin:/bin", "GNS_DOCS_PYTHON": sys.executable, "GNS_DOCS_LOG": str(tmp_path / "log")}
    return subprocess.run(
        ["bash", "-c", "set -eo pipefail\n" + script], cwd=tmp_path, env=env, capture_output=True, text=True
    )


def test_a_failing_command_fails_its_block(tmp_path):
    result = _run_block("gns plugins --kind no_such_kind\ngns plugins\n", tmp_path)
    assert result.returncode != 0


@pytest.mark.parametrize("made", [True, False])
def test_a_command_that_succeeds_without_its_stated_output_fails(tmp_path, monkeypatch, made):
    """The command exits 0; whether its block passes is decided by the --out folder it named."""
    out = tmp_path / "report"

    def fake_run(command, **kwargs):
        if made:
            out.mkdir()
        return subprocess.CompletedProcess(command, 0)

    monkeypatch.setattr(shim.subprocess, "run", fake_run)
    monkeypatch.setenv("GNS_DOCS_LOG", str(tmp_path / "log"))
    assert shim.run("gns", ["check", "recipes/", "--out", str(out)]) == (0 if made else 3)
