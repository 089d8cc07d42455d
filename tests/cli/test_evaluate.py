"""``gns evaluate`` end to end: generated data, a trained model, the simulator at two grids."""

from __future__ import annotations

from pathlib import Path

import meshio
import yaml
from cli_runner import gns
from tiny import tiny_recipe_mapping

SCENE = """
name: tiny_collapse
dim: 2
domain: {bounds: [[0.0, 1.0], [0.0, 0.5]], grid: 24}
time: {frame_dt: 0.005, substeps: 20, frames: 16}
seed: 3
blocks:
  - material: sand
    position: [0.0, 0.0]
    size: [0.2, 0.25]
    properties: {friction: {range: [0.6, 0.8]}}
"""


def test_evaluate_writes_table_plots_vtk_and_gif(tmp_path: Path):
    scene = tmp_path / "scene.yaml"
    scene.write_text(SCENE)
    data = tmp_path / "data"
    generated = gns("generate", str(scene), "--trajectories", "4", "--out", str(data), "--no-progress")
    assert generated.returncode == 0, generated.stderr
    recipe = tmp_path / "tiny.yaml"
    recipe.write_text(yaml.safe_dump(tiny_recipe_mapping(data, tmp_path / "run")))
    trained = gns("train", str(recipe), "--steps", "2", "--no-progress")
    assert trained.returncode == 0, trained.stderr

    out = tmp_path / "report"
    checkpoint = tmp_path / "run" / "checkpoints" / "checkpoint-000000002.pt"
    args = ("evaluate", str(checkpoint), "--out", str(out), "--repeats", "1", "--warmup", "0", "--vtk", "--gif")
    refused = gns(*args)
    assert refused.returncode == 2 and "outside the envelope of" in refused.stderr and not out.exists()
    result = gns(*args, "--outside-envelope", "--batch", "2")
    assert result.returncode == 0, result.stderr
    table = (out / "report.md").read_text()
    assert "| tiny [batch 2] | learned |" in table, "the batched row beside the one-at-a-time row"
    assert "**Warning: data outside a model's training envelope" in table and "property friction" in table
    assert "| tiny | learned |" in table
    assert "grid 24 x 20 substeps (reference)" in table and "grid 12 x 20 substeps" in table
    assert (out / "report.csv").read_text().count("\n") == 5
    for png in ("error_vs_time.png", "error_over_rollout.png"):
        assert (out / png).read_bytes()[:4] == b"\x89PNG"
    frames = sorted((out / "vtk" / "tiny" / "predicted").glob("*.vtu"))
    assert len(frames) == 16, "the 6 input frames and the 10 rolled-out ones"
    assert meshio.read(frames[-1]).point_data["particle_type"].shape[0] > 0
    assert (out / "tiny.gif").stat().st_size > 0

    # The training run was tracked (tests use a temporary MLflow store), so the report went to it.
    assert "logged the evaluation report of tiny to MLflow run" in result.stdout
    import mlflow

    run_id = result.stdout.split("MLflow run ")[-1].split()[0]
    client = mlflow.MlflowClient()
    logged = {a.path for a in client.list_artifacts(run_id, "evaluation")}
    assert {"evaluation/report.md", "evaluation/error_vs_time.png", "evaluation/tiny.gif"} <= logged
    assert {"evaluation_sinkhorn_final_pct", "evaluation_batched_seconds_per_rollout"} <= set(
        client.get_run(run_id).data.metrics
    )

    # Two checkpoints with one file name: labels stay file names, distinct, with no accidental sub-folders.
    other = tmp_path / "other" / "checkpoints"
    other.mkdir(parents=True)
    (other / checkpoint.name).write_bytes(checkpoint.read_bytes())
    both = tmp_path / "both"
    result = gns(
        "evaluate",
        str(checkpoint),
        str(other / checkpoint.name),
        "--out",
        str(both),
        "--no-simulator",
        "--repeats",
        "1",
        "--warmup",
        "0",
        "--trajectories",
        "1",
        "--gif",
        "--outside-envelope",
    )
    assert result.returncode == 0, result.stderr
    assert result.stderr.count("warning: outside the envelope of") == 2, "each model judged on its own envelope"
    labels = ["tiny.run.checkpoint-000000002", "tiny.other.checkpoint-000000002"]
    assert sorted(p.name for p in both.glob("*.gif")) == sorted(f"{label}.gif" for label in labels)
    assert sorted(p.name for p in (both / "rollouts").iterdir()) == sorted(labels)
    assert all(f"| {label} | learned |" in (both / "report.md").read_text() for label in labels)


def test_model_labels_are_safe_file_names_and_unique():
    from gns_framework.cli.evaluate import model_labels

    assert model_labels(["sand2d"], [Path("runs/a/checkpoints/best.pt")]) == ["sand2d"]
    same = [
        Path("runs/a b/checkpoints/best.pt"),
        Path("runs/c/checkpoints/best.pt"),
        Path("runs/c/checkpoints/best.pt"),
    ]
    assert model_labels(["sand2d"] * 3, same) == ["sand2d.a_b.best", "sand2d.c.best", "sand2d.c.best-2"]
    assert model_labels(["x/../y"], [Path("m.pt")]) == ["x_.._y"]
    # Models of different recipes keep their recipes' names, wherever their files are.
    assert model_labels(["sand2d-fast", "sand2d-fast-grid"], [Path("models/a.pt"), Path("models/b.pt")]) == [
        "sand2d-fast",
        "sand2d-fast-grid",
    ]


def test_evaluate_rejects_bad_scales(tmp_path: Path):
    result = gns("evaluate", str(tmp_path / "x.pt"), "--grid-scales", "0,1")
    assert result.returncode == 2 and "comma-separated positive numbers" in result.stderr


def test_precisions_are_checked_before_anything_runs(tmp_path: Path):
    result = gns(
        "evaluate", str(tmp_path / "model.pt"), "--precisions", "float32,float16", "--out", str(tmp_path / "r")
    )
    assert result.returncode == 2
    assert "--precisions: expected comma-separated distinct precisions among float32, tf32, bfloat16" in result.stderr
    assert "'float32,float16'" in result.stderr and not (tmp_path / "r").exists()


def test_evaluate_lists_the_cases_a_models_deposit_warning_flags(tiny_model, tmp_path: Path):
    import csv

    from tiny import with_deposit_warning

    # Fitted to another error than the shipped 15 %: the report says what this record warns of.
    warned = with_deposit_warning(tiny_model, tmp_path / "warned.pt", threshold=0.0, error_pct=12.5)
    out = tmp_path / "report"
    common = ["--no-simulator", "--repeats", "1", "--warmup", "0", "--outside-envelope"]
    result = gns("evaluate", str(warned), "--out", str(out), *common)
    assert result.returncode == 0, result.stderr
    table = (out / "report.md").read_text()
    assert (
        "Deposit warning (the model's own" in table
        and "- tiny: 1 of 1 case(s) flagged as more than 12.5 % off: test_000" in table
    )
    assert "15 %" not in table
    with (out / "cases.csv").open() as handle:
        (row,) = list(csv.DictReader(handle))
    assert float(row["deposit_warning_score"]) == 0.0 and float(row["deposit_warning_flagged"]) == 1.0
    plain = gns("evaluate", str(tiny_model), "--out", str(tmp_path / "plain"), *common)
    assert plain.returncode == 0 and "Deposit warning" not in (tmp_path / "plain" / "report.md").read_text()
