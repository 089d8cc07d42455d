"""benchmarks/step_time.py keeps its documented JSON interface (issue 8), so results stay comparable."""

from __future__ import annotations

import copy
import dataclasses
import json
import subprocess
import sys
from pathlib import Path

import pytest
import torch
from float_tolerances import assert_close_to_reference

SCRIPT = Path(__file__).resolve().parents[2] / "benchmarks" / "step_time.py"
REQUIRED = (
    "particles",
    "edges",
    "mean_neighbours",
    "train_step_s",
    "rollout_step_s",
    "neighbour_search_s",
    "peak_rss_mb",
    "efficiency",
)


@pytest.mark.parametrize(("dim", "precision"), [(2, "float32"), (3, "bfloat16")])
def test_one_scene_prints_one_json_object_with_every_figure(dim, precision):
    command = [
        sys.executable,
        str(SCRIPT),
        "--particles",
        "300",
        "--dim",
        str(dim),
        "--repeat",
        "1",
        "--warmup",
        "0",
        "--threads",
        "1",
        "--precision",
        precision,
        "--json",
    ]
    result = subprocess.run(command, capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stderr
    figures = json.loads(result.stdout.strip().splitlines()[-1])
    for key in REQUIRED:
        assert figures[key] > 0, key
    assert figures["dim"] == dim and figures["precision"] == precision
    assert abs(figures["particles"] - 300) < 0.2 * 300
    assert figures["edges"] == pytest.approx(figures["particles"] * (figures["mean_neighbours"] + 1))
    assert 5 < figures["mean_neighbours"] < 30


def test_the_peer_runs_in_a_child_process_with_the_reference_allocator():
    command = [
        sys.executable,
        str(SCRIPT),
        "--particles",
        "300",
        "--repeat",
        "1",
        "--warmup",
        "0",
        "--threads",
        "1",
        "--peer",
        "--json",
    ]
    result = subprocess.run(command, capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stderr
    figures = json.loads(result.stdout.strip().splitlines()[-1])
    assert figures["peer_allocator"] == "glibc" and figures["keep_freed_memory"]
    for key in (
        "peer_train_step_s",
        "peer_rollout_step_s",
        "peer_peak_rss_inference_mb",
        "peer_peak_rss_mb",
        "peer_train_speedup",
        "peer_rollout_speedup",
    ):
        assert figures[key] > 0, key


def test_the_peer_computes_the_same_function_as_our_model():
    sys.path.insert(0, str(SCRIPT.parent))
    try:
        from reference_style import reference_style
        from step_time import benchmark_model
    finally:
        sys.path.remove(str(SCRIPT.parent))
    scene, simulator = benchmark_model(200, 2)
    peer = reference_style(simulator)
    reference = copy.deepcopy(simulator).double()
    sequence = scene.batch.position_sequence
    batch64 = dataclasses.replace(scene.batch, position_sequence=sequence.double())
    # Float32 positions are rounded at eps * |position| and the edge features divide their differences by the
    # connectivity radius: the network's output is only that much better than its inputs in float32.
    conditioning = 1 + sequence.abs().max().item() / simulator.setup.connectivity_radius
    with torch.no_grad():
        expected = reference.normalized_prediction(batch64.position_sequence, batch64)
        expected_position = reference.predict_next_position(batch64)
        for name, model in (("ours", simulator), ("peer", peer)):
            acceleration = model.normalized_prediction(sequence, scene.batch)
            assert_close_to_reference(acceleration, expected, scale=conditioning * expected.abs().max(), msg=name)
            assert_close_to_reference(model.predict_next_position(scene.batch), expected_position, msg=name)
    assert not torch.equal(expected_position.float(), sequence[:, -1])
