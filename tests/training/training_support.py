"""Helpers of the training tests: a small dataset whose windows differ in particle counts, tiny recipes, child
processes."""

from __future__ import annotations

import os
import sys
from pathlib import Path

import yaml
from synthetic import soft_sphere_trajectory, synthetic_metadata

from gns_framework.plugins import load_registry

# (block, kinematic floor) per training trajectory: 25 to 54 particles, some kinematic, so
# the ranks' batches hold different numbers of predicted particles.
TRAIN_SCENES = [(4, True), (5, False), (3, True), (6, False)]
FRAMES = 16


def write_uneven_dataset(path: Path) -> Path:
    def scene(seed: int, block: int, floor: bool, key: str):
        return soft_sphere_trajectory(
            seed, frames=FRAMES, block=block, particle_types=(5,), kinematic_floor=floor, key=key
        )

    splits = {
        "train": [scene(i, b, f, f"train_{i}") for i, (b, f) in enumerate(TRAIN_SCENES)],
        "valid": [scene(10, 4, True, "valid_0")],
        "test": [scene(11, 4, True, "test_0")],
    }
    load_registry().get("dataset", "safe").write(path, synthetic_metadata(splits["train"], 2), splits)
    return path


def tiny_recipe(dataset: Path, name: str = "tiny", **training) -> dict:
    """A recipe small enough to train in a test: latent 16, 2 message-passing steps, CPU."""
    settings = {
        "steps": 8,
        "batch_size": 2,
        "log_every": 2,
        "validate_every": 4,
        "checkpoint_every": 4,
        "validation_windows": 2,
        "keep_checkpoints": 3,
        "device": "cpu",
        "optimizer": {"lr_init": 1e-3, "lr_min": 1e-5, "lr_decay_steps": 1000},
    }
    settings.update(training)
    return {
        "name": name,
        "seed": 3,
        "dataset": {"path": str(dataset)},
        "model": {
            "latent_size": 16,
            "mlp_hidden_size": 16,
            "mlp_hidden_layers": 1,
            "type_embedding_size": 4,
            "processor": {"name": "interaction_network", "message_passing_steps": 2},
        },
        "training": settings,
    }


def write_recipe(path: Path, recipe: dict) -> Path:
    path.write_text(yaml.safe_dump(recipe))
    return path


def subprocess_env() -> dict[str, str]:
    """Environment of child processes: this checkout importable, one thread each, loopback only."""
    root = str(Path(__file__).resolve().parents[2])
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([root, env.get("PYTHONPATH", "")]).rstrip(os.pathsep)
    env.update({"OMP_NUM_THREADS": "1", "GLOO_SOCKET_IFNAME": "lo", "MASTER_ADDR": "127.0.0.1"})
    env.pop("MLFLOW_TRACKING_URI", None)
    return env


def gns_command(*args: str) -> list[str]:
    return [sys.executable, "-m", "gns_framework.cli", *args]


def last_logged_step(run_dir: Path) -> int:
    from gns_framework.training.tracking import read_metrics

    logged = read_metrics(run_dir)
    return logged[-1]["step"] if logged else 0


def wait_until(condition, timeout: float, what: str, job=None):
    """Poll ``condition()`` until it returns a truthy value; fail after ``timeout`` s or if ``job`` ends."""
    import time

    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        found = condition()
        if found:
            return found
        if job is not None and job.poll() is not None:
            raise AssertionError(f"process ended (exit {job.returncode}) before {what}")
        time.sleep(0.05)
    raise AssertionError(f"timed out after {timeout} s waiting for {what}")


def child_processes(pid: int) -> list[int]:
    """Direct children of ``pid``, from /proc (Linux)."""
    children = []
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        if int(fields[1]) == pid:
            children.append(int(stat.parent.name))
    return children


def process_environment(pid: int) -> dict[str, str]:
    try:
        raw = Path(f"/proc/{pid}/environ").read_bytes()
    except OSError:
        return {}
    return dict(item.split("=", 1) for item in raw.decode(errors="replace").split("\0") if "=" in item)


def trainable_integrators(registry) -> list[str]:
    """Installed integrators training accepts: not those sharing another's position map (assembly.learned)."""
    return [n for n in registry.names("integrator") if not registry.get("integrator", n).same_position_map_as]
