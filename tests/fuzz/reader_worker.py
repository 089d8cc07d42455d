"""The worker of the readers' fuzz harness: reads one input per request, in a process of its own.

Run as ``python reader_worker.py``. Each request is one line on stdin, ``<reader> <path>``;
the answer is one line on stdout: ``ok <summary>``, ``refused <message>`` (a
:class:`~gns_framework.errors.GnsError`, the clear refusal every bad input must get) or
``other <type>: <message>`` (any other exception: a traceback a user would see). The
worker's address space is capped (``GNS_FUZZ_MEMORY_BYTES``), so an input that makes a
reader allocate beyond the limits ends as ``other MemoryError``; one that kills it by a
signal is seen by the harness as a dead worker.
"""

from __future__ import annotations

import os
import resource
import sys
import traceback
from pathlib import Path


def _touch_dataset(name: str, path: Path) -> str:
    from gns_framework.assembly.data import open_dataset
    from gns_framework.config.recipe import DatasetSpec

    dataset = open_dataset(DatasetSpec(name=name, path=str(path)), REGISTRY)
    metadata = dataset.metadata()
    frames = 0
    for split in ("train", "valid", "test"):
        if dataset.has_split(split):
            for trajectory in dataset.split(split):
                frames += int(trajectory.position.shape[0])
                float(trajectory.position.sum())
    return f"{metadata.dim}D, {frames} frames"


def _touch_checkpoint(path: Path) -> str:
    from gns_framework.assembly.trained import load_trained

    loaded = load_trained(path, REGISTRY)
    return f"step {loaded.step}"


def _touch_recipe(path: Path) -> str:
    from gns_framework.config.recipe import load_recipe

    return load_recipe(path, REGISTRY).name


def _touch_scene(path: Path) -> str:
    from gns_framework.ground_truth.scene_spec import load_scene

    return load_scene(path).name


def _touch_invert_config(path: Path) -> str:
    from gns_framework.inverse.config import load_invert_config

    _config, unknowns = load_invert_config(path)
    return ", ".join(unknowns)


READERS = {
    "safe": lambda p: _touch_dataset("safe", p),
    "npz": lambda p: _touch_dataset("npz", p),
    "tfrecord": lambda p: _touch_dataset("tfrecord", p),
    "lagrangebench": lambda p: _touch_dataset("lagrangebench", p),
    "checkpoint": _touch_checkpoint,
    "recipe": _touch_recipe,
    "scene": _touch_scene,
    "invert_config": _touch_invert_config,
}


def main() -> None:
    global REGISTRY
    limit = int(os.environ.get("GNS_FUZZ_MEMORY_BYTES", str(6 << 30)))
    resource.setrlimit(resource.RLIMIT_AS, (limit, limit))
    import torch

    torch.set_num_threads(1)
    from gns_framework.errors import GnsError
    from gns_framework.plugins import load_registry

    REGISTRY = load_registry()
    print("ready", flush=True)
    for line in sys.stdin:
        reader, _, path = line.rstrip("\n").partition(" ")
        try:
            answer = f"ok {READERS[reader](Path(path))}"
        except GnsError as error:
            answer = f"refused {error}"
        except Exception as error:  # anything else is a traceback a user would see: the harness fails on it
            where = traceback.extract_tb(error.__traceback__)[-1]
            answer = f"other {type(error).__name__}: {error} (at {where.filename}:{where.lineno})"
        print(answer.replace("\n", " | ")[:4000], flush=True)


REGISTRY = None

if __name__ == "__main__":
    main()
