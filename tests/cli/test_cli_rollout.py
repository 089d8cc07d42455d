"""``gns rollout`` (``gns_framework.cli.rollout``): rollouts of a trained checkpoint written beside the ground truth,
refused outside the model's envelope unless asked, in reduced precision and in batches; how ``--batch`` groups
trajectories; which earlier folders it may write into; a corrupt checkpoint as a one-line error."""

from __future__ import annotations

import json
from argparse import Namespace
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import torch
import yaml
from cli_runner import gns
from tiny import tiny_recipe_mapping

from gns_framework.cli import main
from gns_framework.cli import rollout as rollout_command
from gns_framework.io.rollout_file import load_rollout
from gns_framework.runtime.processes import Processes


def test_train_resume_rollout_render(dataset_multimaterial, tmp_path):
    recipe = tmp_path / "tiny.yaml"
    raw = tiny_recipe_mapping(dataset_multimaterial, tmp_path / "run")
    raw["training"]["log_every"] = 2
    recipe.write_text(yaml.safe_dump(raw))
    first = gns("train", str(recipe), "--steps", "3", "--no-progress")
    assert first.returncode == 0, first.stderr
    resumed = gns("train", str(recipe), "--steps", "5", "--resume", "--no-progress")
    assert resumed.returncode == 0, resumed.stderr
    assert "resumed from" in resumed.stdout and "to step 5" in resumed.stdout
    assert "step 4 of 5" in resumed.stdout and "to go" in resumed.stdout, "without a bar, the run says how long is left"
    checkpoint = tmp_path / "run" / "checkpoints" / "checkpoint-000000005.pt"
    # Trained for 5 steps on 3 trajectories, the model's envelope is narrow: the test split's friction lies outside.
    refused = gns("rollout", str(checkpoint), "--steps", "4", "--out", str(tmp_path / "rollouts"), "--no-progress")
    assert refused.returncode == 2 and "outside the envelope of" in refused.stderr
    assert "property friction" in refused.stderr and "--outside-envelope" in refused.stderr
    assert not (tmp_path / "rollouts").exists()
    rolled = gns(
        "rollout",
        str(checkpoint),
        "--steps",
        "4",
        "--out",
        str(tmp_path / "rollouts"),
        "--no-progress",
        "--outside-envelope",
    )
    assert rolled.returncode == 0, rolled.stderr
    assert "warning: outside the envelope of" in rolled.stderr
    rollout_file = tmp_path / "rollouts" / "test_0000.npz"
    with np.load(rollout_file, allow_pickle=False) as z:
        assert z["predicted_rollout"].shape[0] == 4
        assert "property friction" in json.loads(str(z["metadata_json"]))["outside_envelope"][0]
    # In process, to see the dtypes of the Linear layers' products as the rollout runs them.
    products = []

    def record(module, inputs, output):
        if isinstance(module, torch.nn.Linear):
            products.append(output.dtype)

    hook = torch.nn.modules.module.register_module_forward_hook(record)
    try:
        low = main(
            [
                "rollout",
                str(checkpoint),
                "--steps",
                "4",
                "--out",
                str(tmp_path / "low"),
                "--no-progress",
                "--precision",
                "bfloat16",
                "--outside-envelope",
            ]
        )
    finally:
        hook.remove()
    assert low == 0
    assert products and set(products) == {torch.bfloat16}, "--precision bfloat16 left products in float32"
    with np.load(rollout_file) as full, np.load(tmp_path / "low" / "test_0000.npz") as bf16:
        assert bf16["predicted_rollout"].dtype == full["predicted_rollout"].dtype == np.float32
        assert np.allclose(bf16["predicted_rollout"], full["predicted_rollout"], atol=1e-3)
    # --batch rolls the two training trajectories out together: each file as when rolled out alone.
    for folder, batch in (("alone", "1"), ("batched", "2")):
        code = main(
            [
                "rollout",
                str(checkpoint),
                "--split",
                "train",
                "--steps",
                "4",
                "--out",
                str(tmp_path / folder),
                "--no-progress",
                "--batch",
                batch,
                "--outside-envelope",
            ]
        )
        assert code == 0
    for index in range(2):
        with (
            np.load(tmp_path / "alone" / f"train_{index:04d}.npz") as alone,
            np.load(tmp_path / "batched" / f"train_{index:04d}.npz") as batched,
        ):
            expected = alone["predicted_rollout"]
            np.testing.assert_allclose(
                batched["predicted_rollout"], expected, rtol=0, atol=1e-5 * np.abs(expected).max()
            )
    rendered = gns("render", str(rollout_file), "--gif", str(tmp_path / "r.gif"))
    assert rendered.returncode == 0 and (tmp_path / "r.gif").stat().st_size > 0


def test_corrupt_checkpoint_is_a_clear_error(tmp_path):
    bad = tmp_path / "checkpoint-000000001.pt"
    bad.write_bytes(b"not a checkpoint")
    result = gns("rollout", str(bad))
    assert result.returncode == 2
    assert str(bad) in result.stderr and "unreadable checkpoint" in result.stderr


def batches_of(lengths: list[int], count: int, batch: int, monkeypatch) -> list[list[int]]:
    """The groups of trajectory indices ``_rollouts`` hands to one call, with the model calls replaced by records."""
    calls = []
    trajectories = [SimpleNamespace(num_steps=length, index=i) for i, length in enumerate(lengths)]

    def one(simulator, trajectory, steps, device, progress, guard, precision, capture):
        calls.append([trajectory.index])
        return f"rollout {trajectory.index}"

    def many(simulator, group, steps, device, guard, precision, capture):
        calls.append([t.index for t in group])
        return [f"rollout {t.index}" for t in group]

    monkeypatch.setattr(rollout_command, "rollout", one)
    monkeypatch.setattr(rollout_command, "rollout_batch", many)
    args = Namespace(batch=batch, no_progress=True, precision="float32", partitions=1, capture=False)
    job = rollout_command._Job(None, trajectories, count, None, "cpu", None)  # type: ignore[arg-type]
    rolled = rollout_command._rollouts(job, args, Processes(), None)  # type: ignore[arg-type]
    results = list(rolled)
    # Every rollout comes back under its own index, in order, whatever the grouping.
    assert results == [(i, f"rollout {i}") for i in range(count)]
    return calls


def test_batches_hold_consecutive_trajectories_of_one_length_up_to_the_batch_size(monkeypatch):
    lengths = [5, 5, 5, 7, 5, 5, 5]
    # A batch closes when it is full (0-1), when the next length differs (2 before the 7), and at the count (4-5).
    assert batches_of(lengths, 6, 2, monkeypatch) == [[0, 1], [2], [3], [4, 5]]
    assert batches_of(lengths, 7, 8, monkeypatch) == [[0, 1, 2], [3], [4, 5, 6]]
    assert batches_of(lengths, 3, 1, monkeypatch) == [[0], [1], [2]]  # --batch 1: one rollout call each


def test_captured_batches_share_one_set_of_capacity_classes(monkeypatch):
    # Issue 45, item 5: batches of similar size replay one capture, so every batch of the job gets the same classes.
    from gns_framework.model.capacity_classes import CaptureClasses

    given = []
    monkeypatch.setattr(rollout_command, "rollout_batch", lambda *a, capture, **k: given.append(capture) or [0, 0])
    args = Namespace(batch=2, no_progress=True, precision="float32", partitions=1, capture=True)
    trajectories = [SimpleNamespace(num_steps=5) for _ in range(6)]
    job = rollout_command._Job(None, trajectories, 6, None, "cpu", None)  # type: ignore[arg-type]
    list(rollout_command._rollouts(job, args, Processes(), None))  # type: ignore[arg-type]
    assert len(given) == 3 and all(c is given[0] for c in given)
    assert isinstance(given[0], CaptureClasses) and given[0].scenes == 2


def test_only_rollout_files_make_a_folder_rollout_may_write_into(tmp_path):
    folder = tmp_path / "rollouts"
    folder.mkdir()
    assert rollout_command._only_rollouts(folder)  # empty
    (folder / "test_0000.npz").write_bytes(b"")
    (folder / "valid-2_0013.npz").write_bytes(b"")
    assert rollout_command._only_rollouts(folder)
    (folder / "notes.txt").write_text("mine")
    assert not rollout_command._only_rollouts(folder)
    (folder / "notes.txt").unlink()
    (folder / "test_001.npz").write_bytes(b"")  # three digits: not a name gns rollout writes
    assert not rollout_command._only_rollouts(folder)
    (folder / "test_001.npz").unlink()
    (folder / "test_0001.npz").mkdir()  # the name of a rollout file, but a folder
    assert not rollout_command._only_rollouts(folder)
    (folder / "test_0001.npz").rmdir()
    (folder / "test_0001.rollout").mkdir()  # a sharded rollout's name, without its manifest
    assert not rollout_command._only_rollouts(folder)
    (folder / "test_0001.rollout" / "rollout.json").write_text("{}")
    assert rollout_command._only_rollouts(folder)


def test_a_rollout_partitioned_over_two_processes_writes_what_one_process_writes(tiny_model, tmp_path):
    """``torchrun --nproc-per-node 2 ... rollout --partitions 2``, as a user launches it, against one process."""
    import os
    import subprocess
    import sys

    common = [str(tiny_model), "--steps", "5", "--outside-envelope", "--no-progress"]
    one = gns("rollout", *common, "--out", str(tmp_path / "one"))
    assert one.returncode == 0, one.stderr
    scratch = tmp_path / "scratch"
    scratch.mkdir()
    env = dict(os.environ, OMP_NUM_THREADS="1", TMPDIR=str(scratch))
    launcher = [sys.executable, "-m", "torch.distributed.run", "--standalone", "--nproc-per-node", "2"]
    command = ["-m", "gns_framework.cli", "rollout", *common, "--partitions", "2", "--out", str(tmp_path / "two")]
    two = subprocess.run(launcher + command, capture_output=True, text=True, timeout=600, env=env)
    assert two.returncode == 0, two.stderr
    assert "2 slabs along dimension" in two.stdout and "moved between processes" in two.stdout  # P = 2: slabs
    written = sorted(p.name for p in (tmp_path / "one").iterdir())
    assert sorted(p.name for p in (tmp_path / "two").iterdir()) == [n.replace(".npz", ".rollout") for n in written]
    kept_aside = [p for p in scratch.rglob("*") if p.suffix in (".npy", ".h5", ".npz")]
    assert not kept_aside, "no frames are kept aside: every process writes its own shard"
    assert sorted(p.name for p in (tmp_path / "two" / "test_0000.rollout").iterdir()) == [
        "rollout.json",
        "shard-00000.h5",
        "shard-00001.h5",
    ]
    _same_rollout(tmp_path / "one" / "test_0000.npz", tmp_path / "two" / "test_0000.rollout")
    rendered = gns("render", str(tmp_path / "two" / "test_0000.rollout"), "--gif", str(tmp_path / "two.gif"))
    assert rendered.returncode == 0 and (tmp_path / "two.gif").stat().st_size > 0, rendered.stderr
    again = subprocess.run(launcher + command, capture_output=True, text=True, timeout=600, env=env)
    assert again.returncode == 0, again.stderr  # its own earlier result: written over
    _same_rollout(tmp_path / "one" / "test_0000.npz", tmp_path / "two" / "test_0000.rollout")


def _same_rollout(one_process: Path, sharded: Path) -> None:
    """The sharded rollout reads back as the single-process file: predictions to float32 rounding, the rest exact."""
    a, b = load_rollout(one_process), load_rollout(sharded)
    tolerance = np.finfo(np.float32).eps * np.abs(a.predicted).max() * a.num_steps
    np.testing.assert_allclose(b.predicted, a.predicted, rtol=0, atol=tolerance)
    np.testing.assert_array_equal(b.truth.position, a.truth.position)
    np.testing.assert_array_equal(b.particle_type, a.particle_type)
    assert b.metadata == a.metadata and b.key == a.key


def test_two_teams_of_two_processes_roll_out_the_scenes_in_turn(tiny_model, tmp_path):
    """4 processes, --partitions 2: team 0 takes scenes 0 and 2, team 1 scene 1 (and waits in the second round)."""
    import os
    import subprocess
    import sys

    from synthetic import write_synthetic_dataset

    data = write_synthetic_dataset(
        tmp_path / "three",
        train=1,
        valid=1,
        test=3,
        particle_types=(5, 6),
        kinematic_floor=True,
        with_property=True,
        frames=20,
    )
    common = [str(tiny_model), "--dataset", str(data), "--steps", "4", "--outside-envelope", "--no-progress"]
    one = gns("rollout", *common, "--out", str(tmp_path / "one"))
    assert one.returncode == 0, one.stderr
    env = dict(os.environ, OMP_NUM_THREADS="1")
    launcher = [sys.executable, "-m", "torch.distributed.run", "--standalone", "--nproc-per-node", "4"]
    command = ["-m", "gns_framework.cli", "rollout", *common, "--partitions", "2", "--out", str(tmp_path / "teams")]
    teams = subprocess.run(launcher + command, capture_output=True, text=True, timeout=600, env=env)
    assert teams.returncode == 0, teams.stderr
    assert teams.stdout.count("moved between processes") == 3
    written = sorted(p.name for p in (tmp_path / "one").iterdir())
    assert len(written) >= 3
    assert sorted(p.name for p in (tmp_path / "teams").iterdir()) == [n.replace(".npz", ".rollout") for n in written]
    for index in range(3):
        _same_rollout(tmp_path / "one" / f"test_{index:04d}.npz", tmp_path / "teams" / f"test_{index:04d}.rollout")


def test_a_team_whose_rollout_stops_stops_every_team_and_nothing_is_written(tiny_model, tmp_path):
    """Scene 1 (team 1's) starts far outside the domain: the guard stops it at its first step, team 0 finishes
    its scene and learns it, every process exits with an error, and no file or folder is written."""
    import dataclasses
    import os
    import subprocess
    import sys

    from synthetic import soft_sphere_trajectory, synthetic_metadata

    from gns_framework.plugins import load_registry

    scene = dict(particle_types=(5, 6), kinematic_floor=True, with_property=True, frames=20)
    train = [soft_sphere_trajectory(0, key="train_000", **scene)]
    test = [soft_sphere_trajectory(seed, key=f"test_{seed:03d}", **scene) for seed in (1, 2)]
    test[1] = dataclasses.replace(test[1], position=test[1].position + np.float32(50.0))
    data = tmp_path / "stops"
    load_registry().get("dataset", "safe").write(
        # A connectivity radius of 30 widens the domain check of the data (two radii) past the 50 m the scene is moved:
        # the data is read, and the rollout's guard (margin 0.1) stops it.
        data,
        synthetic_metadata(train, 2).model_copy(update={"default_connectivity_radius": 30.0}),
        {"train": train, "valid": train, "test": test},
    )
    env = dict(os.environ, OMP_NUM_THREADS="1")
    launcher = [sys.executable, "-m", "torch.distributed.run", "--standalone", "--nproc-per-node", "4"]
    options = ["--dataset", str(data), "--steps", "4", "--outside-envelope", "--no-progress", "--partitions", "2"]
    guard = ["--guard-margin", "0.1", "--on-violation", "stop", "--out", str(tmp_path / "out")]
    command = ["-m", "gns_framework.cli", "rollout", str(tiny_model), *options, *guard]
    stopped = subprocess.run(launcher + command, capture_output=True, text=True, timeout=300, env=env)
    assert stopped.returncode != 0
    assert "another team's rollout stopped in round 0" in stopped.stderr, stopped.stderr[-2000:]
    assert not (tmp_path / "out").exists()


def test_partitions_without_as_many_processes_is_refused(tiny_model, tmp_path):
    refused = gns("rollout", str(tiny_model), "--partitions", "2", "--out", str(tmp_path / "out"))
    assert refused.returncode != 0
    assert "--partitions 2 needs 2 processes" in refused.stderr and "torchrun --nproc-per-node 2" in refused.stderr
    assert not (tmp_path / "out").exists()


def test_partition_options_that_do_not_combine_are_refused(tiny_model, tmp_path):
    without = gns("rollout", str(tiny_model), "--cut", "blocks", "--out", str(tmp_path / "a"))
    assert (
        without.returncode != 0
        and "--partition-axis, --cut, --rebalance and --halo need --partitions P" in without.stderr
    )
    both = ["--partitions", "2", "--cut", "blocks", "--partition-axis", "0", "--out", str(tmp_path / "b")]
    refused = gns("rollout", str(tiny_model), *both)
    assert refused.returncode != 0 and "--cut blocks has no one axis" in refused.stderr
    assert not (tmp_path / "a").exists() and not (tmp_path / "b").exists()


def test_capture_of_a_step_that_waits_for_the_device_is_one_clear_line(tiny_model, tmp_path):
    # The tiny model's radius builder reads its edge count back: its step cannot be captured.
    refused = gns(
        "rollout", str(tiny_model), "--capture", "--steps", "2", "--outside-envelope", "--out", str(tmp_path / "out")
    )
    assert refused.returncode != 0, refused.stdout
    assert "cannot be captured" in refused.stderr and "use radius_fixed_capacity" in refused.stderr
    assert "Traceback" not in refused.stderr
    split = gns("rollout", str(tiny_model), "--capture", "--partitions", "2", "--out", str(tmp_path / "b"))
    assert split.returncode != 0 and "--capture does not combine with --partitions" in split.stderr
    assert not (tmp_path / "b").exists()


def test_a_rollout_over_two_nodes_writes_what_one_process_writes(tiny_model, tmp_path):
    """Two torchrun launches, one per "node", meeting at a c10d rendezvous (issue 50, item 4), as on two hosts."""
    import os
    import socket
    import subprocess
    import sys

    common = [str(tiny_model), "--steps", "4", "--outside-envelope", "--no-progress"]
    one = gns("rollout", *common, "--out", str(tmp_path / "one"))
    assert one.returncode == 0, one.stderr
    with socket.socket() as probe:  # a free port for the rendezvous
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    env = dict(os.environ, OMP_NUM_THREADS="1")
    launcher = [sys.executable, "-m", "torch.distributed.run", "--nnodes", "2", "--nproc-per-node", "1"]
    launcher += ["--rdzv-backend", "c10d", "--rdzv-endpoint", f"127.0.0.1:{port}", "--rdzv-id", "two-nodes"]
    command = ["-m", "gns_framework.cli", "rollout", *common, "--partitions", "2", "--out", str(tmp_path / "two")]
    nodes = [
        subprocess.Popen(launcher + command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
        for _ in range(2)
    ]
    outputs = [node.communicate(timeout=600) for node in nodes]
    assert all(node.returncode == 0 for node in nodes), "\n".join(err for _, err in outputs)
    assert any("2 slabs along dimension" in out for out, _ in outputs)
    _same_rollout(tmp_path / "one" / "test_0000.npz", tmp_path / "two" / "test_0000.rollout")


def test_rollout_compile_compiles_the_node_side_and_writes_the_same_frames(tiny_model, tmp_path, monkeypatch):
    # gns rollout --compile (issue 45, item 4); aot_eager traces the graphs inductor would compile, whole.
    from gns_framework.runtime import compiled

    made = []
    monkeypatch.setattr(
        rollout_command, "compile_node_side", lambda model: made.append(compiled.compile_node_side(model, "aot_eager"))
    )
    common = [str(tiny_model), "--steps", "3", "--trajectories", "1", "--outside-envelope", "--no-progress"]
    torch._dynamo.reset()
    try:
        assert main(["rollout", *common, "--compile", "--out", str(tmp_path / "compiled")]) == 0
    finally:
        torch._dynamo.reset()
    assert main(["rollout", *common, "--out", str(tmp_path / "eager")]) == 0
    assert made and "features.node_features" in made[0]
    [compiled_file] = sorted((tmp_path / "compiled").glob("*.npz"))
    [eager_file] = sorted((tmp_path / "eager").glob("*.npz"))
    np.testing.assert_array_equal(load_rollout(compiled_file).predicted, load_rollout(eager_file).predicted)


def test_a_model_with_a_deposit_warning_scores_every_sand_rollout_and_reports_the_flagged_ones(tiny_model, tmp_path):
    from tiny import with_deposit_warning

    common = ["--outside-envelope", "--no-progress", "--trajectories", "1"]
    flagging = with_deposit_warning(tiny_model, tmp_path / "flags.pt", threshold=0.0)
    flagged = gns("rollout", str(flagging), "--out", str(tmp_path / "flagged"), *common)
    assert flagged.returncode == 0, flagged.stderr
    rollout_file = tmp_path / "flagged" / "test_0000.npz"
    assert f"{rollout_file}: " in flagged.stdout and "deposit warning score 0.00" in flagged.stdout
    assert f"warning: {rollout_file}: the deposit may be more than 15 % off in extent or height" in flagged.stderr
    with np.load(rollout_file, allow_pickle=False) as z:
        recorded = json.loads(str(z["metadata_json"]))["deposit_warning"]
    assert recorded == {"score": 0.0, "threshold": 0.0, "error_pct": 15.0, "flagged": True}

    quiet = with_deposit_warning(tiny_model, tmp_path / "quiet.pt", threshold=0.5)
    calm = gns("rollout", str(quiet), "--out", str(tmp_path / "calm"), *common)
    assert calm.returncode == 0, calm.stderr
    assert "deposit warning score 0.00" in calm.stdout and "may be more than" not in calm.stderr
    with np.load(tmp_path / "calm" / "test_0000.npz", allow_pickle=False) as z:
        assert json.loads(str(z["metadata_json"]))["deposit_warning"]["flagged"] is False

    # A rollout cut short has no deposit to judge; a model without a warning says nothing of one.
    short = gns("rollout", str(flagging), "--out", str(tmp_path / "short"), "--steps", "3", *common)
    assert short.returncode == 0 and "deposit warning" not in short.stdout + short.stderr
    plain = gns("rollout", str(tiny_model), "--out", str(tmp_path / "plain"), *common)
    assert plain.returncode == 0 and "deposit warning" not in plain.stdout + plain.stderr
