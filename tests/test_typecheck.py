"""The package and the built-in plugins pass mypy with the project's configuration ([tool.mypy] in
pyproject.toml: the pydantic plugin, Warp's kernel module left out, targeted ignores only)."""

from __future__ import annotations

import importlib.util
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]


def _mypy() -> list[str]:
    if importlib.util.find_spec("mypy") is None:
        pytest.skip("mypy is not installed (pip install -e .[test] installs it)")
    return [sys.executable, "-m", "mypy"]


def _run(*args: str, cwd: Path) -> subprocess.CompletedProcess:
    return subprocess.run([*_mypy(), *args], cwd=cwd, capture_output=True, text=True, timeout=600)


def test_the_package_and_builtins_pass_mypy(tmp_path):
    # The files, plugins and overrides come from pyproject.toml; a fresh cache keeps the run independent of others.
    result = _run(
        "--config-file",
        str(REPO / "pyproject.toml"),
        "--cache-dir",
        str(tmp_path / "cache"),
        "--no-error-summary",
        "--hide-error-context",
        cwd=REPO,
    )
    errors = [line for line in result.stdout.splitlines() if ": error:" in line]
    assert result.returncode == 0, "\n".join(errors) or result.stdout + result.stderr


def test_the_check_catches_a_type_error(tmp_path):
    (tmp_path / "bad.py").write_text("def f(x: int) -> str:\n    return x\n")
    result = _run(
        "--config-file", str(REPO / "pyproject.toml"), "--cache-dir", str(tmp_path / "cache"), "bad.py", cwd=tmp_path
    )
    assert result.returncode == 1 and "[return-value]" in result.stdout, result.stdout + result.stderr
