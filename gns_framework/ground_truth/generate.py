"""Generate a dataset from a scene: seeded trajectories, train/valid/test splits, metadata from the data.

Trajectory i of a dataset always gets the i-th seed spawned from the scene
seed (train first, then valid, then test), so adding trajectories keeps the
existing ones bit for bit, and a dataset is rebuilt exactly from its scene.
"""

from __future__ import annotations

import json
from collections.abc import Collection
from pathlib import Path
from typing import Any

import numpy as np
from tqdm import tqdm

from .. import __version__
from ..contracts import Dataset, GroundTruthSimulator
from ..data.metadata import DatasetMetadata, compute_statistics
from ..data.particle_spacing import suggest_connectivity_radius
from ..data.trajectory import Trajectory
from .drawn import write_drawn
from .scene_spec import SceneSpec

SPLITS = ("train", "valid", "test")


def trajectory_seeds(scene_seed: int, count: int) -> list[int]:
    """Independent 32-bit seeds for trajectories 0..count-1; the i-th does not depend on ``count``."""
    children = np.random.SeedSequence(scene_seed).spawn(count)
    return [int(child.generate_state(1, dtype=np.uint32)[0]) for child in children]


def provenance(scene: SceneSpec, simulator: GroundTruthSimulator, counts: dict[str, int]) -> dict:
    """What a dataset was generated from; equal provenance means an identical dataset."""
    return {
        "scene": scene.model_dump(mode="json", exclude_none=True),
        "simulator": {"name": simulator.name, **simulator.params.model_dump(mode="json")},
        "trajectories": {split: counts.get(split, 0) for split in SPLITS},
        "gns_framework": __version__,
    }


def is_up_to_date(out: Path, expected: dict) -> bool:
    """Whether ``out`` already holds the dataset ``expected`` describes (so generating again can be skipped)."""
    try:
        metadata = json.loads((Path(out) / "metadata.json").read_text())
    except (OSError, ValueError):
        return False
    return isinstance(metadata, dict) and metadata.get("generated_from") == expected


def simulate_splits(
    scene: SceneSpec,
    simulator: GroundTruthSimulator,
    counts: dict[str, int],
    progress: bool = True,
) -> dict[str, list[Trajectory]]:
    """Run ``counts[split]`` trajectories per split (train, valid, test in that order), with a progress bar."""
    total = sum(counts.get(split, 0) for split in SPLITS)
    seeds = iter(trajectory_seeds(scene.seed, total))
    splits: dict[str, list[Trajectory]] = {}
    with tqdm(total=total, desc=f"simulating {scene.name}", unit="traj", disable=not progress) as bar:
        for split in SPLITS:
            if counts.get(split, 0) == 0:
                continue
            splits[split] = []
            for _ in range(counts[split]):
                bar.set_postfix_str(split)
                splits[split].append(simulator.simulate(scene, next(seeds)))
                bar.update()
    return splits


def dataset_metadata(
    scene: SceneSpec, train: list[Trajectory], kinematic_types: Collection[int], extras: dict | None = None
) -> DatasetMetadata:
    """metadata.json of a generated dataset: the scene's domain and time step, statistics of ``train``.

    ``kinematic_types``: the particle types of kinematic materials, left out of the statistics.

    ``sequence_length`` counts frames (T); DeepMind's files store T - 1, and
    their layout converts.
    """
    return DatasetMetadata.model_validate(
        {
            "bounds": [list(b) for b in scene.domain.bounds],
            "sequence_length": scene.time.frames,
            "default_connectivity_radius": suggest_connectivity_radius(train),
            "dim": scene.dim,
            "dt": scene.time.frame_dt,
            **compute_statistics(train, kinematic_types),
            **({"material_properties": list(scene.property_names)} if scene.property_names else {}),
            **(extras or {}),
        }
    )


def generate_dataset(
    scene: SceneSpec,
    simulator: GroundTruthSimulator,
    out: Path,
    layout: type[Dataset],
    counts: dict[str, int],
    progress: bool = True,
) -> DatasetMetadata:
    """Simulate the splits, compute metadata from the train split and write them in ``layout``.

    A held-out set with no train split (a test set for a model trained elsewhere) takes
    its statistics from the splits it has, and its metadata says which
    (``statistics_from``): a trained model normalises with its own statistics, never these.
    Beside the splits, ``drawn.json`` records every value each trajectory drew (:mod:`.drawn`).
    """
    if sum(counts.get(split, 0) for split in SPLITS) < 1:
        raise ValueError("a dataset needs at least one trajectory")
    splits = simulate_splits(scene, simulator, counts, progress)
    kinematic_types = [m.particle_type for m in simulator.materials.values() if m.kinematic]
    extras: dict[str, Any] = {"generated_from": provenance(scene, simulator, counts)}
    if "train" in splits:
        statistics = splits["train"]
    else:
        statistics = [t for split in SPLITS for t in splits.get(split, [])]
        extras["statistics_from"] = [split for split in SPLITS if split in splits]
    metadata = dataset_metadata(scene, statistics, kinematic_types, extras)
    layout.write(Path(out), metadata, splits)
    # What each trajectory drew (block velocities, sizes, properties, walls...), to check answers found from the data.
    seeds = trajectory_seeds(scene.seed, sum(len(t) for t in splits.values()))
    keys = [t.key or f"trajectory_{i:05d}" for split in SPLITS for i, t in enumerate(splits.get(split, []))]
    write_drawn(Path(out), scene, zip(keys, seeds, strict=True), simulator.materials)
    return metadata
