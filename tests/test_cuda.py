"""Training, resume, rollout, evaluation and the MPM simulator on a CUDA GPU, and their agreement with the CPU.

Every test here is marked ``cuda``: skipped, with the reason, where torch sees no
GPU (tests/conftest.py). benchmarks/gpu_check.sh runs them on GPU machines.
"""

from __future__ import annotations

import copy

import numpy as np
import pytest
import torch
from scene_builders import mixed
from tiny import tiny_recipe_mapping

from gns_framework.assembly.ground_truth import build_ground_truth_simulator as build_ground_truth
from gns_framework.config.recipe import validate_recipe
from gns_framework.evaluation.rollout_scores import validation_rollout_scorer
from gns_framework.ground_truth.scene_spec import parse_scene
from gns_framework.model.rollout import rollout
from gns_framework.training.trainer import Trainer
from gns_framework.training.validation import rollout_score_summary

pytestmark = pytest.mark.cuda

EPS32 = torch.finfo(torch.float32).eps


def _trainer(dataset, run_dir, registry, device, **training):
    raw = tiny_recipe_mapping(dataset, run_dir)
    raw["training"].update(device=device, **training)
    return Trainer(validate_recipe(raw, registry), registry, progress=False)


def test_training_runs_on_the_gpu_and_resumes_exactly(dataset_multimaterial, tmp_path, registry):
    straight = _trainer(dataset_multimaterial, tmp_path / "a", registry, "cuda")
    assert straight.device.type == "cuda" and next(straight.simulator.parameters()).is_cuda
    losses = straight.train(6)
    assert len(losses) == 6 and all(np.isfinite(losses))
    first = _trainer(dataset_multimaterial, tmp_path / "b", registry, "cuda", checkpoint_every=3)
    head = first.train(3)
    resumed = _trainer(dataset_multimaterial, tmp_path / "b", registry, "cuda")
    resumed.checkpoints.resume()
    tail = resumed.train(6)
    # Ordered sums in the edge block and CPU-drawn noise: the GPU repeats itself bit for bit.
    assert head + tail == losses
    for (name, a), (_, b) in zip(
        straight.simulator.state_dict().items(), resumed.simulator.state_dict().items(), strict=True
    ):
        assert torch.equal(a, b), name


def _first_step(trainer: Trainer) -> tuple[float, list[torch.Tensor]]:
    """The first training step's loss and the gradients its optimiser step received."""
    gradients = []
    step = trainer.optimizer.step

    def recording(*args, **kwargs):
        gradients.extend(p.grad.detach().double().cpu() for p in trainer.simulator.parameters())
        return step(*args, **kwargs)

    trainer.optimizer.step = recording
    loss, _ = trainer.train_step()
    return float(loss), gradients


@pytest.mark.parametrize("precision", ["float32", "tf32", "bfloat16"])
def test_a_training_step_agrees_with_the_cpu(precision, dataset_multimaterial, tmp_path, registry):
    cpu = _trainer(dataset_multimaterial, tmp_path / "cpu", registry, "cpu")
    gpu = _trainer(dataset_multimaterial, tmp_path / "gpu", registry, "cuda", precision=precision)
    (cpu_loss, cpu_gradients), (gpu_loss, gpu_gradients) = _first_step(cpu), _first_step(gpu)
    # Same weights, windows and noise. float32 sums in another order move results by ~1e-6,
    # TF32 products (10-bit mantissas) by ~1e-3, bfloat16 products (7-bit) by ~1e-2.
    tolerance = {"float32": 1e-4, "tf32": 1e-2, "bfloat16": 5e-2}[precision]
    assert abs(gpu_loss - cpu_loss) <= tolerance * abs(cpu_loss), (cpu_loss, gpu_loss)
    names = [name for name, _ in cpu.simulator.named_parameters()]
    for name, a, b in zip(names, cpu_gradients, gpu_gradients, strict=True):
        assert torch.linalg.norm(a - b) <= 10 * tolerance * torch.linalg.norm(a) + 1e-12, name


def test_rollout_on_the_gpu_follows_the_cpu_one(dataset_multimaterial, tmp_path, registry):
    trainer = _trainer(dataset_multimaterial, tmp_path, registry, "cpu")
    trainer.train(5)
    trajectory = trainer.data.dataset.split("test")[0]
    cpu = rollout(trainer.simulator, trajectory, steps=5, device="cpu")
    gpu_model = copy.deepcopy(trainer.simulator).to("cuda")
    gpu = rollout(gpu_model, trajectory, steps=5, device="cuda")
    again = rollout(gpu_model, trajectory, steps=5, device="cuda")
    assert np.array_equal(gpu.predicted, again.predicted), "GPU rollouts differ run to run"
    scale = float(np.abs(cpu.predicted).max())
    # Five steps of float32 differences, each ~1e-6 of the positions, grown by the model's sensitivity.
    assert float(np.abs(gpu.predicted - cpu.predicted).max()) <= 1e-4 * scale
    kinematic = ~cpu.predicted_particles
    assert np.array_equal(gpu.predicted[:, kinematic], cpu.ground_truth[:, kinematic])


def test_evaluation_metrics_on_the_gpu_match_the_cpu(dataset_multimaterial, tmp_path, registry):
    pytest.importorskip("geomloss", reason="the Sinkhorn metric needs geomloss (gpu_check.sh carries it)")
    trainer = _trainer(dataset_multimaterial, tmp_path, registry, "cpu")
    trainer.train(5)
    trajectories = [trainer.data.dataset.split("valid")[0]]
    scene, metadata = trainer.data.setup, trainer.data.metadata
    on_cpu = rollout_score_summary(
        trainer.simulator, trajectories, validation_rollout_scorer(registry, scene, metadata, torch.device("cpu"))
    )
    gpu_model = copy.deepcopy(trainer.simulator).to("cuda")
    on_gpu = rollout_score_summary(
        gpu_model, trajectories, validation_rollout_scorer(registry, scene, metadata, torch.device("cuda"))
    )
    assert on_cpu.keys() == on_gpu.keys()
    for name, value in on_cpu.items():
        assert np.isfinite(on_gpu[name]) and abs(on_gpu[name] - value) <= 1e-3 * abs(value) + 1e-9, name


def _simulate(device: str, frames: int):
    raw = mixed(frames)
    raw["simulator"] = {"name": "mls_mpm", "device": device}
    scene = parse_scene(raw)
    return build_ground_truth(scene, _registry(), "<test>").simulate(scene, seed=3)


def _registry():
    from gns_framework.plugins import load_registry

    return load_registry()


def test_mpm_on_the_gpu_repeats_its_bits_and_follows_the_cpu():
    pytest.importorskip("warp", reason="the MLS-MPM needs warp-lang, which the lent GPU machine lacks")
    gpu, again = _simulate("cuda", 10), _simulate("cuda", 10)
    assert gpu.position.tobytes() == again.position.tobytes(), "deterministic atomics differ run to run"
    cpu = _simulate("cpu", 10)
    assert gpu.position.shape == cpu.position.shape and np.isfinite(gpu.position).all()
    # Ten frames of 8 substeps: float32 sums in another order, ~1e-6 m per substep at most.
    assert float(np.abs(gpu.position - cpu.position).max()) <= 1e-4


def test_a_captured_rollout_on_the_gpu_gives_the_eager_frames():
    # gns rollout --capture on CUDA: one CUDA graph per buffer size, replayed; a redo after growth captures again.
    from fixed_capacity_cases import small_simulator, wandering_trajectory

    from gns_framework.model import captured_steps

    processor = {"name": "interaction_network", "message_passing_steps": 2}
    trajectory = wandering_trajectory()
    eager = rollout(small_simulator("radius_fixed_capacity", processor, acc_std=0.02).cuda(), trajectory, device="cuda")
    made = []
    original = captured_steps.CapturedSteps.__init__

    def remember(self, *args, **kwargs):
        original(self, *args, **kwargs)
        made.append(self)

    model = small_simulator("radius_fixed_capacity", processor, acc_std=0.02).cuda()
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(captured_steps.CapturedSteps, "__init__", remember)
        captured = rollout(model, trajectory, device="cuda", capture=True)
    assert made and made[0].captured is not None and made[0].captured._graph is not None
    assert model.graph_builder.search.sizings > 1 and made[0].captures >= 2
    np.testing.assert_allclose(captured.predicted, eager.predicted, rtol=0, atol=1e-5)
