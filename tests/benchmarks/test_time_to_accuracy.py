"""benchmarks/time_to_accuracy.py keeps its fixed interface: side-by-side figures, the last line one JSON object."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import yaml

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
    command = [sys.executable, str(SCRIPT), "--budget-minutes", "0.05", "--data", str(data), "--threads", "1",
               "--points", "2", "--trajectories", "1", "--reference", str(paths["reference"]), "--ours",
               str(paths["ours"]), "--json"]
    result = subprocess.run(command, capture_output=True, text=True, timeout=600)
    assert result.returncode == 0, result.stderr
    figures = json.loads(result.stdout.strip().splitlines()[-1])
    assert figures["budget_minutes"] == 0.05 and figures["threads"] == 1
    for role, name in (("reference", "tiny"), ("ours", "tiny-ours")):
        run = figures["runs"][role]
        assert run["name"] == name and len(run["evaluations"]) == 2
        first, last = run["evaluations"]
        assert 0 < first["minutes"] <= last["minutes"] and first["step"] <= last["step"]
        # Training time is what the budget counts: at most one step beyond it.
        assert last["minutes"] <= 0.05 * 1.5
        for metric in ("runout_error_pct", "sinkhorn_pct", "position_mse"):
            assert last[metric] is not None and last[metric] >= 0
    # ours uses a cosine schedule: its step budget was measured so the schedule ends with the budget.
    assert figures["runs"]["ours"]["steps"] >= 20
    finals = {role: figures["runs"][role]["evaluations"][-1] for role in ("reference", "ours")}
    for metric, ratio in figures["ratio_reference_over_ours"].items():
        assert ratio == finals["reference"][metric] / finals["ours"][metric]
    # --late defaults to 3, more than the 2 points here: both evaluations count, the median is their mean.
    assert figures["late"] == 2
    for metric, ratio in figures["ratio_reference_over_ours_late_median"].items():
        medians = {role: sum(e[metric] for e in figures["runs"][role]["evaluations"]) / 2 for role in finals}
        assert figures["late_median"]["reference"][metric] == medians["reference"]
        assert abs(ratio - medians["reference"] / medians["ours"]) <= 1e-12 * ratio
    assert "reference / ours" in result.stdout
