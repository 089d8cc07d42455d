"""A dataset that changes under a training that maps it (``dataset.memory: windows``): truncated or rewritten in
place, the training stops with one line naming the file and keeps a checkpoint to resume from; never a SIGBUS,
never a step on changed values (issue 47)."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest
import yaml
from synthetic import write_synthetic_dataset
from tiny import tiny_recipe_mapping

from gns_framework.io.run_folder import RunFolder

CHANGE_AT_STEP = """
import os, sys
import gns_framework.data.memory
from gns_framework.cli import main
from gns_framework.training.trainer import Trainer

data, recipe, run, how = sys.argv[1:5]
gns_framework.data.memory.TRAJECTORIES_KEPT = 2  # fewer than the split's trajectories: some are read again
original = Trainer.train_step

def train_step(self):
    if self.step == 3 and how != "none":
        split = os.path.join(data, "train.npz")
        if how == "truncate":
            os.truncate(split, os.path.getsize(split) // 2)
        else:  # rewritten in place, the same size: only the values differ
            with open(split, "r+b") as handle:
                handle.seek(os.path.getsize(split) // 2)
                chunk = handle.read(64)
                handle.seek(-64, 1)
                handle.write(bytes(255 - b for b in chunk))
    return original(self)

Trainer.train_step = train_step
sys.exit(main(["train", recipe, "--out", run, "--no-tracking", "--no-progress", *sys.argv[5:]]))
"""


def _train(data, recipe, run, how, *extra) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-c", CHANGE_AT_STEP, str(data), str(recipe), str(run), how, *extra],
        capture_output=True,
        text=True,
        env={**os.environ, "OMP_NUM_THREADS": "1"},
        timeout=600,
    )


@pytest.mark.parametrize("how", ["truncate", "rewrite"])
def test_a_split_changed_under_a_mapped_training_stops_it_in_one_line_with_a_checkpoint(tmp_path, how):
    data = write_synthetic_dataset(tmp_path / "data", train=5, valid=1, test=1, frames=16)
    original = (data / "train.npz").read_bytes()
    raw = tiny_recipe_mapping(data)
    raw["dataset"].update(memory="windows")
    raw["training"].update(steps=8, batch_size=3, checkpoint_every=100, validate_every=100)
    recipe = tmp_path / "recipe.yaml"
    recipe.write_text(yaml.safe_dump(raw))
    run = tmp_path / "run"

    stopped = _train(data, recipe, run, how)
    assert stopped.returncode == 2, (stopped.returncode, stopped.stderr[-2000:])  # not 135 (SIGBUS) nor -7
    err = stopped.stderr.strip().splitlines()
    assert len(err) == 1, stopped.stderr
    assert err[0].startswith(f"gns train: error: {data / 'train.npz'}: changed while it was being read")
    kept = RunFolder(run).checkpoint(3)
    assert f"training stopped at step 3: {kept} is the checkpoint to resume from" in err[0]
    assert kept.is_file()

    (data / "train.npz").write_bytes(original)  # the data put back: the run resumes from the kept step
    resumed = _train(data, recipe, run, "none", "--resume")
    assert resumed.returncode == 0, resumed.stderr[-2000:]
    assert "resumed from" in resumed.stdout and RunFolder(run).checkpoint(8).is_file()
