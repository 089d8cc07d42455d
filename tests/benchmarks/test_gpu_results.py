"""benchmarks/gpu_results.py: a gpu_check run's lines become one record of docs/gpu_results.json."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))

import gpu_results

LOG = """gpu_check: start device=cuda dry_run=0
gpu_check: device name=NVIDIA_H100_80GB_HBM3 count=1 memory_gb=79.1 capability=9.0 torch=2.11.0 cuda=13.0
gpu_check: sums path=ordered_sorted rows=262144 nodes=13107 features=128 status=ok repeats=10 ms=0.31 same_bits_twice=True
gpu_check: kernels particles=10000 edges=217026 precision=bfloat16 phase=rollout repeats=5 chunked_ms=26.1 triton_ms=3.2 speedup=8.156 max_rel_diff=0.004 finite=True
gpu_check: kernels_bitwise particles=10000 edges=217026 precision=bfloat16 equal=True values=1534
gpu_check: step particles=10000 precision=bfloat16 phase=rollout memory=stored status=ok edges=217026 step_s=0.0041
gpu_check: step particles=10000 precision=bfloat16 phase=train memory=recompute status=ok edges=217026 step_s=0.02
gpu_check: step particles=10000 precision=bfloat16 phase=train memory=stored status=ok edges=217026 step_s=0.015
gpu_check: step particles=10000 precision=float32 phase=rollout memory=stored status=ok edges=217026 step_s=0.009
gpu_check: step particles=1000000 precision=bfloat16 phase=train memory=recompute status=ok edges=23200000 step_s=1.5
gpu_check: step particles=1000000 precision=bfloat16 phase=rollout memory=stored status=oom edges=23200000
gpu_check: part name=scale status=pass seconds=100 limit=130
gpu_check: capture particles=300 steps=20 eager_ms=9.1 captured_ms=0.8 overflowed=False speedup=11.4 max_abs_diff=2e-07 captures=1 status=ok
gpu_check: capture particles=100000 status=over_budget
gpu_check: train_capture particles=10000 steps=20 eager_ms=60.5 captured_ms=7.5 classes=3 captures=3 speedup=8.07 loss_rel_diff=3e-06 weight_diff_lr=1.8 status=ok
"""  # noqa: E501 - gpu_check's log lines as it writes them, one record a line


def test_the_record_holds_the_step_times_of_one_precision_and_the_kernels():
    entry = gpu_results.record(LOG, "abc1234", "2026-12-07")
    assert entry["device"] == "NVIDIA H100 80GB HBM3" and entry["commit"] == "abc1234"
    assert entry["rollout_ms"] == {"10000": 4.1}
    assert entry["training_ms"] == {"10000": 15.0, "1000000": 1500.0}, "stored wins; an oom is no figure"
    assert entry["kernels"][0]["speedup"] == "8.156"
    assert entry["same_bits"] == {"sums_ordered_sorted": True, "triton_train_bfloat16": True}
    assert entry["small_scene_rollout_s"] is None
    assert entry["captured_rollout_ms"] == {"300": {"eager_ms": 9.1, "captured_ms": 0.8, "max_abs_diff": 2e-07}}
    assert entry["captured_training_ms"] == {"10000": {"eager_ms": 60.5, "captured_ms": 7.5, "loss_rel_diff": 3e-06}}


def test_records_are_appended_to_the_list(tmp_path):
    log, out = tmp_path / "gpu_check.log", tmp_path / "gpu_results.json"
    log.write_text(LOG)
    for _ in range(2):
        assert gpu_results.main([str(log), "--commit", "abc", "--date", "2026-12-07", "--out", str(out)]) == 0
    assert [run["commit"] for run in json.loads(out.read_text())] == ["abc", "abc"]
    out.write_text("{}")
    with pytest.raises(SystemExit, match="no JSON list"):
        gpu_results.main([str(log), "--commit", "abc", "--out", str(out)])
