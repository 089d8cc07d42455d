"""Elastic restart: torchrun restarts the job after a rank dies, and it resumes from the last checkpoint."""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
from pathlib import Path

import pytest
import torch
from conftest import DDP_SNAPSHOTS
from spawned import free_loopback_port
from training_support import (
    child_processes,
    process_environment,
    subprocess_env,
    wait_until,
    write_recipe,
)

from gns_framework.io.checkpoint import list_checkpoints, load_checkpoint
from gns_framework.io.run_folder import checkpoint_name

pytestmark = pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="finds torchrun's workers through /proc")


def late_rank0_launcher(folder: Path) -> Path:
    """`gns` for torchrun's workers, where restarted rank 0 starts late.

    torchrun's default (static) rendezvous keeps one store across restarts, so a
    restarted rank 1 that looks for rank 0 before rank 0 is up finds the dead rank 0's
    address unless each attempt has its own keys (see distributed.start).
    """
    script = folder / "gns-late-rank0"
    script.write_text(
        "#!/bin/sh\n"
        'if [ "$RANK" = 0 ] && [ "${TORCHELASTIC_RESTART_COUNT:-0}" != 0 ]; then sleep 6; fi\n'
        f'exec "{sys.executable}" -m gns_framework.cli "$@"\n'
    )
    script.chmod(0o755)
    return script


def torchrun_command(port: int, launcher: Path, *args: str) -> list[str]:
    return [
        sys.executable,
        "-m",
        "torch.distributed.run",
        "--nnodes",
        "1",
        "--nproc-per-node",
        "2",
        "--max-restarts",
        "1",
        "--master-addr",
        "127.0.0.1",
        "--master-port",
        str(port),
        "--local-addr",
        "127.0.0.1",
        "--no-python",
        str(launcher),
        *args,
    ]


def test_killed_rank_restarts_from_last_checkpoint_and_ends_as_uninterrupted(ddp_recipe, ddp_snapshots, tmp_path):
    steps, every = DDP_SNAPSHOTS[-1], ddp_recipe["training"]["checkpoint_every"]
    recipe_file = write_recipe(tmp_path / "recipe.yaml", ddp_recipe)
    run_dir = tmp_path / "run"
    command = torchrun_command(
        free_loopback_port(),
        late_rank0_launcher(tmp_path),
        "train",
        str(recipe_file),
        "--out",
        str(run_dir),
        "--no-tracking",
        "--no-progress",
    )
    log = tmp_path / "torchrun.log"
    with open(log, "w") as output:
        job = subprocess.Popen(
            command, env=subprocess_env(), cwd=tmp_path, stdout=output, stderr=subprocess.STDOUT, start_new_session=True
        )
    try:
        wait_until(lambda: list_checkpoints(run_dir / "checkpoints"), 120, "the first checkpoint", job)
        rank1 = [pid for pid in child_processes(job.pid) if process_environment(pid).get("RANK") == "1"]
        assert len(rank1) == 1, f"rank 1 worker not found among {child_processes(job.pid)}"
        os.kill(rank1[0], signal.SIGKILL)
        job.wait(timeout=240)
    finally:
        if job.poll() is None:
            os.killpg(job.pid, signal.SIGKILL)
            job.wait()
    text = log.read_text()
    assert job.returncode == 0, text
    restarts = re.findall(r"resumed from \S+ at step (\d+)", text)
    assert len(restarts) == 1, f"expected one restart that resumed:\n{text}"
    assert every <= int(restarts[0]) < steps

    final = load_checkpoint(run_dir / "checkpoints" / checkpoint_name(steps))
    uninterrupted = ddp_snapshots[0, steps]["params"]
    for name, value in final["model"].items():
        torch.testing.assert_close(value, uninterrupted[name], rtol=1e-6, atol=1e-9, msg=name)
