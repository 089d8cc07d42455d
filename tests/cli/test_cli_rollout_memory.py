"""A scene too large for one process's memory ceiling rolls out over four (issue 50): under the same limit on
private memory (RLIMIT_DATA: heap and anonymous maps, not the memory-mapped scene file), ``gns rollout`` in one
process fails and ``--partitions 4`` under torchrun succeeds, because no process of the four holds the scene."""

from __future__ import annotations

import os
import resource
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from synthetic import synthetic_metadata

from gns_framework.data.trajectory import Trajectory
from gns_framework.plugins import load_registry

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="RLIMIT_DATA and /proc are Linux's")

MB = 1 << 20


def _large_scene(folder: Path, side: int = 100, frames: int = 2400) -> int:
    """A ``safe`` dataset whose test split is one scene of ``side``^2 particles (the tiny model's types 5 and 6,
    a friction each) creeping for ``frames`` frames: positions stored as they are, so a reader can map them.
    Returns the positions' bytes."""
    rng = np.random.default_rng(0)
    spacing = 0.04
    lattice = np.stack(np.meshgrid(np.arange(side), np.arange(side), indexing="ij"), -1).reshape(-1, 2)
    start = lattice * spacing + 0.2
    creep = rng.normal(0, 0.00001, start.shape)
    position = (start[None] + np.arange(frames)[:, None, None] * creep[None]).astype(np.float32)
    n = len(start)
    scene = Trajectory(position, np.where(np.arange(n) % 2 == 0, 5, 6), np.full((n, 1), 0.7, np.float32), key="big")
    box = side * spacing + 0.4
    metadata = synthetic_metadata([scene], 2).model_copy(update={"bounds": [(0.0, box), (0.0, box)]})
    load_registry().get("dataset", "safe").write(folder, metadata, {"test": [scene]})
    return position.nbytes


def _descendants(pid: int) -> list[int]:
    """``pid`` and every process below it, from /proc."""
    parents: dict[int, list[int]] = {}
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                ppid = int((entry / "stat").read_text().rsplit(")", 1)[1].split()[1])
            except (OSError, IndexError, ValueError):
                continue
            parents.setdefault(ppid, []).append(int(entry.name))
    found, todo = [], [pid]
    while todo:
        current = todo.pop()
        found.append(current)
        todo += parents.get(current, [])
    return found


def _run(command: list[str], limit: int | None = None) -> tuple[subprocess.CompletedProcess, int]:
    """``command`` (with RLIMIT_DATA ``limit`` bytes for it and the processes it starts), and the most private
    memory (VmData) any of its processes held, sampled every 10 ms."""

    def limited() -> None:
        if limit is not None:
            resource.setrlimit(resource.RLIMIT_DATA, (limit, limit))

    env = dict(os.environ, OMP_NUM_THREADS="1")
    process = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env,
                               preexec_fn=limited)  # fmt: skip
    peak = 0

    def sample() -> None:
        nonlocal peak
        while process.poll() is None:
            for pid in _descendants(process.pid):
                try:
                    status = Path(f"/proc/{pid}/status").read_text()
                except OSError:
                    continue
                for line in status.splitlines():
                    if line.startswith("VmData:"):
                        peak = max(peak, int(line.split()[1]) * 1024)
            time.sleep(0.01)

    sampler = threading.Thread(target=sample)
    sampler.start()
    out, err = process.communicate(timeout=600)
    sampler.join()
    return subprocess.CompletedProcess(command, process.returncode, out, err), peak


def test_a_scene_one_process_cannot_hold_under_a_memory_ceiling_rolls_out_over_four(tiny_model, tmp_path):
    scene_bytes = _large_scene(tmp_path / "large")
    common = [str(tiny_model), "--dataset", str(tmp_path / "large"), "--steps", "3", "--outside-envelope"]
    common += ["--no-progress"]
    launcher = [sys.executable, "-m", "torch.distributed.run", "--standalone", "--nproc-per-node", "4"]
    four = [*launcher, "-m", "gns_framework.cli", "rollout", *common, "--partitions", "4"]
    free, four_peak = _run([*four, "--out", str(tmp_path / "free")])
    assert free.returncode == 0, free.stderr
    # The most any of the four held, and a quarter of the scene more: one process holding the scene needs more.
    ceiling = four_peak + scene_bytes // 4
    one, _ = _run([sys.executable, "-m", "gns_framework.cli", "rollout", *common, "--out", str(tmp_path / "one")],
                  ceiling)  # fmt: skip
    assert one.returncode != 0, f"one process ran under {ceiling / MB:.0f} MB: the test shows nothing"
    assert "gns rollout: error: out of memory" in one.stderr, one.stderr[-2000:]
    limited, _ = _run([*four, "--out", str(tmp_path / "limited")], ceiling)
    assert limited.returncode == 0, f"under {ceiling / MB:.0f} MB (scene {scene_bytes / MB:.0f} MB):\n{limited.stderr}"
    assert (tmp_path / "limited" / "test_0000.rollout" / "rollout.json").is_file()
