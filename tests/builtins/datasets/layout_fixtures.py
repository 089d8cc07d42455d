"""The files in tests/fixtures/public_layouts, written by generate.py as DeepMind, LagrangeBench and geoelements write
them.

They are made from the public specifications (TFRecord framing, protobuf wire format,
h5py, numpy), not with gns-framework's writers, so a mistake shared by a reader and
its writer cannot hide in the tests that read them.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

FIXTURES = Path(__file__).resolve().parents[2] / "fixtures" / "public_layouts"
FLOAT32 = float(np.finfo(np.float32).eps)
"""Relative resolution of the stored float32 positions (values of order 0.1 to 1)."""


def expected_position(frames: int, particles: int, number: int) -> np.ndarray:
    """The positions generate.py writes, restated: x = 0.2 + 0.1 i + 0.01 t + 0.05 number, y = 0.3 + 0.1 i - 0.02 t."""
    t, i = np.mgrid[0:frames, 0:particles]
    return np.stack([0.2 + 0.1 * i + 0.01 * t + 0.05 * number, 0.3 + 0.1 * i - 0.02 * t], axis=-1)


def read(registry, layout: str, path: Path):
    """``(metadata, {split: [trajectories]})`` of the dataset at ``path`` read in ``layout``."""
    cls = registry.get("dataset", layout)
    dataset = cls(cls.Params(), path)
    return dataset.metadata(), {name: list(dataset.split(name)) for name in dataset.splits()}
