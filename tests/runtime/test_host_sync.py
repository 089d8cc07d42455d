"""A training step and a rollout step read nothing back from the device but what gns_framework.runtime.host_sync
documents.

On the CPU reads cost nothing, so the CPU paths may read; here the accelerators'
paths are taken on the CPU (``avoids_read_backs`` and ``needs_ordered_sums``
answer as on a GPU) and every way Python reads a tensor's value raises inside
the step. ``read_back``, the documented waits, is counted instead.
"""

from __future__ import annotations

import contextlib

import pytest
import torch
from tiny import tiny_recipe, tiny_trainer

import gns_framework.runtime.host_sync as host_sync
from gns_builtins._kernels import edge_block
from gns_framework.model import learned_simulator as simulator_module
from gns_framework.model import rollout as rollout_module
from gns_framework.model.rollout import rollout
from gns_framework.model.rollout_guard import RolloutGuard
from gns_framework.training import trainer as trainer_module
from gns_framework.training.trainer import Trainer

READS = ("item", "tolist", "cpu", "numpy", "__bool__", "__int__", "__float__", "__index__")
ORIGINAL_READS = {name: getattr(torch.Tensor, name) for name in READS}


class HostRead(AssertionError):
    pass


@pytest.fixture
def as_on_a_gpu(monkeypatch):
    """The accelerators' choices, on the CPU; returns the list of documented read-backs made while forbidding."""
    for module in (simulator_module, edge_block, rollout_module, trainer_module):
        monkeypatch.setattr(module, "avoids_read_backs", lambda device: True)
    monkeypatch.setattr(edge_block, "needs_ordered_sums", lambda device: True)
    return monkeypatch


@contextlib.contextmanager
def no_host_reads(monkeypatch, documented: list):
    """Inside: any read of a tensor's value raises HostRead, except through host_sync.read_back (recorded)."""

    def forbidden(name):
        def read(self, *args, **kwargs):
            raise HostRead(f"Tensor.{name} in the hot path")

        return read

    def counted(tensor):
        documented.append(tuple(tensor.shape))
        with reads_allowed(monkeypatch):
            return tensor.tolist()

    with monkeypatch.context() as patch:
        for name in READS:
            patch.setattr(torch.Tensor, name, forbidden(name))
        for module in (host_sync, trainer_module):
            patch.setattr(module, "read_back", counted)
        from gns_builtins._kernels import cell_list

        patch.setattr(cell_list, "read_back", counted)
        yield


@contextlib.contextmanager
def reads_allowed(monkeypatch):
    with monkeypatch.context() as allowed:
        for name, method in ORIGINAL_READS.items():
            allowed.setattr(torch.Tensor, name, method)
        yield


def test_the_trap_catches_a_read(monkeypatch):
    with pytest.raises(HostRead), no_host_reads(monkeypatch, []):
        torch.ones(2).sum().item()
    with pytest.raises(HostRead), no_host_reads(monkeypatch, []):
        bool(torch.ones(2).all())


def test_a_training_step_reads_back_only_the_edge_count(as_on_a_gpu, dataset_multimaterial, tmp_path, registry):
    trainer = tiny_trainer(tiny_recipe(dataset_multimaterial, registry), tmp_path, registry)
    trainer.train_step()  # the first step may set up (build kernels, caches)
    documented: list = []
    step = Trainer.train_step

    def trapped(self):
        with no_host_reads(as_on_a_gpu, documented):
            return step(self)

    as_on_a_gpu.setattr(Trainer, "train_step", trapped)
    # Adam keeps its step counts on the host (unless capturable or fused): reading them waits for nothing.
    optimizer_step = trainer.optimizer.step

    def host_optimizer_step(*args, **kwargs):
        with reads_allowed(as_on_a_gpu):
            return optimizer_step(*args, **kwargs)

    trainer.optimizer.step = host_optimizer_step
    losses = trainer.train(3)
    trainer.close()
    # One read of the candidate count per graph (small scenes: one chunk), then the two losses at step 3.
    assert documented == [()] * 2 and len(losses) == 2


@pytest.mark.parametrize("on_violation", ["stop", "clamp"])
def test_a_rollout_step_reads_back_only_the_edge_count(
    as_on_a_gpu, on_violation, dataset_multimaterial, tmp_path, registry
):
    trainer = tiny_trainer(tiny_recipe(dataset_multimaterial, registry), tmp_path, registry)
    trajectory = trainer.data.dataset.split("test")[0]
    guard = RolloutGuard(trainer.data.setup, margin=0.5, on_violation=on_violation)
    documented: list = []
    step = rollout_module.rollout_step

    def trapped(*args):
        with no_host_reads(as_on_a_gpu, documented):
            return step(*args)

    as_on_a_gpu.setattr(rollout_module, "rollout_step", trapped)
    result = rollout(trainer.simulator, trajectory, steps=4, guard=guard)
    trainer.close()
    assert documented == [()] * 4
    assert result.predicted.shape[0] == 4


def test_the_read_back_free_rollout_equals_the_cpu_one(as_on_a_gpu, dataset_multimaterial, tmp_path, registry):
    """Decoding every row and replacing the kinematic ones, lagged host copies and ordered sums: the same frames."""
    trainer = tiny_trainer(tiny_recipe(dataset_multimaterial, registry), tmp_path, registry)
    trajectory = trainer.data.dataset.split("test")[0]
    for _ in range(3):
        trainer.train_step()
    guard = RolloutGuard(trainer.data.setup, margin=0.05, on_violation="clamp")
    gpu_like = rollout(trainer.simulator, trajectory, steps=12, guard=guard)
    as_on_a_gpu.undo()
    cpu = rollout(trainer.simulator, trajectory, steps=12, guard=guard)
    trainer.close()
    assert [v.describe() for v in gpu_like.guard_violations] == [v.describe() for v in cpu.guard_violations]
    scale = float(abs(cpu.predicted).max())
    assert abs(gpu_like.predicted - cpu.predicted).max() <= 1e-5 * scale
    assert (gpu_like.predicted[:, ~cpu.predicted_particles] == cpu.ground_truth[:, ~cpu.predicted_particles]).all()


def test_the_guard_continues_from_the_frame_its_check_returns(registry, dataset_multimaterial, tmp_path):
    scene = tiny_trainer(tiny_recipe(dataset_multimaterial, registry), tmp_path, registry).data.setup
    previous = torch.full((5, scene.dim), 0.5)
    position = previous + 0.01
    position[1, 0] = float("nan")
    position[2, 1] = scene.bounds[1][1] + 0.3  # escaped beyond the margin
    position[3, 0] = scene.bounds[0][0] - 0.01  # outside, within the margin
    clamp = RolloutGuard(scene, margin=0.1, on_violation="clamp")
    checked, violations = clamp.check(0, position.clone(), previous)
    assert len(violations) == 2
    assert torch.equal(clamp.continued(position, previous), checked)
    stop = RolloutGuard(scene, margin=0.1, on_violation="stop")
    expected = position.clone()
    expected[1] = previous[1]
    assert torch.equal(stop.continued(position, previous), expected)


def test_the_radius_graph_waits_for_the_device_once_per_chunk_at_the_dispatch_level():
    """Seen below Python (TorchDispatchMode): no torch.unique, one kept-pair count per chunk of candidates.

    With the explicit read-back of the candidate count (counted by the tests above) that is
    two waits per graph build of one chunk, against seven before (four torch.unique, two masks).
    """
    from gns_builtins._kernels import cell_list
    from gns_framework.runtime.sync_counter import SyncCounter

    generator = torch.Generator().manual_seed(0)
    position = torch.rand(3000, 3, generator=generator)
    batch = torch.cat([torch.zeros(1500, dtype=torch.long), torch.ones(1500, dtype=torch.long)])
    with SyncCounter() as one_chunk:
        cell_list.radius_pairs(position, batch, 0.08)
    assert one_chunk.counts == {"aten.nonzero": 1}
    senders, _ = cell_list.radius_pairs(position, batch, 0.08)
    previous = cell_list.CANDIDATES_PER_CHUNK_CPU
    try:
        # Chunks of a few times the edge count's size: the candidates (~2x the edges) span several.
        cell_list.CANDIDATES_PER_CHUNK_CPU = senders.numel() // 2
        with SyncCounter() as several:
            chunked, _ = cell_list.radius_pairs(position, batch, 0.08)
    finally:
        cell_list.CANDIDATES_PER_CHUNK_CPU = previous
    assert torch.equal(chunked, senders)
    assert set(several.counts) == {"aten.nonzero"} and several.counts["aten.nonzero"] >= 3
