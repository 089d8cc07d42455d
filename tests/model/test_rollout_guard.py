"""Rollout guard: NaN/Inf and escaped particles stop a rollout (or are clamped), named by step, particle and cause."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
import torch
from tiny import tiny_recipe, tiny_trainer

from gns_framework.cli import main
from gns_framework.config.recipe import validate_recipe
from gns_framework.contracts import ModelSetup
from gns_framework.data.trajectory import Trajectory
from gns_framework.errors import DatasetError, RecipeError, RolloutDiverged
from gns_framework.io.checkpoint import load_checkpoint, save_checkpoint
from gns_framework.io.rollout_file import load_rollout, write_rollout
from gns_framework.model.rollout import rollout
from gns_framework.model.rollout_guard import RolloutGuard
from gns_framework.plugins import load_registry
from gns_framework.stability.extreme import extreme_metadata, tiny_simulator

pytestmark = [pytest.mark.stability, pytest.mark.usefixtures("one_torch_thread")]

REGISTRY = load_registry()
BOX = ModelSetup(dim=2, bounds=((0.0, 1.0), (0.0, 2.0)), connectivity_radius=0.1, particle_types=(5,))


def resting(particles: int = 9) -> Trajectory:
    grid = np.stack(np.meshgrid(np.linspace(0.3, 0.7, 3), np.linspace(0.3, 0.7, 3), indexing="ij"), -1).reshape(-1, 2)
    return Trajectory(
        np.repeat(grid[None, :particles].astype(np.float32), 12, axis=0),
        np.full(particles, 5, dtype=np.int64),
        key="resting",
    )


def test_non_finite_positions_stop_naming_step_particles_and_cause():
    position = torch.full((8, 2), 0.5)
    position[[2, 6], 1] = math.nan
    position[4, 0] = math.inf
    with pytest.raises(RolloutDiverged) as info:
        RolloutGuard(BOX).check(3, position, torch.full((8, 2), 0.5), trajectory="t7")
    message = str(info.value)
    assert "trajectory 't7'" in message and "step 3 (frame 9)" in message
    assert "3 particle(s) [2, 4, 6] have non-finite positions" in message
    assert info.value.step == 3 and info.value.particles == [2, 4, 6]


def test_escape_beyond_the_margin_stops_and_names_the_farthest_particle():
    position = torch.full((12, 2), 0.5)
    position[1, 1] = 2.25  # 0.25 above the upper wall: inside the margin
    position[[3, 5, 7, 8, 9, 10, 11], 0] = torch.tensor([-0.4, 1.4, 1.31, 1.32, 1.33, 1.34, 5.0])
    with pytest.raises(RolloutDiverged) as info:
        RolloutGuard(BOX, margin=0.3).check(0, position, position)
    message = str(info.value)
    assert "7 particle(s) [3, 5, 7, 8, 9, ... (7 in all)] left the domain by more than the margin 0.3" in message
    assert "farthest: particle 11, 4 beyond a wall" in message


def test_clamp_continues_from_the_previous_position_and_the_walls():
    previous = torch.full((3, 2), 0.5)
    position = torch.tensor([[math.nan, 0.5], [3.0, -1.0], [0.9, 1.9]])
    guard = RolloutGuard(BOX, margin=0.1, on_violation="clamp")
    clamped, violations = guard.check(2, position, previous)
    assert torch.equal(clamped, torch.tensor([[0.5, 0.5], [1.0, 0.0], [0.9, 1.9]]))
    assert [v.particles.tolist() for v in violations] == [[0], [1]]
    assert all(v.step == 2 for v in violations)


def test_periodic_dimensions_have_no_walls_to_leave():
    periodic = ModelSetup(
        dim=2, bounds=((0.0, 1.0), (0.0, 1.0)), connectivity_radius=0.1, particle_types=(5,), periodic=(True, False)
    )
    position = torch.tensor([[7.0, 0.5]])
    assert RolloutGuard(periodic, margin=0.0).check(0, position, position)[1] == []
    with pytest.raises(RolloutDiverged):
        RolloutGuard(periodic, margin=0.0).check(0, torch.tensor([[0.5, 7.0]]), position)


def test_by_default_only_non_finite_positions_are_caught():
    far = torch.tensor([[1e30, -1e30]])
    assert RolloutGuard(BOX).check(0, far, far)[1] == []


def _sabotaged(value: float):
    simulator = tiny_simulator(REGISTRY, 2)
    simulator.output_stats.mean.fill_(value)
    return simulator


def test_rollout_stops_by_default_on_a_diverging_model():
    with pytest.raises(RolloutDiverged, match=r"trajectory 'resting' stopped at step 0 \(frame 6\): 9 particle"):
        rollout(_sabotaged(math.nan), resting(), steps=4)


def test_clamped_rollout_is_finite_and_reports_every_step():
    guard = RolloutGuard(BOX, margin=0.1, on_violation="clamp")
    result = rollout(_sabotaged(0.5), resting(), steps=4, guard=guard)
    assert np.isfinite(result.predicted).all()
    assert result.predicted[:, :, 0].max() <= 1.0
    assert [v.step for v in result.guard_violations] == [0, 1, 2, 3]


def test_write_rollout_refuses_nan_and_leaves_the_old_file(tmp_path):
    guard = RolloutGuard(BOX, margin=0.1, on_violation="clamp")
    good = rollout(_sabotaged(0.0), resting(), steps=3, guard=guard)
    metadata = extreme_metadata(2)
    path = write_rollout(tmp_path / "r.npz", good, metadata)
    before = path.read_bytes()
    bad_prediction = good.predicted.copy()
    bad_prediction[1, 4] = np.nan
    bad = replace(good, predicted=bad_prediction)
    with pytest.raises(
        RolloutDiverged, match=r"r\.npz: predicted_rollout: non-finite positions from step 1 on \(particles \[4\]"
    ):
        write_rollout(path, bad, metadata)
    assert path.read_bytes() == before
    write_rollout(path, bad, metadata, allow_non_finite=True)
    assert np.isnan(load_rollout(path).predicted[1, 4]).all()


def test_recipe_guard_section_is_validated():
    raw = {"name": "g", "dataset": {"path": "d"}, "rollout": {"guard": {"margin": -1, "on_violation": "explode"}}}
    with pytest.raises(RecipeError) as info:
        validate_recipe(raw, REGISTRY)
    locations = dict(info.value.problems)
    assert "rollout.guard.margin" in locations and "rollout.guard.on_violation" in locations


@pytest.fixture(scope="module")
def nan_checkpoint(dataset_2d, tmp_path_factory):
    run = tmp_path_factory.mktemp("guarded")
    trainer = tiny_trainer(tiny_recipe(dataset_2d), run)
    trainer.train(1)
    trainer.close()
    state = load_checkpoint(run / "checkpoints" / "checkpoint-000000001.pt")
    state["model"]["output_stats.mean"] = torch.full_like(state["model"]["output_stats.mean"], math.nan)
    return save_checkpoint(run / "checkpoints" / "checkpoint-000000002.pt", state)


def test_gns_rollout_stops_with_a_clear_error_and_writes_nothing(nan_checkpoint, tmp_path, capsys):
    out = tmp_path / "rollouts"
    out.mkdir()
    (out / "test_0000.npz").write_bytes(b"an earlier rollout")
    code = main(
        ["rollout", "--outside-envelope", str(nan_checkpoint), "--out", str(out), "--steps", "3", "--no-progress"]
    )
    err = capsys.readouterr().err
    assert code == 2
    assert "gns rollout: error: rollout of trajectory 'test_000' stopped at step 0 (frame 6)" in err
    assert "have non-finite positions (NaN or Inf)" in err
    assert sorted(p.name for p in out.iterdir()) == ["test_0000.npz"]
    assert (out / "test_0000.npz").read_bytes() == b"an earlier rollout"


def test_gns_rollout_with_clamp_writes_the_clamped_rollout_and_says_so(nan_checkpoint, tmp_path, capsys):
    code = main(
        [
            "rollout",
            "--outside-envelope",
            str(nan_checkpoint),
            "--out",
            str(tmp_path),
            "--steps",
            "3",
            "--no-progress",
            "--on-violation",
            "clamp",
        ]
    )
    captured = capsys.readouterr()
    assert code == 0
    assert "clamped at 3 check(s)" in captured.out
    assert "warning:" in captured.err and "step 2 (frame 8)" in captured.err
    assert np.isfinite(load_rollout(tmp_path / "test_0000.npz").predicted).all()


def test_rollout_refuses_trajectories_the_model_was_not_built_for():
    simulator = tiny_simulator(REGISTRY, 2)
    flat = resting()
    with pytest.raises(DatasetError, match=r"trajectory 'resting': particle_type: ids \[9\] are not among"):
        rollout(simulator, replace(flat, particle_type=np.full(9, 9)), steps=2)
    deep = replace(flat, position=np.zeros((12, 9, 3), np.float32))
    with pytest.raises(
        DatasetError, match=r"trajectory 'resting': position: has d = 3 but the model simulates dim = 2"
    ):
        rollout(simulator, deep, steps=2)


def test_a_trajectory_with_its_own_domain_is_guarded_by_its_own_walls():
    """The model's bounds are (0, 1) x (0, 2); the trajectory's box ends at x = 0.5: a particle at 0.7 has left it."""
    small_box = np.array([[0.0, 0.5], [0.0, 2.0]], np.float32)
    guard = RolloutGuard(BOX, margin=0.0, on_violation="clamp").with_bounds(small_box)
    position = torch.tensor([[0.2, 0.5], [0.7, 0.5]])
    clamped, violations = guard.check(0, position, position)
    assert [v.particles.tolist() for v in violations] == [[1]]
    torch.testing.assert_close(clamped[1], torch.tensor([0.5, 0.5]))
    assert RolloutGuard(BOX, margin=0.0).check(0, position, position)[1] == []  # the model's own box holds it

    simulator = tiny_simulator(REGISTRY, 2)
    stay = resting()
    own = replace(stay, position=stay.position * 0.5, bounds=np.array([[0.0, 0.2], [0.0, 0.2]], np.float32))
    result = rollout(simulator, own, steps=3, guard=RolloutGuard(simulator.setup, margin=0.0, on_violation="clamp"))
    assert result.guard_violations and all(v.cause.startswith("left the domain") for v in result.guard_violations)


def test_rewritten_walls_reach_the_copies_a_captured_step_already_reads():
    # A capacity class's next batch rewrites the walls in place (model/capacity_classes.py): the float32 copies
    # made for the first batch's steps must hold the new walls, not only the float64 originals.
    guard = RolloutGuard(BOX, margin=0.0, on_violation="clamp").with_bounds(np.array([[[0.0, 1.0], [0.0, 2.0]]] * 2))
    position = torch.tensor([[1.5, 0.5], [0.5, 0.5]])
    assert guard.continued(position, position)[0, 0] == 1.0  # makes the float32 copies, holds the particle
    guard.rewrite_bounds(np.array([[[0.0, 2.0], [0.0, 2.0]]] * 2))
    assert guard.continued(position, position)[0, 0] == 1.5
    with pytest.raises(ValueError, match=r"walls of shape \(3, 2\) cannot replace walls of shape \(2, 2\)"):
        guard.rewrite_bounds(np.zeros((3, 2, 2)))
