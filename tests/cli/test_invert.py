"""``gns invert`` (``gns_framework.cli.invert``) end to end on a tiny trained model: refused outside the model's
envelope unless asked, its results written (and never over an earlier inversion's), logged to MLflow, the
problems only the model and the data reveal reported at once, and its best iterate returned with the truth the
data records, from a config whose paths are relative to itself."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml
from inverse_cases import config_mapping, write_config


def gns(*args: str, cwd: Path) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "gns_framework.cli", *args], capture_output=True, text=True, cwd=cwd, timeout=600
    )


@pytest.mark.parametrize("optimizer", ["adam", "lbfgs"])
def test_gns_invert_writes_its_results(tmp_path, tiny_model, dataset_multimaterial, optimizer):
    config = write_config(
        tmp_path / "inv.yaml",
        config_mapping(tiny_model, dataset_multimaterial, optimizer={"name": optimizer, "lr": 0.05, "iterations": 2}),
    )
    # The search bounds [0.4, 1] reach beyond the frictions the tiny model was trained on.
    refused = gns("invert", str(config), "--out", "out", "--no-progress", "--no-tracking", cwd=tmp_path)
    assert refused.returncode == 2 and "unknowns.friction.bounds [0.4, 1] (trained: " in refused.stderr
    assert not (tmp_path / "out").exists()
    result = gns(
        "invert", str(config), "--out", "out", "--no-progress", "--no-tracking", "--outside-envelope", cwd=tmp_path
    )
    assert result.returncode == 0, result.stderr
    out = tmp_path / "out"
    record = json.loads((out / "result.json").read_text())
    assert set(record) >= {"unknowns", "loss", "iterations", "seconds"}
    assert "unknowns.friction.bounds" in record["outside_envelope"][0]
    assert 0.4 <= record["unknowns"]["friction"] <= 1.0 and np.isfinite(record["loss"])
    assert 1 <= record["iterations"] <= 2
    for name in ("convergence.png", "rollout.npz", "rollout.gif", "metrics.jsonl"):
        assert (out / name).stat().st_size > 0
    lines = [json.loads(line) for line in (out / "metrics.jsonl").read_text().splitlines()]
    assert [line["step"] for line in lines if "friction" in line][:2] == [1, 2]
    # Nothing written is replaced: a second inversion into the same folder is refused.
    before = (out / "result.json").read_bytes()
    again = gns(
        "invert", str(config), "--out", "out", "--no-progress", "--no-tracking", "--outside-envelope", cwd=tmp_path
    )
    assert again.returncode == 2 and "holds an earlier inversion" in again.stderr
    assert (out / "result.json").read_bytes() == before


def test_gns_invert_logs_to_mlflow(tmp_path, tiny_model, dataset_multimaterial, mlflow_store_of_the_session):
    config = write_config(tmp_path / "inv.yaml", config_mapping(tiny_model, dataset_multimaterial))
    result = gns(
        "invert",
        str(config),
        "--out",
        "out",
        "--no-progress",
        "--no-gif",
        "--experiment",
        "inverse-test",
        "--outside-envelope",
        cwd=tmp_path,
    )
    assert result.returncode == 0, result.stderr
    from mlflow.tracking import MlflowClient

    client = MlflowClient(mlflow_store_of_the_session)
    experiment = client.get_experiment_by_name("inverse-test")
    (run,) = client.search_runs([experiment.experiment_id])
    assert {"loss", "friction", "final_loss"} <= set(run.data.metrics)
    assert "unknowns.friction.bounds" in run.data.params["outside_envelope"]
    assert "result.json" in {a.path for a in client.list_artifacts(run.info.run_id)}


def test_model_and_data_problems_are_reported_at_once(tmp_path, tiny_model, dataset_multimaterial):
    raw = config_mapping(tiny_model, dataset_multimaterial)
    raw["observed"]["trajectory"] = 7
    raw["unknowns"] = {
        "cohesion": {"bounds": [0, 1]},
        "initial_velocity": {"particle_type": 3, "bounds": [[-1, 1]]},
    }
    config = write_config(tmp_path / "inv.yaml", raw)
    result = gns("invert", str(config), "--out", "out", "--no-progress", "--no-tracking", cwd=tmp_path)
    assert result.returncode == 2
    for expected in (
        "unknowns.cohesion: the model has no input 'cohesion': it was trained with the material properties: friction",
        "unknowns.initial_velocity.bounds: needs 2 [low, high] pairs",
        "unknowns.initial_velocity.particle_type: 3 is kinematic",
        "observed.trajectory: 7 is out of range",
    ):
        assert expected in result.stderr, result.stderr
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("held_out", [False, True])
def test_gns_invert_returns_its_best_iterate(tmp_path, tiny_model, dataset_multimaterial, held_out):
    configs = tmp_path / "configs"
    configs.mkdir()
    os.symlink(tiny_model, configs / "model.pt")
    os.symlink(dataset_multimaterial, tmp_path / "observed")
    raw = {
        "model": "model.pt",  # beside the config
        "observed": {"dataset": "../observed", "split": "test", "trajectory": 0, "frames": [8, 10, 12]},
        "unknowns": {"friction": {"bounds": [0.4, 1.0], "initial": 0.95}},
        "optimizer": {"name": "adam", "lr": 0.3, "iterations": 6, "lr_decay": 0.8},
        "loss": "positions",
        "checkpoint_every": 3,
        "threads": 1,
    }
    if held_out:
        raw["observed"]["held_out"] = [14, 16]
    (configs / "inv.yaml").write_text(yaml.safe_dump(raw))
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    done = subprocess.run(
        [
            sys.executable,
            "-m",
            "gns_framework.cli",
            "invert",
            str(configs / "inv.yaml"),
            "--out",
            "out",
            "--no-progress",
            "--no-tracking",
            "--no-gif",
            "--outside-envelope",
        ],
        capture_output=True,
        text=True,
        cwd=elsewhere,
        timeout=600,
    )
    assert done.returncode == 0, done.stderr
    record = json.loads((elsewhere / "out" / "result.json").read_text())
    rows = [json.loads(line) for line in (elsewhere / "out" / "metrics.jsonl").read_text().splitlines()]
    rows = [row for row in rows if "friction" in row]
    assert [row["step"] for row in rows][:6] == [1, 2, 3, 4, 5, 6]
    score = "held_out_loss" if held_out else "loss"
    best = min(rows, key=lambda row: row[score])
    assert record["best_iteration"] == best["step"] and record["selected_by"] == ("held_out" if held_out else "loss")
    assert record["loss"] == pytest.approx(best["loss"]) and record["unknowns"]["friction"] == pytest.approx(
        best["friction"]
    )
    assert record["last"]["iteration"] == rows[-1]["step"]
    assert all(record.get("held_out_loss", record["loss"]) <= row[score] for row in rows)
    # The synthetic data holds its friction in its property column: the truth, and the error of both answers.
    truth = record["truth"]["friction"]
    assert record["error_pct"]["friction"] == pytest.approx(100 * abs(record["unknowns"]["friction"] - truth) / truth)
    assert "error_pct" in record["last"] and "unknowns.friction.bounds" in record["outside_envelope"][0]
    assert f"iteration {record['best_iteration']}" in done.stdout and "error" in done.stdout
    assert (elsewhere / "out" / "convergence.png").stat().st_size > 0


def test_gns_invert_searches_several_starts_as_one_batch(tmp_path, tiny_model, dataset_multimaterial):
    raw = config_mapping(
        tiny_model,
        dataset_multimaterial,
        optimizer={"name": "adam", "lr": 0.1, "iterations": 3, "starts": 3, "seed": 1},
        observed={"dataset": str(dataset_multimaterial), "split": "test", "trajectory": 0, "frames": [8, 10]},
    )
    config = write_config(tmp_path / "inv.yaml", raw)
    done = gns(
        "invert", str(config), "--out", "out", "--no-progress", "--no-tracking", "--no-gif", "--outside-envelope",
        cwd=tmp_path,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    record = json.loads((tmp_path / "out" / "result.json").read_text())
    assert [entry["start"] for entry in record["starts"]] == [0, 1, 2]
    assert record["starts"][0]["initial"]["friction"] == pytest.approx(0.7)
    assert len({round(entry["initial"]["friction"], 6) for entry in record["starts"]}) == 3
    best = record["starts"][record["best_start"]]
    assert record["loss"] == min(entry["loss"] for entry in record["starts"]) == best["loss"]
    assert record["unknowns"] == best["unknowns"] and record["evaluations"] == 4
    rows = [json.loads(line) for line in (tmp_path / "out" / "metrics.jsonl").read_text().splitlines()]
    for start in range(3):
        losses = [row[f"start{start}.loss"] for row in rows if f"start{start}.loss" in row]
        assert len(losses) in (3, 4) and min(losses) == pytest.approx(record["starts"][start]["loss"])
    assert f"start {record['best_start']} of 3" in done.stdout and "4 batched rollouts of 3 starts" in done.stdout
