"""The training memory mode: activations stored by default; recomputed when set, or within a block that
restores the mode after it, even on an error."""

from __future__ import annotations

import subprocess
import sys

import pytest

from gns_framework.runtime.activation_memory import (
    activations_recomputed,
    recompute_activations,
    set_recompute_activations,
)


@pytest.fixture(autouse=True)
def mode_restored():
    """The mode is process-wide: leave it as the other tests found it."""
    before = recompute_activations()
    yield
    set_recompute_activations(before)


def test_activations_are_stored_in_a_fresh_process():
    # A fresh interpreter, since tests earlier in the session may have set the mode.
    code = "from gns_framework.runtime.activation_memory import recompute_activations; print(recompute_activations())"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "False"


def test_the_mode_holds_what_was_set_as_a_bool():
    set_recompute_activations(False)
    assert recompute_activations() is False
    set_recompute_activations(1)
    assert recompute_activations() is True  # a truthy recipe value becomes a bool


def test_the_block_recomputes_within_and_restores_after():
    set_recompute_activations(False)
    with activations_recomputed():
        assert recompute_activations() is True
    assert recompute_activations() is False


def test_a_block_cannot_switch_off_a_recompute_mode_set_outside_it():
    # Gradient checkpointing inside a run that already recomputes must not make components store activations.
    set_recompute_activations(True)
    with activations_recomputed(enabled=False):
        assert recompute_activations() is True
    assert recompute_activations() is True
    set_recompute_activations(False)
    with activations_recomputed(enabled=False):
        assert recompute_activations() is False


def test_the_mode_is_restored_when_the_block_raises():
    set_recompute_activations(False)
    with pytest.raises(RuntimeError, match="out of memory"), activations_recomputed():
        raise RuntimeError("out of memory")
    assert recompute_activations() is False
