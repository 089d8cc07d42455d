"""The project passes its own lint configuration ([tool.ruff] in pyproject.toml): no unused imports or
names, no undefined names, no syntax errors, in the package, the plugins, tests, benchmarks and scripts;
and its layout is ruff format's."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
CHECKED = ("gns_framework", "plugins", "tests", "benchmarks", "parity", "scripts")


def _ruff() -> list[str]:
    found = shutil.which("ruff", path=str(Path(sys.executable).parent)) or shutil.which("ruff")
    if found is None:
        pytest.skip("ruff is not installed (pip install -e .[test] installs it)")
    return [found]


def test_the_project_passes_ruff():
    result = subprocess.run(
        [*_ruff(), "check", "--output-format", "concise", *CHECKED],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert result.returncode == 0, result.stdout + result.stderr


def test_the_check_catches_an_unused_import(tmp_path):
    (tmp_path / "bad.py").write_text("import os\n")
    result = subprocess.run(
        [*_ruff(), "check", "--config", str(REPO / "pyproject.toml"), "bad.py"],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert result.returncode == 1 and "F401" in result.stdout


def test_the_project_is_laid_out_by_ruff_format():
    result = subprocess.run(
        [*_ruff(), "format", "--check", *CHECKED], cwd=REPO, capture_output=True, text=True, timeout=300
    )
    assert result.returncode == 0, "run `ruff format .`:\n" + result.stdout + result.stderr


def test_the_format_check_catches_a_misformatted_file(tmp_path):
    (tmp_path / "bad.py").write_text("x = ( 1,2 )\n")
    result = subprocess.run(
        [*_ruff(), "format", "--check", "--config", str(REPO / "pyproject.toml"), "bad.py"],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert result.returncode == 1 and "bad.py" in result.stdout
