"""benchmarks/step_budget.py: operations and read-backs per step on the GPU code path, counted on the CPU.

The counts do not depend on the scene's size (one chunk of candidates, the edge block one Triton
launch per message-passing step), so a small scene stands for the 10k of the benchmark's default.
The ceilings hold what the code does today (the graph build in a few dozen operations for all
3^d neighbour cells, two read-backs per graph, fused Adam): a change that adds launches or waits
to a step fails here. With the fixed-capacity graph a rollout step reads nothing back, and captured (``gns
rollout --capture``) it is a few operations around one replay: issue 45's <= 60 operations and no read-back.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(REPO / "benchmarks"))

import step_budget  # noqa: E402


@pytest.fixture(scope="module")
def figures():
    return step_budget.measure(400, 3)


def test_the_graph_build_is_a_few_dozen_launches_and_two_read_backs(figures):
    graph = figures["graph_build"]
    assert graph["launching"] <= 150, graph["top"]
    assert graph["syncs"] == 2, "the candidate count and the kept pairs"
    names = dict(graph["top"])
    assert names.get("aten.searchsorted", 0) <= 6, "one search per neighbour-cell key set, not one per cell"


def test_a_rollout_step_waits_only_for_its_graph(figures):
    step = figures["rollout_step"]
    assert step["syncs"] == figures["graph_build"]["syncs"]
    assert step["launching"] <= 380, step["top"]
    names = dict(step["top"])
    assert names["triton.forward_kernel"] == 10, "one Triton launch per message-passing step"


def test_a_training_step_with_fused_adam(figures):
    step = figures["training_step"]
    assert step["syncs"] == figures["graph_build"]["syncs"], "Adam reads nothing back"
    assert step["launching"] <= 820, step["top"]
    names = dict(step["top"])
    assert names.get("aten._fused_adam_", 0) == 1 and "aten.addcdiv_" not in names
    assert names["triton.backward_kernel"] == 10


def test_with_fixed_capacity_a_rollout_step_never_waits_for_the_device():
    # Issue 45, item 3: the graph in fixed-size buffers, its overflow read every few steps by the rollout.
    figures = step_budget.measure(400, 3, graph_builder="radius_fixed_capacity")
    step = figures["rollout_step"]
    assert step["syncs"] == 0, step["top"]
    assert step["launching"] <= 345, step["top"]
    assert figures["graph_build"]["launching"] <= 125, figures["graph_build"]["top"]
    # Outside a rollout nobody reads the overflow later: each build is checked at once, one read-back.
    assert figures["training_step"]["syncs"] == 1
    # Issue 45, item 4: captured, the host dispatches a handful of operations per step around one replay.
    captured = figures["captured_rollout_step"]
    assert captured["ops"] <= 60 and captured["syncs"] == 0, captured["top"]
    assert dict(captured["top"])["cuda_graph.replay"] == 1


def test_the_chunked_training_step_sorts_its_graph_once():
    # Issue 45, item 1: on accelerators without Triton the ordered sums need the senders' order: made once per
    # graph (edge_order's ChunkOrder), not per backward call; the receivers, sorted by the builder, not re-sorted.
    step = step_budget.measure(400, 3, triton=False)["training_step"]
    names = dict(step["top"])
    assert names["aten.sort"] <= 8, "the graph build's sorts and one for the senders"
    assert step["launching"] <= 1200, step["top"]


def test_the_script_ends_with_its_json_line():
    result = subprocess.run(
        [sys.executable, str(REPO / "benchmarks/step_budget.py"), "--particles", "300", "--json"],
        capture_output=True,
        text=True,
        timeout=300,
        env={"OMP_NUM_THREADS": "1", "PATH": "/usr/bin:/bin"},
    )
    assert result.returncode == 0, result.stderr
    summary = json.loads(result.stdout.strip().splitlines()[-1])
    for key in ("ops_per_rollout_step", "syncs_per_rollout_step", "ops_per_training_step", "syncs_per_training_step"):
        assert isinstance(summary[key], int) and summary[key] >= 0
