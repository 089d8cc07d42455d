"""What training on GPUs relies on, checked on the CPU: resume without CUDA generators, the process group's device and
timeout, timing."""

from __future__ import annotations

from datetime import timedelta

import pytest
import torch
from tiny import tiny_recipe, tiny_trainer

from gns_framework.io.checkpoint import load_checkpoint, save_checkpoint
from gns_framework.training import distributed
from gns_framework.training import progress as progress_module
from gns_framework.training import trainer as trainer_module
from gns_framework.training.distributed import Processes


def test_resume_ignores_the_cuda_generators_of_a_checkpoint_written_with_more_gpus(
    dataset_multimaterial, tmp_path, registry, monkeypatch
):
    """A checkpoint from an 8-GPU run, resumed where fewer GPUs are visible: restoring 8 states raised IndexError."""
    recipe = tiny_recipe(dataset_multimaterial, registry)
    trainer = tiny_trainer(recipe, tmp_path, registry)
    trainer.train(3)
    path = next((tmp_path / "checkpoints").glob("checkpoint-*.pt"))
    state = load_checkpoint(path)
    assert set(state["rng"]) == {"torch"}, "nothing draws from CUDA generators: none is saved"
    state["rng"]["cuda"] = [torch.zeros(16, dtype=torch.uint8)] * 8
    path.unlink()
    save_checkpoint(path, state)

    def fewer_gpus(states):
        raise IndexError("list index out of range")

    monkeypatch.setattr(torch.cuda, "is_available", lambda: True)
    monkeypatch.setattr(torch.cuda, "set_rng_state_all", fewer_gpus)
    resumed = tiny_trainer(recipe, tmp_path, registry)
    assert resumed.checkpoints.resume() == path and resumed.step == 3


def test_the_process_group_is_given_the_rank_gpu(monkeypatch):
    seen = {}
    monkeypatch.setattr(distributed.dist, "is_initialized", lambda: False)
    monkeypatch.setattr(distributed.dist, "rendezvous", lambda *args: iter([(distributed.dist.HashStore(), 1, 2)]))
    monkeypatch.setattr(distributed.dist, "init_process_group", lambda **kwargs: seen.update(kwargs))
    monkeypatch.setattr(torch.cuda, "set_device", lambda device: seen.setdefault("current", device))
    monkeypatch.setattr(torch.cuda, "device_count", lambda: 1)
    device = distributed.start(Processes(rank=1, world_size=2, local_rank=1), torch.device("cuda"))
    assert device == torch.device("cuda", 0) == seen["device_id"] == seen["current"]
    assert seen["backend"] == "nccl"
    assert (
        seen["timeout"] == distributed.process_group_timeout() == timedelta(seconds=distributed.PROCESS_GROUP_TIMEOUT_S)
    )
    seen.clear()
    distributed.start(Processes(rank=1, world_size=2, local_rank=1), torch.device("cpu"))
    assert seen["device_id"] is None and seen["backend"] == "gloo"


def test_the_process_group_timeout_comes_from_the_environment_or_is_an_hour(monkeypatch):
    assert distributed.process_group_timeout({}) == timedelta(hours=1)
    assert distributed.process_group_timeout({"GNS_PROCESS_GROUP_TIMEOUT_S": "90"}) == timedelta(seconds=90)
    for bad in ("soon", "0", "-5"):
        with pytest.raises(ValueError, match="GNS_PROCESS_GROUP_TIMEOUT_S"):
            distributed.process_group_timeout({"GNS_PROCESS_GROUP_TIMEOUT_S": bad})
    seen = {}
    monkeypatch.setenv("GNS_PROCESS_GROUP_TIMEOUT_S", "120")
    monkeypatch.setattr(distributed.dist, "is_initialized", lambda: False)
    monkeypatch.setattr(distributed.dist, "rendezvous", lambda *args: iter([(distributed.dist.HashStore(), 0, 2)]))
    monkeypatch.setattr(distributed.dist, "init_process_group", lambda **kwargs: seen.update(kwargs))
    distributed.start(Processes(rank=0, world_size=2), torch.device("cpu"))
    assert seen["timeout"] == timedelta(seconds=120)


def test_throughput_is_timed_between_device_synchronisations(dataset_multimaterial, tmp_path, registry, monkeypatch):
    """Each logged window starts and ends with a synchronisation, so queued GPU work is inside it."""
    events = []
    monkeypatch.setattr(progress_module, "synchronize", lambda device: events.append(("sync", device.type)))
    raw_step = trainer_module.Trainer.train_step

    def step(self):
        events.append(("step", self.step))
        return raw_step(self)

    monkeypatch.setattr(trainer_module.Trainer, "train_step", step)
    recipe = tiny_recipe(dataset_multimaterial, registry)
    recipe = recipe.model_copy(update={"training": recipe.training.model_copy(update={"log_every": 2})})
    trainer = tiny_trainer(recipe, tmp_path, registry)
    trainer.train(4)
    trainer.close()
    sync = ("sync", "cpu")
    assert events == [sync, ("step", 0), ("step", 1), sync, sync, ("step", 2), ("step", 3), sync]


def test_tf32_is_float32_on_the_cpu_and_its_cuda_setting_is_restored(dataset_multimaterial, tmp_path, registry):
    from gns_framework.runtime.tf32 import cuda_tf32

    losses = {}
    for precision in ("float32", "tf32"):
        recipe = tiny_recipe(dataset_multimaterial, registry)
        recipe = recipe.model_copy(update={"training": recipe.training.model_copy(update={"precision": precision})})
        trainer = tiny_trainer(recipe, tmp_path / precision, registry)
        losses[precision] = trainer.train(2)
        trainer.close()
    assert losses["tf32"] == losses["float32"]
    before = torch.backends.cuda.matmul.allow_tf32, torch.get_float32_matmul_precision()
    with cuda_tf32():
        assert torch.backends.cuda.matmul.fp32_precision == "tf32"
    assert (torch.backends.cuda.matmul.allow_tf32, torch.get_float32_matmul_precision()) == before
