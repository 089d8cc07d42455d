"""Fixtures of the model tests."""

from __future__ import annotations

import pytest

from gns_framework.model import captured_steps


@pytest.fixture
def counted(monkeypatch):
    """Every CapturedSteps the rollouts make, in order."""
    made = []
    original = captured_steps.CapturedSteps.__init__

    def remember(self, *args, **kwargs):
        original(self, *args, **kwargs)
        made.append(self)

    monkeypatch.setattr(captured_steps.CapturedSteps, "__init__", remember)
    return made
