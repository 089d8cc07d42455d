"""The code's provenance: the git commit of the checkout in use, marked +dirty with local changes, "unknown"
outside git."""

from __future__ import annotations

import subprocess
from pathlib import Path

import pytest

from gns_framework.training import provenance
from gns_framework.training.provenance import git_commit

HEAD = "0123456789abcdef0123456789abcdef01234567"


@pytest.fixture
def fake_git(monkeypatch):
    """git answering ``HEAD`` to rev-parse and ``status`` to status; the cached answer cleared before and after."""
    answers = {"status": ""}
    calls = []

    def run(args, **kwargs):
        calls.append(args)
        if isinstance(answers.get("error"), BaseException):
            raise answers["error"]
        out = HEAD + "\n" if "rev-parse" in args else answers["status"]
        return subprocess.CompletedProcess(args, 0, stdout=out, stderr="")

    git_commit.cache_clear()
    monkeypatch.setattr(provenance.subprocess, "run", run)
    yield answers, calls
    git_commit.cache_clear()


def test_a_clean_checkout_is_its_commit(fake_git):
    _, calls = fake_git
    assert git_commit() == HEAD
    # Asked of the package's own folder, wherever the command runs; untracked files do not make it dirty.
    source = str(Path(provenance.__file__).resolve().parent)
    assert calls[0][:3] == ["git", "-C", source] and "--untracked-files=no" in calls[1]


def test_local_changes_mark_the_commit_dirty(fake_git):
    answers, _ = fake_git
    answers["status"] = " M gns_framework/training/step.py\n"
    assert git_commit() == f"{HEAD}+dirty"


@pytest.mark.parametrize(
    "error",
    [FileNotFoundError("git"), subprocess.CalledProcessError(128, "git"), subprocess.TimeoutExpired("git", 10)],
    ids=["no git", "not a repository", "git hangs"],
)
def test_outside_git_the_commit_is_unknown(fake_git, error):
    answers, _ = fake_git
    answers["error"] = error
    assert git_commit() == "unknown"


def test_git_is_asked_once_per_process(fake_git):
    _, calls = fake_git
    assert git_commit() == git_commit()
    assert len(calls) == 2  # rev-parse and status, the first time only
