"""benchmarks/time_to_accuracy.py keeps its fixed interface: side-by-side figures, the last line one JSON object."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import yaml
from load_script import load_script
from tiny import tiny_recipe_mapping

SCRIPT = Path(__file__).resolve().parents[2] / "benchmarks" / "time_to_accuracy.py"


def test_both_recipes_train_on_the_same_budget_and_report_ratios(tmp_path):
    from synthetic import write_synthetic_dataset

    data = write_synthetic_dataset(tmp_path / "sand", train=2, valid=1, test=2, particle_types=(6,))
    reference, ours = tiny_recipe_mapping(data), tiny_recipe_mapping(data, noise_relative=0.1)
    ours["name"] = "tiny-ours"
    ours["training"]["optimizer"] = {"schedule": "cosine", "lr_init": 1e-3, "lr_min": 1e-5, "warmup_steps": 2}
    paths = {}
    for name, raw in (("reference", reference), ("ours", ours)):
        paths[name] = tmp_path / f"{name}.yaml"
        paths[name].write_text(yaml.safe_dump(raw))
    held_out = write_synthetic_dataset(tmp_path / "held_out", train=1, valid=0, test=2, particle_types=(6,), frames=24)
    command = [
        sys.executable,
        str(SCRIPT),
        "--budget-minutes",
        "0.05",
        "--data",
        str(data),
        "--threads",
        "1",
        "--points",
        "2",
        "--trajectories",
        "2",
        "--held-out",
        str(held_out),
        "--seeds",
        "2",
        "--reference",
        str(paths["reference"]),
        "--ours",
        str(paths["ours"]),
        "--json",
    ]
    result = subprocess.run(command, capture_output=True, text=True, timeout=900)
    assert result.returncode == 0, result.stderr
    figures = json.loads(result.stdout.strip().splitlines()[-1])
    assert figures["budget_minutes"] == 0.05 and figures["threads"] == 1 and figures["seeds"] == 2
    assert figures["held_out"] == str(held_out)
    for role, name in (("reference", "tiny"), ("ours", "tiny-ours")):
        runs = figures["runs"][role]
        assert [run["seed"] for run in runs] == [0, 1] and all(run["name"] == name for run in runs)
        for run in runs:
            first, last = run["evaluations"]
            assert 0 < first["minutes"] <= last["minutes"] and first["step"] <= last["step"]
            # Training time is what the budget counts: at most one step beyond it.
            assert last["minutes"] <= 0.05 * 1.5
            for metric in ("runout_error_pct", "sinkhorn_pct", "position_mse"):
                assert last[metric] is not None and last[metric] >= 0
            assert run["steady"] in (True, False)
        # The spread per point is over the seeds' values at that point.
        for k, point in enumerate(figures["per_point"][role]):
            values = [run["evaluations"][k]["sinkhorn_pct"] for run in runs]
            assert point["sinkhorn_pct"]["low"] == min(values) and point["sinkhorn_pct"]["high"] == max(values)
            assert abs(point["sinkhorn_pct"]["mean"] - sum(values) / 2) <= 1e-12 * max(values)
    # ours uses a cosine schedule: its step budget was measured so the schedule ends with the budget.
    assert all(run["steps"] >= 20 for run in figures["runs"]["ours"])
    # --late defaults to 3, more than the 2 points here: both evaluations count, the median is their mean.
    assert figures["late"] == 2
    per_seed = figures["ratio_reference_over_ours_late_median_per_seed"]
    for seed, ratios in enumerate(per_seed):
        for metric, ratio in ratios.items():
            medians = {
                role: sum(e[metric] for e in figures["runs"][role][seed]["evaluations"]) / 2
                for role in ("reference", "ours")
            }
            assert abs(ratio - medians["reference"] / medians["ours"]) <= 1e-12 * ratio
    for metric, spread in figures["ratio_reference_over_ours_late_median"].items():
        assert spread["low"] == min(r[metric] for r in per_seed) and spread["high"] == max(r[metric] for r in per_seed)
    assert "reference / ours" in result.stdout and "steady" in result.stdout


def test_steadiness_is_judged_after_the_first_third_of_the_budget():
    tta = load_script(SCRIPT)

    def points(*pairs):
        return [{"minutes": m, "runout_error_pct": v} for m, v in pairs]

    assert tta.steady(points((1, 50), (2, 200), (4, 20), (6, 30), (9, 39)), 9)  # 200 falls in the first third
    assert not tta.steady(points((1, 50), (4, 20), (6, 41)), 9)  # 41 > 2 x 20 after a third
    assert tta.steady(points((4, 20), (6, 40)), 9)  # exactly twice is not above it
