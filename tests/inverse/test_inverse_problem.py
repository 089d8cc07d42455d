"""gns invert: gradients of the learned rollout against finite differences, config errors, outputs.

The gradient checks run the shipped model in float64 on a short rollout of a
synthetic granular-like trajectory. The loss is smooth only piecewise: a pair of
particles crossing the connectivity radius adds or removes an edge. Central
differences in float64 with step h have truncation error O(h^2 f''') and round-off
O(eps f / h), both ~1e-9 relative at h = 1e-6 of the unit-scaled unknown; a larger
step (1e-5) already crosses such a kink on this trajectory and is off by 0.4 %.
"""

from __future__ import annotations

import json
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import torch
import yaml
from synthetic import soft_sphere_trajectory, synthetic_metadata

from gns_framework.assembly.trained import load_trained
from gns_framework.errors import RecipeError
from gns_framework.inverse.config import PropertyUnknown, VelocityUnknown, parse_invert_config
from gns_framework.inverse.optimize import InversionDiverged, adam
from gns_framework.inverse.problem import InverseProblem

MODEL = Path(__file__).resolve().parents[2] / "models" / "sand2d_fast.pt"
SAND = 6
UNKNOWNS = {
    "friction": PropertyUnknown(bounds=(0.4, 1.0), initial=0.7),
    "initial_velocity": VelocityUnknown(
        particle_type=SAND, bounds=[(-0.5, 0.5), (-0.5, 0.5)], initial=[0.1, -0.05], gravity=[0.0, -9.81]
    ),
}


@pytest.fixture(scope="module")
def shipped_float64(registry):
    model = load_trained(MODEL, registry, "cpu")
    return model.simulator.double()


@pytest.fixture(scope="module")
def observed():
    """A falling block of sand-typed particles with a friction column, 12 frames."""
    trajectory = soft_sphere_trajectory(3, frames=12, block=5, particle_types=(SAND,), with_property=True, key="block")
    return trajectory, synthetic_metadata([trajectory], 2)


def problem_of(simulator, observed, loss: str, checkpoint_every: int = 0, frames=(9, 11), unknowns=UNKNOWNS):
    trajectory, metadata = observed
    return InverseProblem(
        simulator,
        trajectory,
        metadata,
        unknowns,
        loss,
        list(frames),
        checkpoint_every=checkpoint_every,
        dtype=torch.float64,
    )


def autograd_and_central_differences(problem: InverseProblem, h: float = 1e-6) -> tuple[np.ndarray, np.ndarray]:
    u = torch.tensor(problem.start, dtype=torch.float64, requires_grad=True)
    (gradient,) = torch.autograd.grad(problem.loss(u), u)
    differences = []
    with torch.no_grad():
        for i in range(len(problem.start)):
            step = torch.zeros_like(u)
            step[i] = h
            differences.append((problem.loss(u + step).item() - problem.loss(u - step).item()) / (2 * h))
    return gradient.numpy(), np.array(differences)


@pytest.mark.parametrize("loss", ["positions", "runout"])
def test_the_gradient_of_every_unknown_matches_central_differences(shipped_float64, observed, loss):
    gradient, differences = autograd_and_central_differences(problem_of(shipped_float64, observed, loss))
    assert np.all(np.abs(differences) > 0), "every unknown moves the loss"
    relative = np.abs(gradient - differences) / np.abs(differences)
    assert relative.max() <= 1e-3, (gradient, differences)


def test_the_sinkhorn_gradient_matches_central_differences(shipped_float64, observed):
    # geomloss differentiates the converged dual potentials (envelope theorem), so the
    # gradient is that of the Sinkhorn divergence itself, to the solver's tolerance.
    gradient, differences = autograd_and_central_differences(problem_of(shipped_float64, observed, "sinkhorn"))
    relative = np.abs(gradient - differences) / np.abs(differences)
    assert relative.max() <= 1e-3, (gradient, differences)


def test_the_gradient_check_catches_a_wrong_gradient(shipped_float64, observed):
    """The same comparison fails when the unknown's path into the model is cut (a detach)."""
    problem = problem_of(shipped_float64, observed, "positions")
    inputs = problem.model_inputs

    def detached_property(u):
        state = inputs(u)
        return replace(state, material_property=state.material_property.detach())

    problem.model_inputs = detached_property
    gradient, differences = autograd_and_central_differences(problem)
    relative = np.abs(gradient - differences) / np.abs(differences)
    assert relative[0] > 1e-3


def test_checkpointing_gives_the_same_loss_and_gradient(shipped_float64, observed):
    whole, checkpointed = (problem_of(shipped_float64, observed, "positions", k) for k in (0, 2))
    results = []
    for problem in (whole, checkpointed):
        u = torch.tensor(problem.start, dtype=torch.float64, requires_grad=True)
        loss = problem.loss(u)
        results.append((loss.item(), torch.autograd.grad(loss, u)[0].numpy()))
    assert results[0][0] == pytest.approx(results[1][0], rel=1e-12)
    np.testing.assert_allclose(results[0][1], results[1][1], rtol=1e-10)


def test_the_observed_value_of_an_unknown_is_never_read(shipped_float64, observed):
    trajectory, metadata = observed
    altered = replace(
        trajectory,
        material_property=np.full_like(trajectory.material_property, 0.1),
        position=trajectory.position.copy(),
    )
    altered.position[1:6] += 0.01  # the C - 1 input frames after the first: rebuilt from the unknown velocity
    u = torch.tensor(problem_of(shipped_float64, observed, "positions").start)
    with torch.no_grad():
        first = problem_of(shipped_float64, observed, "positions").loss(u)
        second = problem_of(shipped_float64, (altered, metadata), "positions").loss(u)
    assert float(first) == float(second)


def test_adam_stops_on_a_non_finite_loss_naming_the_field():
    def loss(u):
        return (u * float("nan")).sum()

    with pytest.raises(InversionDiverged, match=r"loss: non-finite value at evaluation 1 \(friction 0.7\)"):
        adam(loss, np.array([0.5]), 0.1, 3, lambda it: None, lambda u: "friction 0.7")


def config_mapping(model: Path, dataset: Path, **changes) -> dict:
    raw = {
        "model": str(model),
        "observed": {"dataset": str(dataset), "split": "test", "trajectory": 0, "frames": "last"},
        "unknowns": {"friction": {"bounds": [0.4, 1.0], "initial": 0.7}},
        "optimizer": {"name": "adam", "lr": 0.05, "iterations": 2},
        "loss": "positions",
        "checkpoint_every": 3,
        "threads": 1,
    }
    raw.update(changes)
    return raw


def test_schema_problems_are_reported_at_once_with_their_location():
    raw = config_mapping(Path("m.pt"), Path("d"), optimizer={"name": "sgd", "iterations": 0}, loss="runnout")
    raw["unknowns"] = {
        "friction": {"bounds": [0.4, 1.0], "initial": 1.2},
        "initial_velocity": {"particle_type": 6, "bounds": [[1, -1], [0, 1]]},
    }
    with pytest.raises(RecipeError) as caught:
        parse_invert_config(raw, "inv.yaml")
    locations = {loc for loc, _ in caught.value.problems}
    assert {
        "optimizer.name",
        "optimizer.iterations",
        "loss",
        "unknowns.friction",
        "unknowns.initial_velocity",
    } <= locations
    text = str(caught.value)
    assert "initial 1.2 lies outside its bounds [0.4, 1.0]" in text
    assert "axis 0: bounds must be [low, high] with low <= high" in text


def gns(*args: str, cwd: Path) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "gns_framework.cli", *args], capture_output=True, text=True, cwd=cwd, timeout=600
    )


def write_config(path: Path, raw: dict) -> Path:
    path.write_text(yaml.safe_dump(raw))
    return path


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


def test_equal_bounds_fix_a_known_velocity_axis(shipped_float64, observed):
    unknowns = {"initial_velocity": VelocityUnknown(particle_type=SAND, bounds=[(0.0, 1.0), (-0.2, -0.2)])}
    problem = problem_of(shipped_float64, observed, "positions", unknowns=unknowns)
    assert problem.start.tolist() == [0.5, 0.5]
    u = torch.tensor(problem.start, requires_grad=True)
    gradient = torch.autograd.grad(problem.loss(u), u)[0]
    assert gradient[0] != 0 and gradient[1] == 0
    assert problem.parameters.values(torch.tensor([0.25, 0.9], dtype=torch.float64)).tolist() == [0.25, -0.2]
    with pytest.raises(RecipeError, match=r"unknowns.friction: .*low < high"):
        parse_invert_config(
            {"model": "m", "observed": {"dataset": "d"}, "unknowns": {"friction": {"bounds": [0.5, 0.5]}}}, "x"
        )


def test_a_ballistic_start_is_rebuilt_exactly(shipped_float64, observed):
    """With the scene's gravity the input frames of a body in free flight are those the data holds."""
    trajectory, metadata = observed
    dt, launch, gravity = metadata.dt, np.array([0.3, 0.5]), np.array([0.0, -9.81])
    times = np.arange(trajectory.num_steps)[:, None, None] * dt
    flight = trajectory.position[0][None] + times * launch + 0.5 * times**2 * gravity
    flying = replace(trajectory, position=flight.astype(np.float64))
    unknowns = {
        "initial_velocity": VelocityUnknown(
            particle_type=SAND, bounds=[(0.0, 1.0), (0.0, 1.0)], gravity=gravity.tolist()
        )
    }
    problem = problem_of(shipped_float64, (flying, metadata), "positions", unknowns=unknowns)
    u = torch.tensor(problem.parameters.scaled(launch))
    rebuilt = problem.model_inputs(u).position_sequence.transpose(0, 1).numpy()
    np.testing.assert_allclose(rebuilt, flight[:6], rtol=0, atol=1e-12)
    with pytest.raises(RecipeError, match=r"gravity has 3 entries but bounds has 2"):
        parse_invert_config(
            {
                "model": "m",
                "observed": {"dataset": "d"},
                "unknowns": {
                    "initial_velocity": {"particle_type": 6, "bounds": [[0, 1], [0, 1]], "gravity": [0, 0, -9.81]}
                },
            },
            "x",
        )


@pytest.mark.parametrize("path", sorted((Path(__file__).resolve().parents[2] / "inversions").glob("*.yaml")))
def test_the_example_inversions_name_a_shipped_model_and_validate(path, registry):
    from gns_framework.inverse.config import load_invert_config

    config, unknowns = load_invert_config(path)  # the model is named relative to the config file
    model = load_trained(config.model, registry, "cpu")
    for name, unknown in unknowns.items():
        assert name in model.simulator.scene.property_names or isinstance(unknown, VelocityUnknown)
