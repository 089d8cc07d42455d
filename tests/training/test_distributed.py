"""Data-parallel training: distinct shards, identical ranks, and the step of one process on the global batch."""

from __future__ import annotations

import json

import torch
from conftest import DDP_SNAPSHOTS
from ddp_worker import share_from_chief, train_rank
from spawned import free_loopback_port, run_processes

from gns_framework.config.recipe import validate_recipe
from gns_framework.data.windows import WindowOrder
from gns_framework.plugins import load_registry
from gns_framework.training.distributed import backend_for, processes_from_environment
from gns_framework.training.trainer import Trainer


def test_ranks_hold_identical_parameters_equal_to_one_process_on_the_global_batch(ddp_snapshots, ddp_recipe, tmp_path):
    steps = DDP_SNAPSHOTS[0]
    rank0, rank1 = ddp_snapshots[0, steps], ddp_snapshots[1, steps]
    assert rank0["windows"] != rank1["windows"], "both ranks trained on the same windows"
    for name, value in rank0["params"].items():
        assert torch.equal(value, rank1["params"][name]), f"{name} differs between ranks after {steps} steps"
    assert rank0["losses"] == rank1["losses"]

    # One process, batch = both ranks' windows: the uneven particle counts make a
    # per-rank mean loss differ from the global one, so this checks the weighting too.
    single = dict(
        ddp_recipe, training=dict(ddp_recipe["training"], batch_size=2 * ddp_recipe["training"]["batch_size"])
    )
    registry = load_registry()
    trainer = Trainer(validate_recipe(single, registry), registry, run_dir=tmp_path / "single", progress=False)
    losses = trainer.train(steps)
    trainer.close()
    assert sorted(trainer.order.draw(0).mine) == sorted(rank0["windows"] + rank1["windows"])
    torch.testing.assert_close(torch.tensor(losses), torch.tensor(rank0["losses"]), rtol=1e-5, atol=1e-7)
    for name, value in trainer.simulator.state_dict().items():
        torch.testing.assert_close(
            value, rank0["params"][name], rtol=1e-5, atol=1e-7, msg=f"{name}: DDP != one process"
        )


def test_ranks_stay_identical_over_a_longer_run(ddp_snapshots):
    steps = DDP_SNAPSHOTS[-1]
    for name, value in ddp_snapshots[0, steps]["params"].items():
        assert torch.equal(value, ddp_snapshots[1, steps]["params"][name]), name


def test_window_order_gives_each_rank_a_distinct_shard_of_every_epoch():
    num_windows, batch = 24, 3
    ranks = [WindowOrder(num_windows, batch, seed=5, rank=r, world_size=2) for r in (0, 1)]
    steps_per_epoch = num_windows // (batch * 2)
    for epoch in range(3):
        seen = [
            w
            for step in range(epoch * steps_per_epoch, (epoch + 1) * steps_per_epoch)
            for o in ranks
            for w in o.draw(step).mine
        ]
        assert sorted(seen) == list(range(num_windows)), f"epoch {epoch} is not one pass over the windows"
    first, second = (ranks[0].draw(s).mine for s in (0, steps_per_epoch))
    assert first != second, "epochs are not reshuffled"


def test_processes_come_from_torchrun_environment():
    env = {"RANK": "3", "WORLD_SIZE": "4", "LOCAL_RANK": "1", "TORCHELASTIC_RESTART_COUNT": "2"}
    processes = processes_from_environment(env)
    assert (processes.rank, processes.world_size, processes.local_rank, processes.restart_count) == (3, 4, 1, 2)
    assert processes.distributed and not processes.is_chief
    assert processes.device(torch.device("cuda"), visible_gpus=4) == torch.device("cuda", 1)
    alone = processes_from_environment({})
    assert not alone.distributed and alone.is_chief and alone.device(torch.device("cuda")) == torch.device("cuda")


def test_backend_is_gloo_on_cpu_and_nccl_on_gpu():
    assert backend_for(torch.device("cpu")) == "gloo"
    assert backend_for(torch.device("cuda", 0)) == "nccl"


def test_ranks_that_keep_a_few_trajectories_train_bitwise_as_ranks_that_keep_all(ddp_snapshots, ddp_recipe, tmp_path):
    """dataset.memory: two processes keep a few trajectories each (auto), with the same windows in the same order."""
    assert ddp_recipe["dataset"].get("memory", "auto") == "auto"  # the snapshots' run: windows mode
    steps = DDP_SNAPSHOTS[0]
    keep_all = dict(ddp_recipe, dataset=dict(ddp_recipe["dataset"], memory="all"))
    run_processes(train_rank, (2, free_loopback_port(), keep_all, str(tmp_path / "run"), [steps], str(tmp_path)))
    for rank in (0, 1):
        whole = torch.load(tmp_path / f"rank{rank}-step{steps}.pt", weights_only=True)
        windows = ddp_snapshots[rank, steps]
        assert whole["losses"] == windows["losses"] and whole["windows"] == windows["windows"]
        for name, value in whole["params"].items():
            assert torch.equal(value, windows["params"][name]), f"rank {rank}: {name} differs with memory: all"


def test_what_rank_0_derives_reaches_every_rank_and_so_does_its_failure(tmp_path):
    run_processes(share_from_chief, (2, free_loopback_port(), str(tmp_path)), seconds=120)
    ranks = [json.loads((tmp_path / f"rank{rank}.json").read_text()) for rank in (0, 1)]
    assert [r["shared"] for r in ranks] == [{"statistics": [0.5, 0.0]}] * 2  # rank 0's value
    assert [r["computed"] for r in ranks] == [[0], []]  # computed once, on rank 0
    reason = "data/train.npz: trajectory 'a': position: non-finite value at frame 3, particle 1"
    assert ranks[0]["failure"] == f"DatasetError: {reason}"
    assert ranks[1]["failure"] == f"GnsError: rank 0 failed: {reason}"
