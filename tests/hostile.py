"""Hostile geoelements datasets: pickles whose payload runs when unpickled, and leaves a marker file."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

MEMBER = "simulation_trajectory_0"


class WritesMarker:
    """Unpickled, creates ``path``: what a hostile file's payload does (``builtins.exec`` of the file's code)."""

    def __init__(self, path: Path):
        self.path = str(path)

    def __reduce__(self):
        return exec, (f"open({self.path!r}, 'w').close()",)


def write_hostile_dataset(folder: Path, metadata: dict, marker: Path, particles: int = 10) -> Path:
    """A geoelements (``npz``) dataset whose every split holds one trajectory tuple with a payload for positions."""
    folder.mkdir(parents=True)
    (folder / "metadata.json").write_text(json.dumps(metadata))
    for split in ("train", "valid", "test"):
        item = np.empty(2, dtype=object)
        item[0], item[1] = WritesMarker(marker), np.full(particles, 5, np.int64)
        np.savez(folder / f"{split}.npz", **{MEMBER: item})
    return folder
